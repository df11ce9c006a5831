"""The paper's training loss (eq. 1-4): L = 0.1 L1 + 0.01 ||phi(I~) - phi(I)||^2 + 1 ||G - G~||^2.

Both images are multiplied by the validity mask before every term, as in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .features import FeatureNet


@dataclass(frozen=True)
class LossWeights:
    l1: float = 0.1
    vgg: float = 0.01
    style: float = 1.0


def gram(features: torch.Tensor) -> torch.Tensor:
    """(N,C,H,W) -> (N,C,C), normalised by C*H*W so that it does not grow with crop size."""
    n, c, h, w = features.shape
    flat = features.reshape(n, c, h * w)
    return flat @ flat.transpose(1, 2) / (c * h * w)


def bf16_is_fast(device: torch.device) -> bool:
    """Whether the feature network should run in bfloat16 autocast on this device."""
    if device.type == "cuda":
        return torch.cuda.is_bf16_supported()
    return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


class ReshadeLoss(nn.Module):
    """`feature_dtype` bfloat16 runs the frozen feature network under autocast (about 1.8x
    faster on CPUs with AVX512-BF16); the loss terms themselves are computed in float32."""

    def __init__(
        self,
        feature_net: FeatureNet,
        weights: LossWeights | None = None,
        feature_dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__()
        if feature_net is None:
            raise ValueError(
                "ReshadeLoss needs a feature network: the perceptual terms are required"
            )
        self.feature_net = feature_net
        self.weights = weights or LossWeights()
        self.feature_dtype = feature_dtype

    def features(self, x: torch.Tensor) -> torch.Tensor:
        if self.feature_dtype == torch.float32:
            return self.feature_net(x)
        with torch.autocast(x.device.type, dtype=self.feature_dtype):
            return self.feature_net(x).float()

    def forward(
        self, pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, float]]:
        pred = pred * mask
        target = target * mask
        l1 = F.l1_loss(pred, target)
        fp = self.features(pred)
        with torch.no_grad():
            ft = self.features(target)
        vgg = F.mse_loss(fp, ft)
        style = F.mse_loss(gram(fp), gram(ft))
        w = self.weights
        total = w.l1 * l1 + w.vgg * vgg + w.style * style
        parts = {
            "loss": float(total.detach()),
            "l1": float(l1.detach()),
            "vgg": float(vgg.detach()),
            "style": float(style.detach()),
        }
        return total, parts
