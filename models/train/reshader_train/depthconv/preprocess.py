"""The Tiefenrausch input convention: RGB photo -> area-resized NCHW float32 in [0, 1].

Matches the original implementation: the longer side becomes 384 and the other keeps the
aspect ratio (truncated to an integer), each side is rounded down to a multiple of 32, and the
uint8 photo is area-averaged to that size (rounded back to uint8) before dividing by 255.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

LONG_SIDE = 384
MULTIPLE = 32


def network_size(height: int, width: int) -> tuple[int, int]:
    """(rows, columns) the network sees for a photo of the given size."""
    if height <= 0 or width <= 0:
        raise ValueError(f"photo size {height}x{width} is empty")
    if height > width:
        nh, nw = LONG_SIDE, int(width * LONG_SIDE / height)
    else:
        nw, nh = LONG_SIDE, int(height * LONG_SIDE / width)
    nh, nw = nh - nh % MULTIPLE, nw - nw % MULTIPLE
    if nh == 0 or nw == 0:
        raise ValueError(f"photo {height}x{width} is too elongated for a {LONG_SIDE}px network")
    return nh, nw


def _area_taps(src: int, dst: int) -> tuple[np.ndarray, np.ndarray]:
    """Source indices and float32 weights [dst, taps] of the input interval each output covers.

    Partial overlaps below 1e-3 of a pixel are dropped and the weights are float32, as in
    OpenCV's INTER_AREA, so that the result is bit-identical to the original preprocessing.
    """
    scale = src / dst
    taps = []
    for d in range(dst):
        lo, hi = d * scale, (d + 1) * scale
        first, last = int(np.ceil(lo)), int(np.floor(hi))
        row = []
        if first - lo > 1e-3:
            row.append((first - 1, (first - lo) / scale))
        row += [(s, 1.0 / scale) for s in range(first, last)]
        if hi - last > 1e-3 and last < src:
            row.append((last, (hi - last) / scale))
        taps.append(row)
    width = max(len(row) for row in taps)
    index = np.zeros((dst, width), np.int64)
    weight = np.zeros((dst, width), np.float32)
    for d, row in enumerate(taps):
        for k, (s, w) in enumerate(row):
            index[d, k], weight[d, k] = s, w
    return index, weight


def _block_mean(image: np.ndarray, fy: int, fx: int) -> np.ndarray:
    """Integer shrink factors: exact integer block sums, rounded as OpenCV's fast path does."""
    h, w, c = image.shape[0] // fy, image.shape[1] // fx, image.shape[2]
    sums = image.astype(np.int64).reshape(h, fy, w, fx, c).sum(axis=(1, 3))
    if fy * fx == 4:
        return ((sums + 2) >> 2).astype(np.uint8)
    return np.rint(sums.astype(np.float32) * np.float32(1 / (fy * fx))).astype(np.uint8)


def area_resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """Area-average a uint8 HxWxC image down to height x width, rounding to uint8.

    Sums run in float32 in source order, rows first, matching the original implementation
    (OpenCV INTER_AREA) bit for bit; the network is sensitive to one-level input changes.
    """
    if height > image.shape[0] or width > image.shape[1]:
        raise ValueError("area resize only shrinks")
    if image.shape[0] % height == 0 and image.shape[1] % width == 0:
        return _block_mean(image, image.shape[0] // height, image.shape[1] // width)
    yi, yw = _area_taps(image.shape[0], height)
    xi, xw = _area_taps(image.shape[1], width)
    src = image.astype(np.float32)
    rows = np.zeros((image.shape[0], width, image.shape[2]), np.float32)
    for k in range(xi.shape[1]):
        rows += src[:, xi[:, k], :] * xw[None, :, k, None]
    out = np.zeros((height, width, image.shape[2]), np.float32)
    for k in range(yi.shape[1]):
        out += yw[:, k, None, None] * rows[yi[:, k]]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def load_rgb(path: Path) -> np.ndarray:
    """Decode a photo to uint8 RGB HxWx3, naming the file on failure."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except (OSError, UnidentifiedImageError) as err:
        raise ValueError(f"{path}: cannot read photo: {err}") from err


def network_input(rgb: np.ndarray) -> np.ndarray:
    """1x3xHxW float32 tensor for the network from a uint8 RGB photo."""
    nh, nw = network_size(rgb.shape[0], rgb.shape[1])
    small = area_resize(rgb, nh, nw)
    return (small.astype(np.float32) / np.float32(255.0)).transpose(2, 0, 1)[None].copy()
