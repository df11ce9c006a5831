"""Rendered photos with their true depth, as the depth network sees photos.

Any example folder with input.exr and depth.exr serves (`render --input-only` writes just
those). A photo is the linear render tone-mapped by clamp((x * exposure)^(1/gamma), 0, 1)
and rounded to 8 bits, as `reshader eval-relocation` makes it (exposure 5.5, gamma 2.2);
training draws exposure and gamma per crop (the paper's augmentation, narrowed to gammas
photos have). The target is disparity 1/depth (0 where a ray missed the scene).

Decals (`decals`): patterns painted onto a crop's linear light, as albedo or a cast shadow
would be, without changing its depth. The renders' dark patterns are mostly depth (gaps,
recesses, the shadow under an object) and their textures never are, so a network tuned
on them alone learns to read depth from dark shapes, which photos use for anything (a
carved face, a leaded window, lettering).
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


def _soften(mask: np.ndarray) -> np.ndarray:
    """A 3x3 box blur: antialiased edges, as a photo's are."""
    padded = np.pad(mask, 1, mode="edge")
    h, w = mask.shape
    return sum(padded[i : i + h, j : j + w] for i in range(3) for j in range(3)) / 9.0


def _shape(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """One random shape's coverage in [0, 1]: a convex polygon, an ellipse, a thick arc
    or a lattice of lines inside an ellipse."""
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    cy, cx = rng.uniform(0, h), rng.uniform(0, w)
    radius = float(np.exp(rng.uniform(np.log(6), np.log(0.45 * min(h, w)))))
    kind = rng.integers(4)
    if kind == 0:
        angles = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 7)))
        r = radius * rng.uniform(0.5, 1.0, angles.size)
        py, px = cy + r * np.sin(angles), cx + r * np.cos(angles)
        inside = np.ones((h, w), bool)
        for i in range(angles.size):
            j = (i + 1) % angles.size
            inside &= (px[j] - px[i]) * (yy - py[i]) - (py[j] - py[i]) * (xx - px[i]) >= 0
        return _soften(inside.astype(np.float32))
    theta = rng.uniform(0, np.pi)
    u = (xx - cx) * np.cos(theta) + (yy - cy) * np.sin(theta)
    v = -(xx - cx) * np.sin(theta) + (yy - cy) * np.cos(theta)
    aspect = rng.uniform(0.3, 1.0)
    ellipse = (u / radius) ** 2 + (v / (radius * aspect)) ** 2 <= 1
    if kind == 1:
        return _soften(ellipse.astype(np.float32))
    if kind == 2:
        bend = rng.uniform(-1, 1) * radius
        t = np.linspace(-1, 1, 24)
        pu, pv = t * radius, bend * (1 - t**2)
        near = np.min((u[..., None] - pu) ** 2 + (v[..., None] - pv) ** 2, axis=-1)
        return _soften((near <= rng.uniform(1.5, 6) ** 2).astype(np.float32))
    period = rng.uniform(5, 16)
    width = rng.uniform(1, 2.5) / period
    turn = rng.uniform(0.3, 1.3)
    lattice = np.zeros((h, w), bool)
    for a in (u + v * turn, u - v * turn):
        lattice |= np.abs((a / period) % 1.0 - 0.5) > 0.5 - width
    return _soften((ellipse & lattice).astype(np.float32))


def paint_decals(linear: np.ndarray, rng: np.random.Generator, count: int) -> np.ndarray:
    """`count` random shapes multiplied into linear RGB (H x W x 3): mostly dark (a
    factor of 0.02-0.4, tinted), a fifth bright (1.5-3)."""
    out = linear.astype(np.float32)
    for _ in range(count):
        coverage = _shape(out.shape[:2], rng)[..., None]
        if rng.random() < 0.8:
            factor = rng.uniform(0.02, 0.4) * rng.uniform(0.7, 1.3, 3)
        else:
            factor = rng.uniform(1.5, 3.0) * rng.uniform(0.8, 1.2, 3)
        out *= 1.0 + coverage * (factor.astype(np.float32) - 1.0)
    return out


def training_crop(pair: Pair, size: tuple[int, int], rng: np.random.Generator, decals: float = 0.0):
    """(photo [3, h, w], disparity [h, w]) of a random crop of `size` (h, w), random
    exposure, gamma and left-right mirror; with probability `decals`, one to four decals
    painted on it."""
    h, w = size
    height, width = pair.disparity.shape
    if height < h or width < w:
        raise DatasetError(f"example of {width}x{height} is smaller than the {w}x{h} crop")
    y = int(rng.integers(0, height - h + 1))
    x = int(rng.integers(0, width - w + 1))
    exposure = float(np.exp(rng.uniform(*np.log(EXPOSURE_RANGE))))
    gamma = float(rng.uniform(*GAMMA_RANGE))
    linear = pair.linear[y : y + h, x : x + w]
    if rng.random() < decals:
        linear = paint_decals(linear, rng, int(rng.integers(1, 5)))
    rgb = photo(linear, exposure, gamma)
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
