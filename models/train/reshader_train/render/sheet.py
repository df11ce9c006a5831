"""`reshader-train sheet`: a contact sheet PNG of a rendered dataset for a person to inspect.

One row per example: input | reshaded | |reshaded - input| (x4) | validity mask
(and the novel view with --novel). Each row is exposed so that its input's 95th
percentile luminance maps to 0.9, then sRGB-encoded.
"""

import os
import sys

import numpy as np

DIFF_GAIN = 4.0


def add_arguments(parser) -> None:
    parser.add_argument("dataset", help="dataset folder written by `reshader-train render`")
    parser.add_argument("--out", required=True, help="PNG file to write")
    parser.add_argument("--count", type=int, default=8, help="examples to show (default 8)")
    parser.add_argument("--start", type=int, default=0, help="skip this many examples first")
    parser.add_argument("--novel", action="store_true", help="add the novel view as a column")
    parser.add_argument(
        "--downscale", type=int, default=1, help="shrink by this integer factor (box filter)"
    )


def _srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _read(mi, path: str) -> np.ndarray:
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: missing (is this a complete example folder?)")
    image = np.array(mi.Bitmap(path), dtype=np.float32)
    return image if image.ndim == 3 else image[..., None]


def example_row(mi, folder: str, with_novel: bool = False) -> np.ndarray:
    """The tone-mapped tiles of one example side by side, float RGB in [0, 1]."""
    inp = _read(mi, os.path.join(folder, "input.exr"))
    resh = _read(mi, os.path.join(folder, "reshaded.exr"))
    mask = _read(mi, os.path.join(folder, "mask.png")) / 255.0
    lum = inp @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    exposure = 0.9 / max(float(np.percentile(lum, 95)), 1e-6)
    tiles = [
        _srgb(inp * exposure),
        _srgb(resh * exposure),
        _srgb(np.abs(resh - inp) * exposure * DIFF_GAIN),
        np.repeat(mask, 3, axis=-1),
    ]
    if with_novel:
        tiles.append(_srgb(_read(mi, os.path.join(folder, "novel.exr")) * exposure))
    gap = np.ones((inp.shape[0], 2, 3), dtype=np.float32)
    row = [tiles[0]]
    for tile in tiles[1:]:
        row += [gap, tile]
    return np.concatenate(row, axis=1)


def complete_examples(dataset: str) -> list[str]:
    """Sorted ids of complete examples (a folder with meta.json; temp folders excluded)."""
    if not os.path.isdir(dataset):
        raise FileNotFoundError(f"{dataset}: not a directory")
    return sorted(
        name
        for name in os.listdir(dataset)
        if not name.startswith(".") and os.path.isfile(os.path.join(dataset, name, "meta.json"))
    )


def make_sheet(mi, dataset: str, count: int, start: int = 0, with_novel: bool = False):
    ids = complete_examples(dataset)[start : start + count]
    if not ids:
        raise ValueError(f"{dataset}: no complete examples (folders with meta.json) to show")
    rows = [example_row(mi, os.path.join(dataset, i), with_novel) for i in ids]
    width = max(r.shape[1] for r in rows)
    padded = []
    for r in rows:
        r = np.pad(r, ((0, 2), (0, width - r.shape[1]), (0, 0)), constant_values=1.0)
        padded.append(r)
    return np.concatenate(padded, axis=0), ids


def downscale(image: np.ndarray, k: int) -> np.ndarray:
    """Box-filter shrink by an integer factor (edges that do not fill a box are cut)."""
    h, w = image.shape[0] // k * k, image.shape[1] // k * k
    return image[:h, :w].reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def run(args) -> int:
    from .mitsuba_env import LlvmNotFound, load_mitsuba

    if args.count < 1 or args.downscale < 1:
        print("reshader-train sheet: --count and --downscale must be >= 1", file=sys.stderr)
        return 2
    try:
        mi = load_mitsuba()
        sheet, ids = make_sheet(mi, args.dataset, args.count, args.start, args.novel)
    except (FileNotFoundError, ValueError, LlvmNotFound) as err:
        print(f"reshader-train sheet: {err}", file=sys.stderr)
        return 2
    sheet = downscale(sheet, args.downscale)
    image = np.round(sheet * 255).astype(np.uint8)
    tmp = f"{args.out}.tmp.png"
    mi.Bitmap(image, mi.Bitmap.PixelFormat.RGB).write(tmp)
    os.replace(tmp, args.out)
    print(f"wrote {args.out}: {len(ids)} examples ({ids[0]} .. {ids[-1]})")
    return 0
