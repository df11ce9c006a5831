"""Rendered photos with their true depth, as the depth network sees photos.

Any example folder with input.exr and depth.exr serves (`render --input-only` writes just
those). A photo is the linear render tone-mapped by clamp((x * exposure)^(1/gamma), 0, 1)
and rounded to 8 bits, as `reshader eval-relocation` makes it (exposure 5.5, gamma 2.2);
training draws exposure and gamma per crop (the paper's augmentation, narrowed to gammas
photos have). The target is disparity 1/depth (0 where a ray missed the scene).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data import DatasetError, read_exr

EVAL_EXPOSURE = 5.5
EVAL_GAMMA = 2.2
EXPOSURE_RANGE = (3.0, 10.0)
GAMMA_RANGE = (2.2, 3.0)


def example_folders(roots: list[Path]) -> list[Path]:
    """Complete examples (input.exr, depth.exr and meta.json) under each root and its
    immediate subfolders (a family per subfolder), sorted."""
    found = []
    for root in roots:
        root = Path(root)
        if not root.is_dir():
            raise DatasetError(f"{root}: dataset folder does not exist")
        for meta in sorted(list(root.glob("*/meta.json")) + list(root.glob("*/*/meta.json"))):
            folder = meta.parent
            if not folder.name.startswith(".tmp-") and (folder / "depth.exr").is_file():
                found.append(folder)
    if not found:
        raise DatasetError(f"{', '.join(map(str, roots))}: no examples with depth.exr")
    return found


@dataclass
class Pair:
    """A linear render (float16, H x W x 3) and its disparity (float32, H x W)."""

    linear: np.ndarray
    disparity: np.ndarray


def load_pair(folder: Path) -> Pair:
    linear = read_exr(folder / "input.exr", 3)
    depth = read_exr(folder / "depth.exr", 1)[..., 0]
    if depth.shape != linear.shape[:2]:
        raise DatasetError(
            f"{folder / 'depth.exr'}: {depth.shape[1]}x{depth.shape[0]}, "
            f"input.exr is {linear.shape[1]}x{linear.shape[0]}"
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        disparity = np.where(np.isfinite(depth) & (depth > 0), 1.0 / depth, 0.0)
    return Pair(np.maximum(linear, 0).astype(np.float16), disparity.astype(np.float32))


def photo(linear: np.ndarray, exposure: float, gamma: float) -> np.ndarray:
    """8-bit-rounded tone-mapped RGB in [0, 1], float32."""
    x = np.clip((linear.astype(np.float32) * exposure) ** (1.0 / gamma), 0.0, 1.0)
    return np.round(x * 255.0) / 255.0


class Cache:
    """Pairs loaded once and kept (a 384x288 pair is about 1 MB)."""

    def __init__(self):
        self.pairs: dict[Path, Pair] = {}

    def get(self, folder: Path) -> Pair:
        if folder not in self.pairs:
            self.pairs[folder] = load_pair(folder)
        return self.pairs[folder]


def training_crop(pair: Pair, size: tuple[int, int], rng: np.random.Generator):
    """(photo [3, h, w], disparity [h, w]) of a random crop of `size` (h, w), random
    exposure, gamma and left-right mirror."""
    h, w = size
    height, width = pair.disparity.shape
    if height < h or width < w:
        raise DatasetError(f"example of {width}x{height} is smaller than the {w}x{h} crop")
    y = int(rng.integers(0, height - h + 1))
    x = int(rng.integers(0, width - w + 1))
    exposure = float(np.exp(rng.uniform(*np.log(EXPOSURE_RANGE))))
    gamma = float(rng.uniform(*GAMMA_RANGE))
    rgb = photo(pair.linear[y : y + h, x : x + w], exposure, gamma)
    disparity = pair.disparity[y : y + h, x : x + w]
    if rng.random() < 0.5:
        rgb, disparity = rgb[:, ::-1], disparity[:, ::-1]
    return np.ascontiguousarray(rgb.transpose(2, 0, 1)), np.ascontiguousarray(disparity)


def evaluation_image(pair: Pair, multiple: int = 32):
    """The whole example at the evaluation's tone mapping, cropped to a multiple of 32."""
    height, width = pair.disparity.shape
    h, w = height // multiple * multiple, width // multiple * multiple
    rgb = photo(pair.linear[:h, :w], EVAL_EXPOSURE, EVAL_GAMMA)
    return np.ascontiguousarray(rgb.transpose(2, 0, 1)), pair.disparity[:h, :w].copy()
