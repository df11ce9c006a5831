"""A tiny synthetic dataset in the rendered dataset's layout, for tests (no Mitsuba needed).

Each example is a smooth HDR image with a highlight blob; the "reshaded" image moves the
blob by an amount proportional to the camera offset, so there is something to learn.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def write_exr(path: Path, planes: dict[str, np.ndarray]) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {k: np.ascontiguousarray(v, np.float32) for k, v in planes.items()}).write(
        str(path)
    )


def write_example(folder: Path, rng: np.random.Generator, height: int, width: int) -> None:
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    base = rng.uniform(0.02, 0.08, 3).astype(np.float32)
    ramp = (xx / width)[..., None] * rng.uniform(0.0, 0.05, 3).astype(np.float32)
    offset = rng.uniform(-0.3, 0.3, 3).astype(np.float32)
    cy, cx = rng.uniform(0.3, 0.7) * height, rng.uniform(0.3, 0.7) * width
    radius = 0.12 * min(height, width)

    def blob(y: float, x: float) -> np.ndarray:
        return (0.3 * np.exp(-((yy - y) ** 2 + (xx - x) ** 2) / (2 * radius**2)))[..., None]

    shift = 0.3 * min(height, width)
    image = base + ramp + blob(cy, cx)
    reshaded = base + ramp + blob(cy + shift * offset[1], cx + shift * offset[0])
    depth = np.full((height, width), rng.uniform(1.0, 5.0), np.float32)
    depth[: height // 4] = np.inf  # sky: a miss
    mask = np.full((height, width), 255, np.uint8)
    mask[:, :2] = 0
    write_exr(folder / "input.exr", {"R": image[..., 0], "G": image[..., 1], "B": image[..., 2]})
    write_exr(
        folder / "reshaded.exr",
        {"R": reshaded[..., 0], "G": reshaded[..., 1], "B": reshaded[..., 2]},
    )
    write_exr(folder / "novel.exr", {"R": image[..., 0], "G": image[..., 1], "B": image[..., 2]})
    write_exr(folder / "depth.exr", {"Y": depth})
    Image.fromarray(mask).save(folder / "mask.png")
    fx = 0.5 * width / np.tan(np.radians(30.0))  # a 60 degree horizontal field of view
    camera = {"fx": fx, "fy": fx, "cx": (width - 1) / 2, "cy": (height - 1) / 2}
    meta = {
        "novel_offset": offset.tolist(),
        "input_camera": camera,
        "scene": "synthetic",
        "width": width,
        "height": height,
    }
    (folder / "meta.json").write_text(json.dumps(meta))


def write_dataset(root: Path, count: int, height: int = 32, width: int = 32, seed: int = 0) -> Path:
    """`count` complete examples plus one unfinished `.tmp-*` folder that readers must skip."""
    rng = np.random.default_rng(seed)
    root = Path(root)
    for i in range(count):
        write_example(root / f"{i:05d}", rng, height, width)
    (root / f".tmp-{count:05d}").mkdir(parents=True, exist_ok=True)
    return root
