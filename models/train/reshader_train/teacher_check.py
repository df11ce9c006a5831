"""`reshader-train teacher-check`: how well a taught lobes or lobes-slide network picks out
the light its teacher's fields pick out, on examples as they are (no augmentation).

The taught runs of the model card lower the view loss slowly while the teacher's distance
(`train --teacher`, an L1 on fields that are zero almost everywhere) hardly moves. This
separates the two things that distance mixes: *where* the network puts its sliding layer
(the correlation of its fraction with the teacher's, and the share of the teacher's fraction
that lies in the network's top tenth of pixels: 0.1 by chance, 1 when the network's
brightest tenth holds all of it) and *how much* (the two mean fractions).

For a "lobes" network (the renderer's lobes, `teacher --source renderer`) it says the same
of the lobes: at the pixels the teacher lights (a lobe of at least AMPLITUDE_SEEN) the
median amplitude of each, in log10, the network's at the others, the same of the share
of the pixel's light each lobe holds at the photo's view (u/(1 + u), `losses.light_share`),
and how well the lit pixels' axes and sharpnesses agree.
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


def lobe_agreement(
    network: np.ndarray, teacher: np.ndarray, shares: tuple[np.ndarray, np.ndarray]
) -> dict[str, float] | None:
    """How the first lobe of two (7K, H, W) field maps agree where the teacher's shines
    (None if nowhere): median log10 amplitudes (mean of the colours) there, the network's
    elsewhere, the same of their `shares` (network's, teacher's: (H, W) each), the mean
    cosine of the axes and the median log10 sharpness ratio there."""
    from .model import AMPLITUDE_SEEN

    amp_n, amp_t = network[4:7].mean(0), teacher[4:7].mean(0)
    lit = amp_t > AMPLITUDE_SEEN
    if not lit.any():
        return None
    log = np.log10
    share_n, share_t = shares
    return {
        "network_share_lit": float(np.median(share_n[lit])),
        "teacher_share_lit": float(np.median(share_t[lit])),
        "network_share_unlit": float(np.median(share_n[~lit])) if (~lit).any() else float("nan"),
        "lit_share": float(lit.mean()),
        "network_amplitude_lit": float(np.median(log(np.maximum(amp_n[lit], 1e-30)))),
        "teacher_amplitude_lit": float(np.median(log(amp_t[lit]))),
        "network_amplitude_unlit": float(np.median(log(np.maximum(amp_n[~lit], 1e-30))))
        if (~lit).any()
        else float("nan"),
        "axis_cosine_lit": float((network[0:3] * teacher[0:3]).sum(0)[lit].mean()),
        "sharpness_ratio_lit": float(np.median(log(network[3][lit] / teacher[3][lit]))),
    }


def first_lobe_shares(
    network: torch.Tensor, teacher: torch.Tensor, image: torch.Tensor, rays: torch.Tensor
) -> tuple[np.ndarray, np.ndarray]:
    """`light_share` of the first lobe of (1, 7K, H, W) fields, network's and teacher's,
    for the photo `image` (1,3,H,W) and its `rays`, mean of the colours: (H, W) each."""
    from .losses import light_share
    from .model import linear_light, photo_directions

    linear, w0 = linear_light(image), photo_directions(rays)
    return tuple(light_share(f[:, :7], linear, w0)[0].mean(0).numpy() for f in (network, teacher))


def compare(
    head: str,
    lobes: int,
    network: np.ndarray,
    teacher: np.ndarray,
    shares: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict | None:
    """The head's agreement with its teacher on one example (None: nothing to compare);
    `shares` (head lobes): the first lobes' `first_lobe_shares`."""
    if head == "lobes":
        return lobe_agreement(network, teacher, shares)
    layer = slice(7 * lobes, 7 * lobes + 3)  # the sliding fraction's three colours
    taught = teacher[layer].mean(0)
    if taught.mean() < 1e-4:
        return None
    return selection(network[layer].mean(0), taught)


