"""`reshader-train teacher-check`: how well a taught lobes-slide network picks out the
light its teacher's sliding layer picks out, on training examples as they are (no
augmentation).

The taught runs of the model card lower the view loss slowly while the teacher's distance
(`train --teacher`, an L1 on fields that are zero almost everywhere) hardly moves. This
separates the two things that distance mixes: *where* the network puts its sliding layer
(the correlation of its fraction with the teacher's, and the share of the teacher's fraction
that lies in the network's top tenth of pixels: 0.1 by chance, 1 when the network's
brightest tenth holds all of it) and *how much* (the two mean fractions).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch

from .data import DatasetError, ReshadeDataset, teacher_settings
from .evaluate import load_checkpoint_model, pad_to_multiple

TOP = 0.9


def selection(network: np.ndarray, teacher: np.ndarray) -> dict[str, float]:
    """Agreement of two per-pixel fraction maps (same shape): correlation, the teacher's
    share in the network's top tenth, and each one's mean."""
    n, t = network.ravel().astype(np.float64), teacher.ravel().astype(np.float64)
    top = np.argsort(n, kind="stable")[round(TOP * n.size) :]
    corr = float(np.corrcoef(n, t)[0, 1]) if np.ptp(n) > 0 and np.ptp(t) > 0 else 0.0
    return {
        "correlation": corr,
        "teacher_share_in_top_tenth": float(t[top].sum() / max(t.sum(), 1e-12)),
        "network_mean": float(n.mean()),
        "teacher_mean": float(t.mean()),
    }


@torch.no_grad()
def check(net, data: Path, teacher: Path, count: int, seed: int) -> list[dict]:
    """`selection` of the sliding fraction (mean over colours) on up to `count` examples
    drawn with `seed`, skipping those whose teacher slides nothing."""
    lobes = teacher_settings(teacher)["lobes"]
    if lobes != net.cfg.lobes:
        raise ValueError(f"{teacher}: fields of {lobes} lobe(s), the network has {net.cfg.lobes}")
    ds = ReshadeDataset(data, teacher=teacher, targets=2)
    picks = np.random.default_rng(seed).permutation(len(ds))[:count]
    rows = []
    layer = slice(7 * lobes, 7 * lobes + 3)  # the sliding fraction's three colours
    for idx in picks:
        s = ds[int(idx)]
        taught = s["teacher"][layer].mean(0).numpy()
        if taught.mean() < 1e-4:
            continue
        h, w = s["image"].shape[-2:]
        _, fields = net(
            pad_to_multiple(s["image"][None]),
            pad_to_multiple(s["disparity"][None]),
            s["cameras"][None],
            pad_to_multiple(s["rays"][None]),
            fields=True,
        )
        mine = fields[0, layer, :h, :w].mean(0).numpy()
        rows.append({"example": ds.example(int(idx)).name, **selection(mine, taught)})
    return rows


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--checkpoint", type=Path, required=True, help="a lobes-slide checkpoint")
    p.add_argument("--data", type=Path, required=True, help="the training examples")
    p.add_argument("--teacher", type=Path, required=True, help="their fitted fields")
    p.add_argument("--count", type=int, default=40, help="examples drawn (default 40)")
    p.add_argument("--seed", type=int, default=0, help="which examples (default 0)")
    p.add_argument("--json", type=Path, help="write the per-example rows and the means")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")


def run(args: argparse.Namespace) -> int:
    torch.set_num_threads(max(1, args.threads))
    try:
        net, _ = load_checkpoint_model(args.checkpoint)
        if net.cfg.head != "lobes-slide":
            raise ValueError(f"{args.checkpoint}: a {net.cfg.head} head has no sliding layer")
        rows = check(net, args.data, args.teacher, args.count, args.seed)
    except (FileNotFoundError, ValueError, DatasetError) as err:
        print(f"teacher-check: {err}", file=sys.stderr)
        return 2
    if not rows:
        print("teacher-check: no drawn example has a sliding teacher", file=sys.stderr)
        return 1
    means = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "example"}
    print(
        f"{args.checkpoint}: {len(rows)} examples with a sliding teacher; fraction correlation "
        f"{means['correlation']:.3f}; the teacher's share in the network's top tenth "
        f"{means['teacher_share_in_top_tenth']:.3f} (chance {1 - TOP:.1f}); mean fraction: "
        f"network {means['network_mean']:.4f}, teacher {means['teacher_mean']:.4f}"
    )
    if args.json:
        tmp = args.json.with_name(f".{args.json.name}.tmp")
        tmp.write_text(json.dumps({"means": means, "examples": rows}, indent=2))
        os.replace(tmp, args.json)
    return 0
