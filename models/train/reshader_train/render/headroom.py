"""`reshader-train headroom`: how much any network could gain on examples rendered like ours.

The network sees the input render and is scored against the ground-truth reshaded render
of the same samples. Their difference is partly the change of shading between the two
cameras, which a network can learn, and partly Monte-Carlo noise, which it cannot: the
two renders share their random numbers, but their paths part after the first hit. This
command re-renders examples exactly as `render` does (same dataset seed, indices, size,
spp and sample seed) and, with `--repeats` further sample seeds, estimates the noise-free
change as the mean of (reshaded - input) over those seeds. It scores against the usual
ground truth (sample seed 0):

- Input: the input render (no reshading), as `evaluate` does;
- Oracle: the input plus the estimated noise-free change, the output of a network that
  learned the change perfectly (up to the noise left in a mean of `--repeats` renders);
- Noise: a second render of the ground truth with another seed, i.e. how far two
  correct images of this example are apart at this spp;
- with `--deadzone D`, the Oracle's change (in the evaluation's display encoding, where
  the network's residual lives) shrunk by D as the network's head shrinks its residual:
  how much of the headroom a network with that dead zone can reach at best.

Metrics as in `evaluate`: fixed tone mapping, masked by validity, mean / median / pooled.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ..evaluate import (
    format_table,
    masked_mse,
    masked_ssim,
    psnr_of_mse,
    split_by_change,
    summarise,
)
from ..model import shrink
from ..tonemap import EVAL_EXPOSURE, EVAL_GAMMA, tonemap
from .command import parse_settings, release_caches
from .example import brightness_scale, seed_pairs, setup_example


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=int, default=1001, help="dataset seed (default 1001: val)")
    p.add_argument("--count", type=int, default=24, help="examples 0..COUNT-1 (default 24)")
    p.add_argument("--size", default="160x160", help="WIDTHxHEIGHT (default 160x160)")
    p.add_argument("--spp", type=int, default=256, help="samples per pixel (default 256)")
    p.add_argument(
        "--repeats",
        type=int,
        default=8,
        help="extra sample seeds for the noise-free change (default 8)",
    )
    p.add_argument(
        "--radius", default="0.1,0.3", help="novel camera shell radii MIN,MAX (default 0.1,0.3)"
    )
    p.add_argument(
        "--family",
        default="mixed",
        help="procedural scene family: mixed (default), highlights, studio, products, rooms "
        "or diffuse (see render --scenes)",
    )
    p.add_argument(
        "--deadzone",
        type=float,
        default=0.0,
        help="also score the Oracle's change shrunk by this dead zone, as the network's "
        "head shrinks its residual (e.g. 0.008, the shipped model's; default 0: not scored)",
    )
    p.add_argument("--threads", type=int, default=None, help="Dr.Jit threads (default all)")
    p.add_argument("--json", type=Path, help="write the summary and per-example rows as JSON")


def _chw(hdr: np.ndarray) -> torch.Tensor:
    ldr = tonemap(hdr.astype(np.float32), EVAL_EXPOSURE, EVAL_GAMMA)
    return torch.from_numpy(np.ascontiguousarray(ldr.transpose(2, 0, 1)))


def example_row(
    mi, source, seed: int, index: int, settings, repeats: int, deadzone: float = 0.0
) -> dict:
    """Input / Oracle / Noise (and, with a dead zone, the Oracle through it) metrics of
    one example against its ground truth."""
    from .integrator import make_path, make_reshade

    ex = setup_example(mi, source, seed, index, settings)
    path = make_path(ex.params["max_depth"])
    reshade = make_reshade(ex.novel_cam, ex.input_cam, ex.params["max_depth"])
    seeds = range(ex.render_seed, ex.render_seed + repeats + 1)
    pairs = list(seed_pairs(ex.scene, ex.input_cam, settings.spp, seeds, path, reshade))
    inputs = [image for image, _ in pairs]
    truths = [truth[..., :3] for _, truth in pairs]
    invalid = pairs[0][1][..., 3]
    scale = brightness_scale(inputs[0])
    change = np.mean([t - i for t, i in zip(truths[1:], inputs[1:], strict=True)], axis=0)
    target = _chw(truths[0] * scale)
    mask = torch.from_numpy((invalid == 0).astype(np.float32))[None]
    row = {"split": "headroom", "scene": ex.params.get("kind", "all"), "example": index}
    row["valid_values"] = int((mask.expand_as(target) > 0.5).sum())
    images = {
        method: _chw(hdr * scale)
        for method, hdr in (
            ("input", inputs[0]),
            ("ours", inputs[0] + change),
            ("noise", truths[1]),
        )
    }
    if deadzone > 0.0:
        moved = images["ours"] - images["input"]
        images["deadzone"] = images["input"] + shrink(moved, deadzone)
    for method, img in images.items():
        row[f"mse_{method}"] = masked_mse(img, target, mask)
        row[f"psnr_{method}"] = psnr_of_mse(row[f"mse_{method}"])
        row[f"ssim_{method}"] = masked_ssim(img, target, mask)
    return row


def deadzone_line(rows: list[dict], deadzone: float) -> str:
    """Mean PSNR gain of the Oracle and of the Oracle through the dead zone, over the
    views whose shading changes and the others (`evaluate`'s split)."""

    def gain(part: list[dict], method: str) -> str:
        if not part:
            return "-"
        return f"{np.mean([r[f'psnr_{method}'] - r['psnr_input'] for r in part]):+.2f} dB"

    parts = split_by_change(rows)
    return "; ".join(
        f"{name} (n={len(part)}): Oracle {gain(part, 'ours')}, through a dead zone of "
        f"{deadzone:g} {gain(part, 'deadzone')}"
        for name, part in parts.items()
    )


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from .mitsuba_env import LlvmNotFound, load_mitsuba
    from .sources import ProceduralSource

    try:
        if args.repeats < 1:
            raise ValueError("--repeats must be at least 1")
        if not 0.0 <= args.deadzone < 0.5:
            raise ValueError(f"--deadzone {args.deadzone}: must be in [0, 0.5)")
        settings = parse_settings(args)
        source = ProceduralSource(args.family)
        mi = load_mitsuba(args.threads)
    except (ValueError, LlvmNotFound) as err:
        print(f"reshader-train headroom: {err}", file=sys.stderr)
        return 2
    source.prepare(mi)
    print(
        f"headroom: {source.name}, seed {args.seed}, examples 0..{args.count - 1}, "
        f"{args.size} at {args.spp} spp, {args.repeats} extra sample seeds "
        f"({2 * (args.repeats + 1)} renders each)",
        flush=True,
    )
    start = time.perf_counter()
    rows = []
    for index in tqdm(range(args.count), unit="ex", dynamic_ncols=True, mininterval=5):
        rows.append(
            example_row(mi, source, args.seed, index, settings, args.repeats, args.deadzone)
        )
        release_caches()
    summary = summarise(rows)
    print(format_table(summary, None, labels=("Input", "Oracle")))
    for name, m in summary.items():
        print(f"{name}: Noise (a second render of the truth) {m['psnr_noise']:.2f} dB mean PSNR")
    if args.deadzone > 0.0:
        print(deadzone_line(rows, args.deadzone))
    print(f"{time.perf_counter() - start:.0f} s")
    if args.json:
        report = {"args": {k: str(v) for k, v in vars(args).items() if not k.startswith("_")}}
        report.update(splits=summary, examples=rows)
        tmp = args.json.with_name(f".{args.json.name}.tmp")
        tmp.write_text(json.dumps(report, indent=2))
        os.replace(tmp, args.json)
    return 0