@torch.no_grad()
def check(net, data: Path, teacher: Path, count: int, seed: int) -> list[dict]:
    """`compare` on up to `count` examples drawn with `seed`, skipping those whose teacher
    slides or lights nothing."""
    lobes = teacher_settings(teacher)["lobes"]
    if lobes != net.cfg.lobes:
        raise ValueError(f"{teacher}: fields of {lobes} lobe(s), the network has {net.cfg.lobes}")
    ds = ReshadeDataset(data, teacher=teacher, targets=2)
    picks = np.random.default_rng(seed).permutation(len(ds))[:count]
    rows = []
    for idx in picks:
        s = ds[int(idx)]
        h, w = s["image"].shape[-2:]
        _, fields = net(
            pad_to_multiple(s["image"][None]),
            pad_to_multiple(s["disparity"][None]),
            s["cameras"][None],
            pad_to_multiple(s["rays"][None]),
            fields=True,
        )
        fields = fields[:, :, :h, :w]
        shares = None
        if net.cfg.head == "lobes":
            shares = first_lobe_shares(
                fields, s["teacher"][None], s["image"][None], s["rays"][None]
            )
        row = compare(net.cfg.head, lobes, fields[0].numpy(), s["teacher"].numpy(), shares)
        if row is not None:
            rows.append({"example": ds.example(int(idx)).name, **row})
    return rows


def summary_line(head: str, count: int, means: dict[str, float]) -> str:
    if head == "lobes":
        return (
            f"{count} examples with a lit teacher ({means['lit_share']:.0%} of their pixels); "
            f"median log10 amplitude where lit: network {means['network_amplitude_lit']:.2f}, "
            f"teacher {means['teacher_amplitude_lit']:.2f}; elsewhere network "
            f"{means['network_amplitude_unlit']:.2f}; median share of the pixel's light "
            f"(u/(1+u)) where lit: network {means['network_share_lit']:.3f}, teacher "
            f"{means['teacher_share_lit']:.3f}; elsewhere network "
            f"{means['network_share_unlit']:.3f}; axis cosine where lit "
            f"{means['axis_cosine_lit']:.3f}; log10 sharpness ratio "
            f"{means['sharpness_ratio_lit']:+.2f}"
        )
    return (
        f"{count} examples with a sliding teacher; fraction correlation "
        f"{means['correlation']:.3f}; the teacher's share in the network's top tenth "
        f"{means['teacher_share_in_top_tenth']:.3f} (chance {1 - TOP:.1f}); mean fraction: "
        f"network {means['network_mean']:.4f}, teacher {means['teacher_mean']:.4f}"
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--checkpoint", type=Path, required=True, help="a lobes-slide or lobes checkpoint"
    )
    p.add_argument("--data", type=Path, required=True, help="the examples (training or held out)")
    p.add_argument("--teacher", type=Path, required=True, help="their fitted fields")
    p.add_argument("--count", type=int, default=40, help="examples drawn (default 40)")
    p.add_argument("--seed", type=int, default=0, help="which examples (default 0)")
    p.add_argument("--json", type=Path, help="write the per-example rows and the means")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")


def run(args: argparse.Namespace) -> int:
    torch.set_num_threads(max(1, args.threads))
    try:
        net, _ = load_checkpoint_model(args.checkpoint)
        if net.cfg.head not in ("lobes-slide", "lobes"):
            raise ValueError(f"{args.checkpoint}: a {net.cfg.head} head has no fields to check")
        rows = check(net, args.data, args.teacher, args.count, args.seed)
    except (FileNotFoundError, ValueError, DatasetError) as err:
        print(f"teacher-check: {err}", file=sys.stderr)
        return 2
    if not rows:
        print("teacher-check: no drawn example has a sliding or lit teacher", file=sys.stderr)
        return 1
    means = {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0] if k != "example"}
    print(f"{args.checkpoint}: {summary_line(net.cfg.head, len(rows), means)}")
    if args.json:
        tmp = args.json.with_name(f".{args.json.name}.tmp")
        tmp.write_text(json.dumps({"means": means, "examples": rows}, indent=2))
        os.replace(tmp, args.json)
    return 0
