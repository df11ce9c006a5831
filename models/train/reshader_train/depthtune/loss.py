"""Scale-and-shift-invariant disparity loss with gradient matching.

Relative depth has no scale or shift, and the runtime's evaluation aligns the network's
disparity to the truth by least squares before it relocates anything; the loss does the
same per image, then weighs the aligned error and its gradients (which put a step of the
prediction where the truth steps) by the truth's mean, so that near and far scenes count
alike.
"""

from __future__ import annotations

import torch


def aligned(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """pred [N, H, W] mapped by the per-image affine function that fits target best."""
    p = pred.flatten(1)
    t = target.flatten(1)
    pm, tm = p.mean(1, keepdim=True), t.mean(1, keepdim=True)
    var = ((p - pm) ** 2).mean(1, keepdim=True).clamp_min(1e-12)
    scale = ((p - pm) * (t - tm)).mean(1, keepdim=True) / var
    return (scale * (p - pm) + tm).view_as(pred)


def gradient_term(residual: torch.Tensor, scales: int) -> torch.Tensor:
    """Mean absolute x and y differences of the residual at `scales` halvings [N]."""
    total = residual.new_zeros(residual.shape[0])
    r = residual
    for _ in range(scales):
        total = total + (r[:, :, 1:] - r[:, :, :-1]).abs().mean((1, 2))
        total = total + (r[:, 1:, :] - r[:, :-1, :]).abs().mean((1, 2))
        r = r[:, ::2, ::2]
    return total


def depth_loss(
    log_disparity: torch.Tensor, target: torch.Tensor, grad_weight: float = 0.5, scales: int = 4
) -> tuple[torch.Tensor, dict]:
    """log_disparity [N, 1, H, W] from the network, target disparity [N, H, W]."""
    residual = aligned(log_disparity[:, 0].exp(), target) - target
    norm = target.flatten(1).mean(1).clamp_min(1e-6)
    data = residual.abs().mean((1, 2)) / norm
    grad = gradient_term(residual, scales) / norm
    loss = (data + grad_weight * grad).mean()
    return loss, {"data": float(data.detach().mean()), "grad": float(grad.detach().mean())}
