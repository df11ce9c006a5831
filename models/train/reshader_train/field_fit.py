"""`reshader-train field-fit`: how much a lobe head's closed form could gain if the network
predicted its fields well, apart from how well a network learns to predict them.

For each example with several reshaded targets (`render --scenes analytic --targets N`),
the head's per-pixel fields are fitted directly (no network) to all cameras but the last,
and scored on the last, held out: the gain a network could reach whose fields were as good
as a fit that saw N - 1 other cameras of the same scene. The fields are smooth, as a
network's are: they are fitted at 1/`--smooth` of the resolution and upsampled bilinearly
(at full resolution a pixel has more unknowns than there are cameras to fit). Scores as
`evaluate` gives them: fixed tone mapping, masked by validity, "changing" views those
whose input is below 40 dB.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F

from .data import DatasetError, list_examples, load_example, make_sample
from .evaluate import CHANGING_BELOW_DB, masked_psnr
from .model import LOBE_HEADS, LobeField, lobe_head_channels, shade_lobes


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, required=True, help="examples with several targets")
    p.add_argument("--count", type=int, default=24, help="first COUNT examples (default 24)")
    p.add_argument(
        "--heads",
        default="lobes,lobes-slide",
        help=f"comma-separated heads to fit (default lobes,lobes-slide; any of {LOBE_HEADS})",
    )
    add_fit_arguments(p, lobes=2, smooth=4, sparsity=0.0)
    p.add_argument("--json", type=Path, help="write the summary and per-example rows as JSON")


def add_fit_arguments(
    p: argparse.ArgumentParser, lobes: int, smooth: int, sparsity: float, why: str = ""
) -> None:
    """The fit's options, shared with `teacher` (which has other defaults)."""
    p.add_argument("--lobes", type=int, default=lobes, help=f"lobes per pixel (default {lobes})")
    p.add_argument(
        "--smooth",
        type=int,
        default=smooth,
        help=f"fields at 1/SMOOTH of the resolution (default {smooth})",
    )
    p.add_argument("--steps", type=int, default=150, help="Adam steps per fit (default 150)")
    p.add_argument("--lr", type=float, default=0.05, help="Adam learning rate (default 0.05)")
    p.add_argument(
        "--sparsity",
        type=float,
        default=sparsity,
        help=f"add this times the mean lobe amplitude and layer fraction to each fit{why} "
        f"(default {sparsity:g})",
    )
    p.add_argument("--threads", type=int, default=1, help="PyTorch threads (default 1)")


