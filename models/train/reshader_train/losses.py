"""The paper's training loss (eq. 1-4): L = 0.1 L1 + 0.01 ||phi(I~) - phi(I)||^2 + 1 ||G - G~||^2.

The pixel term is L1 as in the paper, or optionally the mean squared error (`pixel="l2"`).

Both images are multiplied by the validity mask before every term, as in the paper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .features import FeatureNet


@dataclass(frozen=True)
class LossWeights:
    pixel: float = 0.1
    vgg: float = 0.01
    style: float = 1.0

    @classmethod
    def parse(cls, text: str) -> LossWeights:
        """'PIXEL,VGG,STYLE', e.g. '0.1,0.01,1' (the paper's) or '0.1,0,0' (pixels only)."""
        try:
            pixel, vgg, style = (float(v) for v in text.split(","))
        except ValueError:
            raise ValueError(
                f"--loss-weights {text!r}: expected three numbers PIXEL,VGG,STYLE"
            ) from None
        if min(pixel, vgg, style) < 0 or pixel + vgg + style == 0:
            raise ValueError(f"--loss-weights {text!r}: weights must be >= 0, not all zero")
        return cls(pixel, vgg, style)

    def __str__(self) -> str:
        return f"{self.pixel:g},{self.vgg:g},{self.style:g}"

    @property
    def needs_features(self) -> bool:
        return self.vgg > 0 or self.style > 0


# The cap must lie above what unchanged validation images reach (up to ~60 dB): at the
# first cap, 50 dB, nothing pushed those images' residual below 1e-5 and they lost up to
# 4 dB each (lite-v4), most of the mean loss.
PSNR_CAP_DB = 80.0


def negative_psnr(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """-PSNR in dB per sample (peak 1, capped at PSNR_CAP_DB), averaged over the batch.

    The evaluation averages PSNR over images, where a faint residual on an image that does
    not change costs as many dB as a missed highlight on one that does; L1 and L2 summed
    over a batch weigh the changed images far more and leave that residual."""
    mse = (pred - target).square().flatten(1).mean(1)
    return 10.0 * torch.log10(mse + 10.0 ** (-PSNR_CAP_DB / 10.0)).mean()


# The floor of relative_l2's weights: crops whose shading changes less than this (as PSNR
# of the input against the truth) all weigh as much as one at the floor.
RELATIVE_FLOOR_DB = 45.0


def relative_l2(
    pred: torch.Tensor,
    target: torch.Tensor,
    image: torch.Tensor | None,
    floor_db: float = RELATIVE_FLOOR_DB,
) -> torch.Tensor:
    """Per crop, the squared error divided by how much the truth differs from the input
    (floored at `floor_db`), averaged over the batch.

    The evaluation's mean PSNR is a mean of log(error): to first order, each image's error
    counts relative to its own change, so a faint residual on a view that hardly changes
    costs as much as missing a highlight that moves. `psnr` weighs by the prediction's own
    error and rewards retreating to the identity (every run with it did); these weights
    come from the data alone."""
    if image is None:
        raise ValueError("the rel-l2 pixel loss needs the input image")
    err = (pred - target).square().flatten(1).mean(1)
    change = (target - image).square().flatten(1).mean(1)
    return (err / (change + 10.0 ** (-floor_db / 10.0))).mean()


# L1 is the paper's. With Monte-Carlo noise in the targets its optimum at a noisy pixel is
# the median, i.e. no change; L2's is the mean, which keeps view-dependent brightness changes.
# Each takes (prediction, target, input image); only rel-l2 uses the input.
PIXEL_LOSSES = {
    "l1": lambda pred, target, _image: F.l1_loss(pred, target),
    "l2": lambda pred, target, _image: F.mse_loss(pred, target),
    "psnr": lambda pred, target, _image: negative_psnr(pred, target),
    "rel-l2": relative_l2,
}


def pixel_loss(name: str):
    """The pixel loss called `name`. `rel-l2:DB` moves rel-l2's floor from 45 dB to DB: a
    higher floor weighs views whose shading hardly changes more, so that a faint residual
    there costs more."""
    base, colon, floor = name.partition(":")
    if base not in PIXEL_LOSSES or (colon and base != "rel-l2"):
        raise ValueError(
            f"pixel loss {name!r}: expected one of {sorted(PIXEL_LOSSES)} (or rel-l2:DB)"
        )
    if not colon:
        return PIXEL_LOSSES[base]
    try:
        floor_db = float(floor)
    except ValueError:
        raise ValueError(
            f"pixel loss {name!r}: the floor {floor!r} is not a number of dB"
        ) from None
    return lambda pred, target, image: relative_l2(pred, target, image, floor_db)


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
    faster on CPUs with AVX512-BF16); the loss terms themselves are computed in float32.
    With both perceptual weights at zero no feature network is needed or run."""

    def __init__(
        self,
        feature_net: FeatureNet | None,
        weights: LossWeights | None = None,
        feature_dtype: torch.dtype = torch.float32,
        pixel: str = "l1",
    ) -> None:
        super().__init__()
        self.pixel_fn = pixel_loss(pixel)
        self.pixel = pixel
        self.weights = weights or LossWeights()
        if feature_net is None and self.weights.needs_features:
            raise ValueError(
                f"loss weights {self.weights} have perceptual terms: a feature network is needed"
            )
        self.feature_net = feature_net
        self.feature_dtype = feature_dtype

    @property
    def ident(self) -> str:
        """What the perceptual terms were computed with, for configs and checkpoints."""
        return self.feature_net.ident if self.feature_net is not None else "none"

    def features(self, x: torch.Tensor) -> torch.Tensor:
        if self.feature_dtype == torch.float32:
            return self.feature_net(x)
        with torch.autocast(x.device.type, dtype=self.feature_dtype):
            return self.feature_net(x).float()

    def forward(
        self,
        pred: torch.Tensor,
        target: torch.Tensor,
        mask: torch.Tensor,
        image: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        pred = pred * mask
        target = target * mask
        image = None if image is None else image * mask
        pixel = self.pixel_fn(pred, target, image)
        w = self.weights
        if self.feature_net is None:
            vgg = style = torch.zeros((), device=pred.device)
        else:
            fp = self.features(pred)
            with torch.no_grad():
                ft = self.features(target)
            vgg = F.mse_loss(fp, ft)
            style = F.mse_loss(gram(fp), gram(ft))
        total = w.pixel * pixel + w.vgg * vgg + w.style * style
        parts = {
            "loss": float(total.detach()),
            "pixel": float(pixel.detach()),
            "vgg": float(vgg.detach()),
            "style": float(style.detach()),
        }
        return total, parts


def make_loss(
    weights: LossWeights,
    feature_net: str,
    vgg_weights: str | None,
    precision: str,
    device: torch.device,
    pixel: str = "l1",
) -> ReshadeLoss:
    """The training criterion as the command line asks for it (train and quantize share it)."""
    if not weights.needs_features:
        return ReshadeLoss(None, weights, pixel=pixel)
    from .features import load_feature_net

    net = load_feature_net(feature_net, vgg_weights).to(device)
    bf16 = precision == "bfloat16" or (precision == "auto" and bf16_is_fast(device))
    return ReshadeLoss(net, weights, torch.bfloat16 if bf16 else torch.float32, pixel)


def multi_target_loss(
    criterion: ReshadeLoss,
    pred: torch.Tensor,
    targets: torch.Tensor,
    masks: torch.Tensor,
    weights: torch.Tensor,
    image: torch.Tensor,
) -> tuple[torch.Tensor, dict[str, float]]:
    """`criterion` over several targets per photo: pred and targets (B,N,3,H,W), masks
    (B,N,1,H,W), weights (B,N) of 1 (a target) or 0 (padding), image (B,3,H,W).

    Every term of the criterion is a mean over the batch of same-sized per-image terms, so
    evaluating it once on the real targets stacked along the batch is the mean of the
    per-target losses: each real target weighs the same, whichever example it is from."""
    keep = weights > 0
    if not bool(keep.any()):
        raise ValueError("every target of the batch has weight 0")
    photos = image[:, None].expand(-1, pred.shape[1], -1, -1, -1)
    return criterion(pred[keep], targets[keep], masks[keep], photos[keep])


# How the sliding layer's fraction is compared with its teacher's (`train --teacher-distance`).
FRACTION_DISTANCES = ("l1", "squared")


def fraction_distance(p: torch.Tensor, t: torch.Tensor, kind: str) -> torch.Tensor:
    """ "l1": the mean absolute difference. A teacher's fraction is zero almost everywhere,
    and where a network cannot tell a pixel's from the photo the L1 optimum is the median
    of what it has seen there, zero: it slides too little (`teacher-check`: its mean
    fraction stays at a quarter to a half of the teacher's). "squared": the mean squared
    difference, whose optimum is the mean instead, scaled by mean(t) / mean(t^2) so that a
    network sliding nothing is as far from the teacher as under "l1"."""
    if kind == "l1":
        return (p - t).abs().mean()
    if kind != "squared":
        raise ValueError(f"fraction distance {kind!r}: expected one of {FRACTION_DISTANCES}")
    scale = t.mean() / (t * t).mean().clamp(min=1e-12)
    return scale.detach() * ((p - t) ** 2).mean()


def _masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The mean of `x` where `mask` holds (0 where it never does)."""
    return (x * mask).sum() / mask.sum().clamp(min=1)


def _log_amplitude_distance(
    mine: torch.Tensor, told: torch.Tensor, lo: float, hi: float
) -> torch.Tensor:
    """Per pixel and colour, the squared log ratio of two amplitudes over the span lo..hi.
    Where the teacher has no lobe (below lo) only a brighter one is pulled down, so that a
    faint one keeps its gradient where the teacher has one. Squared: L1's pull is the same
    for a lobe a hair too bright where the teacher has none as for one a thousand times too
    faint where it has one, and with most pixels unlit a network sits at the threshold
    everywhere."""
    gap = torch.log(mine.clamp(min=1e-30, max=hi)) - torch.log(told.clamp(min=lo, max=hi))
    gap = torch.where(told > lo, gap, gap.clamp(min=0.0))
    return (gap / math.log(hi / lo)).square()


def light_share(lobe: torch.Tensor, linear: torch.Tensor, w0: torch.Tensor) -> torch.Tensor:
    """u = a G(w0) / L for one lobe (B,7,H,W): the share of the pixel's linear light `linear`
    (B,3,H,W) that the lobe holds at the photo's view w0, mapped through u / (1 + u) to
    [0, 1): linear for the shares of unclipped pixels (u <= 1 matters there), and a lobe
    over a clipped highlight, far brighter than white, near 1 rather than unbounded."""
    g0 = torch.exp(lobe[:, 3:4] * ((lobe[:, 0:3] * w0).sum(1, keepdim=True) - 1.0))
    u = lobe[:, 4:7] * g0 / linear
    return u / (1.0 + u)


def field_loss(
    fields: torch.Tensor,
    teacher: torch.Tensor,
    lobes: int,
    fraction: str = "l1",
    log_amplitude: bool = False,
    balance: bool = False,
    photo: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """How far a lobe head's fields (B,C,H,W) are from fitted ones (`train --teacher`).

    Amplitudes and the sliding layer's fraction are compared as they are. A lobe's axis and
    sharpness matter only as far as its amplitude (a lobe of amplitude 0 may point
    anywhere), and the layer's depth only as far as its fraction, so those are weighted by
    the fitted amplitude or fraction; the fraction is compared by `fraction_distance`.
    Sharpness is compared in log, over the span of SHARPNESS_RANGE (a mirror's lobe and a
    wide one differ by four orders). `log_amplitude` (domain linear-clamped, whose
    amplitudes span ten orders): amplitudes are compared by their squared log ratio, from
    AMPLITUDE_SEEN (fainter lobes change nothing past the dead zone, so where the teacher
    has none any fainter one will do: a network starts below it, and is pulled down only
    from above it) to the top of LOG_AMPLITUDE_RANGE, and weigh axes and sharpness up to 1
    (a lobe brighter than white matters as much as a white one). `balance` (with
    `log_amplitude`): the mean over the teacher's lit amplitudes and the mean over its
    unlit ones count equally, so that lit pixels, a seventh of the training scenes', are
    not outvoted by a network that cannot tell the two apart. `photo` (image, rays), with
    `log_amplitude` (`train --teacher-share`): amplitudes are compared instead by the share
    of the pixel's light each lobe holds at the photo's view (`light_share`), squared.
    Where the photo leaves in doubt whether a highlight is there, a squared log distance
    settles on the mean of the logs, which the many unlit pixels drag to the floor (a
    network's lobes then sit near 10^-2.5 everywhere and move nothing); the mean share is
    what a view's squared error asks for there."""
    from .model import (
        AMPLITUDE_SEEN,
        LOG_AMPLITUDE_RANGE,
        SHARPNESS_RANGE,
        linear_light,
        photo_directions,
    )

    span = math.log(SHARPNESS_RANGE[1] / SHARPNESS_RANGE[0])
    lo, hi = AMPLITUDE_SEEN, LOG_AMPLITUDE_RANGE[1]
    total = fields.new_zeros(())
    if photo is not None:
        image, rays = photo
        linear, w0 = linear_light(image), photo_directions(rays)
    for j in range(lobes):
        p, t = fields[:, 7 * j : 7 * j + 7], teacher[:, 7 * j : 7 * j + 7]
        weight = t[:, 4:7].abs().mean(1, keepdim=True)
        if log_amplitude:
            weight = weight.clamp(max=1.0)
            if photo is not None:
                sq = (light_share(p, linear, w0) - light_share(t, linear, w0)).square()
            else:
                sq = _log_amplitude_distance(p[:, 4:7], t[:, 4:7], lo, hi)
            if balance:
                lit = t[:, 4:7] > lo
                total = total + _masked_mean(sq, lit) + _masked_mean(sq, ~lit)
            else:
                total = total + sq.mean()
        else:
            total = total + (p[:, 4:7] - t[:, 4:7]).abs().mean()
        total = total + (weight * (1.0 - (p[:, 0:3] * t[:, 0:3]).sum(1, keepdim=True))).mean()
        log_ratio = torch.log(p[:, 3:4].clamp(min=1e-6) / t[:, 3:4].clamp(min=1e-6))
        total = total + (weight * log_ratio.abs()).mean() / span
    if fields.shape[1] > 7 * lobes:
        p, t = fields[:, 7 * lobes :], teacher[:, 7 * lobes :]
        total = total + fraction_distance(p[:, 0:3], t[:, 0:3], fraction)
        total = total + (t[:, 0:3].mean(1, keepdim=True) * (p[:, 3:4] - t[:, 3:4]).abs()).mean()
    return total
