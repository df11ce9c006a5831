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


def _area_weights(src: int, dst: int) -> np.ndarray:
    """[dst, src] matrix: each output pixel averages the input interval it covers."""
    scale = src / dst
    edges = np.arange(dst + 1) * scale
    lo, hi = edges[:-1, None], edges[1:, None]
    left = np.arange(src)[None, :]
    overlap = np.clip(np.minimum(hi, left + 1) - np.maximum(lo, left), 0, None)
    return overlap / scale


def area_resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """Area-average a uint8 HxWxC image down to height x width, rounding to uint8."""
    if height > image.shape[0] or width > image.shape[1]:
        raise ValueError("area resize only shrinks")
    rows = _area_weights(image.shape[0], height)
    cols = _area_weights(image.shape[1], width)
    tmp = np.tensordot(rows, image.astype(np.float64), axes=(1, 0))
    out = np.tensordot(cols, tmp, axes=(1, 1)).transpose(1, 0, 2)
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