def fit_fields(
    head: str,
    lobes: int,
    sample: dict,
    smooth: int,
    steps: int,
    lr: float,
    held_out: int = 1,
    sparsity: float = 0.0,
):
    """The head's fields (B, C, H, W), fitted to every target of `sample` but the last
    `held_out`, plus `sparsity` times the mean lobe amplitude and layer fraction (with a
    few cameras many fields fit; the sparse ones put the light where it shines)."""
    image, disparity, rays = (sample[k][None] for k in ("image", "disparity", "rays"))
    targets, masks, cameras = sample["targets"], sample["masks"], sample["cameras"]
    h, w = image.shape[2:]
    field = LobeField(lobes, head)
    size = (max(1, h // smooth), max(1, w // smooth))
    raw = torch.zeros(1, lobe_head_channels(head, lobes), *size, requires_grad=True)
    opt = torch.optim.Adam([raw], lr=lr)

    def fields() -> torch.Tensor:
        return field(F.interpolate(raw, size=(h, w), mode="bilinear"), rays)

    for _ in range(steps):
        f = fields()
        loss = sum(
            (
                (shade_lobes(image, f, disparity, rays, cameras[k : k + 1], head=head) - targets[k])
                ** 2
                * masks[k]
            ).mean()
            for k in range(len(targets) - held_out)
        )
        if sparsity:
            loss = loss + sparsity * sparse_penalty(f, lobes)
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        return fields()


def sparse_penalty(fields: torch.Tensor, lobes: int) -> torch.Tensor:
    """Mean |amplitude| of the lobes plus the mean sliding fraction (if the head has one)."""
    amps = torch.cat([fields[:, 7 * j + 4 : 7 * j + 7] for j in range(lobes)], 1)
    penalty = amps.abs().mean()
    if fields.shape[1] > 7 * lobes:
        penalty = penalty + fields[:, 7 * lobes : 7 * lobes + 3].mean()
    return penalty


def target_psnrs(
    head: str, sample: dict, fields: torch.Tensor, domain: str = "display"
) -> list[tuple[float, float]]:
    """(input PSNR, the fields' view's PSNR) at each target camera of `sample`."""
    image, disparity, rays = (sample[k][None] for k in ("image", "disparity", "rays"))
    targets, masks, cameras = sample["targets"], sample["masks"], sample["cameras"]
    psnr = []
    for k in range(len(targets)):
        view = shade_lobes(
            image, fields, disparity, rays, cameras[k : k + 1], domain=domain, head=head
        )
        psnr.append(
            (
                masked_psnr(image, targets[k : k + 1], masks[k : k + 1]),
                masked_psnr(view.clamp(0, 1), targets[k : k + 1], masks[k : k + 1]),
            )
        )
    return psnr


def score(head: str, sample: dict, fields: torch.Tensor) -> tuple[float, float, float]:
    """Input PSNR and the fit's on the held-out (last) camera, and the fit's mean gain on
    the cameras it was fitted to."""
    psnr = target_psnrs(head, sample, fields)
    fitted = statistics.mean(ours - inp for inp, ours in psnr[:-1])
    return psnr[-1][0], psnr[-1][1], fitted


def summary(rows: list[dict], head: str) -> dict:
    """Means over the examples whose held-out view changes (an unchanged one's input is the
    truth to the last bit, and any fit can only lose there)."""
    changing = [r for r in rows if r["head"] == head and r["psnr_input"] < CHANGING_BELOW_DB]
    mean = (lambda key: statistics.mean(r[key] for r in changing)) if changing else None
    return {
        "head": head,
        "changing": len(changing),
        "held_out_gain_db": mean("gain_db") if mean else None,
        "improved": sum(r["gain_db"] > 0 for r in changing),
        "fitted_gain_db": mean("fitted_gain_db") if mean else None,
    }


def run(args: argparse.Namespace) -> int:
    heads = [h for h in args.heads.split(",") if h]
    unknown = [h for h in heads if h not in LOBE_HEADS]
    if unknown or not heads:
        print(f"field-fit: --heads {args.heads!r}: expected some of {LOBE_HEADS}", file=sys.stderr)
        return 2
    if args.smooth < 1 or args.steps < 1:
        print("field-fit: --smooth and --steps must be at least 1", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    try:
        folders = list_examples(args.data)[: args.count]
        examples = [load_example(f) for f in folders]
    except DatasetError as err:
        print(f"field-fit: {err}", file=sys.stderr)
        return 1
    examples = [ex for ex in examples if ex.target_count >= 2]
    if not examples:
        print(
            f"field-fit: {args.data} has no examples with two or more targets among its first "
            f"{args.count} (render them with --scenes analytic --targets N)",
            file=sys.stderr,
        )
        return 1
    rows, started = [], time.monotonic()
    for i, ex in enumerate(examples):
        sample = make_sample(ex, crop=None, rng=None, aug=None, targets=ex.target_count)
        for head in heads:
            fields = fit_fields(
                head, args.lobes, sample, args.smooth, args.steps, args.lr, sparsity=args.sparsity
            )
            inp, ours, fitted = score(head, sample, fields)
            rows.append(
                {
                    "example": ex.name,
                    "head": head,
                    "psnr_input": inp,
                    "psnr_fit": ours,
                    "gain_db": ours - inp,
                    "fitted_gain_db": fitted,
                }
            )
        print(
            f"[{i + 1}/{len(examples)}] {ex.name} ({time.monotonic() - started:.0f} s)",
            file=sys.stderr,
        )
    table = [summary(rows, h) for h in heads]
    print(
        f"{len(examples)} examples, fields at 1/{args.smooth} resolution; means over those "
        "whose held-out view changes (input below 40 dB):"
    )
    print(f"{'head':<14} {'changing':>9} {'held-out camera':>16} {'improved':>9} {'fitted':>10}")
    for s in table:
        if s["changing"] == 0:
            print(f"{s['head']:<14} {0:>9} {'-':>16} {'-':>9} {'-':>10}")
            continue
        print(
            f"{s['head']:<14} {s['changing']:>9} {s['held_out_gain_db']:+13.2f} dB "
            f"{s['improved']:>9} {s['fitted_gain_db']:+7.2f} dB"
        )
    if args.json:
        args.json.write_text(json.dumps({"summary": table, "rows": rows}, indent=1))
    return 0
