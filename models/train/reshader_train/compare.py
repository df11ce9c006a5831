"""`reshader-train compare`: two models' scores on the same views, view by view.

A family's or a part's mean gain can hang on one view: a near-exact input (50 dB against
the truth) that a model spoils by 10 dB moves the mean of 64 views by 0.15 dB. This lists
each part's mean and median difference and the views that differ most, so that a bar a
model misses can be traced to the views that make it miss.
"""

import argparse
import json
import statistics
import sys
from pathlib import Path

from .evaluate import split_by_change


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("before", type=Path, help="evaluate --json of the first model")
    p.add_argument("after", type=Path, help="evaluate --json of the second, on the same views")
    p.add_argument("--worst", type=int, default=5, help="views listed per end (default 5)")


def _view(row: dict) -> tuple:
    return row["split"], row["scene"], row["example"]


def _delta(row: dict) -> float:
    return row["gain_after"] - row["gain_before"]


def differences(before: list[dict], after: list[dict]) -> list[dict]:
    """Per view present in both: split, example, the input's PSNR and each model's gain."""
    theirs = {_view(r): r for r in after}
    missing = [_view(r) for r in before if _view(r) not in theirs]
    if missing or len(theirs) != len(before):
        raise ValueError(
            f"the two scores are not of the same views ({len(before)} and {len(theirs)}; "
            f"first missing from the second: {missing[:1]})"
        )
    return [
        {
            "split": r["split"],
            "example": r["example"],
            "psnr_input": r["psnr_input"],
            "gain_before": r["psnr_ours"] - r["psnr_input"],
            "gain_after": theirs[_view(r)]["psnr_ours"] - r["psnr_input"],
        }
        for r in before
    ]


def parts(rows: list[dict]) -> dict[str, list[dict]]:
    """Changing and static views (the glossy families'), and each family."""
    out = split_by_change([r for r in rows if r["split"] != "diffuse"])
    for r in rows:
        out.setdefault(r["split"], []).append(r)
    return {name: rs for name, rs in out.items() if rs}


def report(rows: list[dict], worst: int) -> str:
    lines = [
        f"{'part':<12} {'views':>5} {'mean':>8} {'median':>8} {'worse':>6}  without the worst view"
    ]
    for name, rs in parts(rows).items():
        d = sorted(_delta(r) for r in rs)
        rest = statistics.mean(d[1:]) if len(d) > 1 else float("nan")
        lines.append(
            f"{name:<12} {len(d):>5} {statistics.mean(d):>+8.2f} {statistics.median(d):>+8.2f} "
            f"{sum(x < 0 for x in d):>6}  {rest:+.2f}"
        )
    # Whole matte scenes' inputs sit at 60-100 dB: any level changed there costs tens of
    # dB and would fill both lists; their row above says how they moved.
    ranked = sorted((r for r in rows if r["split"] != "diffuse"), key=_delta)
    for title, chosen in (("most worse", ranked[:worst]), ("most better", ranked[::-1][:worst])):
        lines.append(f"{title} (glossy families):")
        lines += [
            f"  {r['split']}/{r['example']}: input {r['psnr_input']:.1f} dB, gain "
            f"{r['gain_before']:+.2f} -> {r['gain_after']:+.2f} dB ({_delta(r):+.2f})"
            for r in chosen
        ]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    try:
        before, after = (json.loads(p.read_text())["examples"] for p in (args.before, args.after))
        rows = differences(before, after)
    except (OSError, KeyError, ValueError) as err:
        print(f"compare: {err}", file=sys.stderr)
        return 2
    print(report(rows, args.worst))
    return 0
