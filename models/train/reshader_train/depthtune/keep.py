"""Real photos without depth, to keep the shipped network's coarse shapes (`--keep-photos`).

The renders teach where depth steps; they also teach the renders' look, and a network
tuned on them alone reads depth from patterns that photos use for anything (docs/
relocation.md). On photos with no true depth the shipped network is the reference: the
tuned network's disparity, aligned to the shipped one's by scale and shift, is compared
with it after both are averaged over BLUR x BLUR windows. A plate or a bump
the size of a window costs its whole volume; a step made sharper, whose difference
changes sign across the edge within a few pixels, hardly costs, so the renders stay free
to teach edges.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..data import DatasetError
from ..depthconv.preprocess import area_resize, load_rgb
from .loss import aligned

SUFFIXES = {".jpg", ".jpeg", ".png"}
LONG_SIDE = 512
BLUR = 9


def photo_files(roots: list[Path]) -> list[Path]:
    """The photos named, and those in the folders named (sorted)."""
    found = []
    for root in map(Path, roots):
        if root.is_dir():
            found += sorted(p for p in root.iterdir() if p.suffix.lower() in SUFFIXES)
        elif root.is_file():
            found.append(root)
        else:
            raise DatasetError(f"{root}: no such photo or folder")
    if not found:
        raise DatasetError(f"{', '.join(map(str, roots))}: no .jpg or .png photos")
    return found


def load_photos(roots: list[Path], crop: tuple[int, int]) -> list[np.ndarray]:
    """Each photo as uint8 RGB, area-averaged so that its longer side is at most LONG_SIDE."""
    photos = []
    for path in photo_files(roots):
        try:
            rgb = load_rgb(path)
        except ValueError as err:
            raise DatasetError(str(err)) from None
        h, w = rgb.shape[:2]
        scale = LONG_SIDE / max(h, w)
        small = area_resize(rgb, round(h * scale), round(w * scale)) if scale < 1 else rgb
        if small.shape[0] < crop[0] or small.shape[1] < crop[1]:
            raise DatasetError(
                f"{path}: {small.shape[1]}x{small.shape[0]} after resizing, smaller than "
                f"the {crop[1]}x{crop[0]} crop"
            )
        photos.append(small)
    return photos


def photo_crop(photo: np.ndarray, size: tuple[int, int], rng: np.random.Generator):
    """A random crop [3, h, w] in [0, 1], mirrored at random."""
    h, w = size
    y = int(rng.integers(0, photo.shape[0] - h + 1))
    x = int(rng.integers(0, photo.shape[1] - w + 1))
    crop = photo[y : y + h, x : x + w].astype(np.float32) / 255.0
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    return np.ascontiguousarray(crop.transpose(2, 0, 1))


def _blur(disparity: torch.Tensor) -> torch.Tensor:
    """[N, H, W] averaged over BLUR x BLUR windows (fewer at the borders)."""
    return F.avg_pool2d(
        disparity[:, None], BLUR, stride=1, padding=BLUR // 2, count_include_pad=False
    )[:, 0]


def keep_loss(log_disparity: torch.Tensor, reference_log: torch.Tensor) -> torch.Tensor:
    """Coarse distance of the network's disparity from the reference's, both [N, 1, H, W]
    log disparity, over the reference's mean. Both are blurred before the alignment, so
    that a sharper step does not lower the fitted scale."""
    reference = _blur(reference_log[:, 0].exp())
    residual = aligned(_blur(log_disparity[:, 0].exp()), reference) - reference
    return (residual.abs().mean((1, 2)) / reference.flatten(1).mean(1).clamp_min(1e-6)).mean()
