"""Which window of kept checkpoints to average: a table of `evaluate --json` scores of
each window's mean on the validation scenes, and the window with the best gain on the
views whose shading changes among those that keep the static views and the whole matte
scenes (`choose`; `recipes/choose-window`).

    python -m reshader_train.windows FROM-TO=SCORES.json ...
"""

import json
import math
import sys
from pathlib import Path

from .evaluate import gains_by_change

STATIC_SLACK_DB = 0.1
# The model card's bar for whole matte scenes, scored against the photo they should equal.
MATTE_FLOOR_DB = 60.0
# The scene kind of the whole matte scenes, in val-families and in the held-out sets.
MATTE_SCENE = "diffuse"


def gains(examples: list[dict]) -> dict:
    """Mean gain and counts of the glossy scenes' changing and static views, how many of
    the changing views improved, and the whole matte scenes' mean PSNR against the photo
    (NaN without any). Matte scenes stay out of the static views: each is near-exact, so a
    few of them would outweigh every glossy static view."""
    matte = [r["psnr_ours"] for r in examples if r.get("scene") == MATTE_SCENE]
    glossy = [r for r in examples if r.get("scene") != MATTE_SCENE]
    out = {}
    for part, g in gains_by_change(glossy).items():
        out[part] = sum(g) / len(g) if g else float("nan")
        out[f"{part}_views"] = len(g)
        if part == "changing":
            out["improved"] = sum(x > 0 for x in g)
    out["matte"] = sum(matte) / len(matte) if matte else float("nan")
    out["matte_views"] = len(matte)
    return out


def choose(scores: dict[str, dict], static_slack: float = STATIC_SLACK_DB) -> str:
    """Among the windows whose matte scenes stay at MATTE_FLOOR_DB or more and whose
    static views lose at most `static_slack` dB more than the best of those, the one whose
    changing views gain most (the first of equals): the model card's bars judge all three,
    and a window's static views move by tenths of a dB where its changing views move by
    hundredths."""
    if not scores:
        raise ValueError("no windows to choose from")
    kept = {
        w: s
        for w, s in scores.items()
        if math.isnan(s.get("matte", math.nan)) or s["matte"] >= MATTE_FLOOR_DB
    }
    if not kept:
        raise ValueError(f"no window keeps the whole matte scenes at {MATTE_FLOOR_DB:g} dB")
    floor = max(s["static"] for s in kept.values()) - static_slack
    return max(
        (w for w, s in kept.items() if s["static"] >= floor),
        key=lambda w: kept[w]["changing"],
    )


def table(scores: dict[str, dict]) -> str:
    lines = [
        "| window | changing | improved | static | matte scenes |",
        "| --- | --- | --- | --- | --- |",
    ]
    for window, s in scores.items():
        lines.append(
            f"| {window} | {s['changing']:+.2f} dB ({s['changing_views']}) | {s['improved']} "
            f"| {s['static']:+.2f} dB ({s['static_views']}) "
            f"| {s['matte']:.1f} dB ({s['matte_views']}) |"
        )
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    scores = {}
    for arg in argv:
        window, sep, path = arg.partition("=")
        if not sep:
            print(f"windows: {arg!r} is not FROM-TO=SCORES.json", file=sys.stderr)
            return 2
        scores[window] = gains(json.loads(Path(path).read_text())["examples"])
    print(table(scores))
    try:
        chosen = choose(scores)
    except ValueError as e:
        print(f"windows: {e}", file=sys.stderr)
        return 1
    print(
        f"chosen: {chosen} (the best changing views among the windows whose matte scenes "
        f"stay at {MATTE_FLOOR_DB:g} dB or more and whose static views are within "
        f"{STATIC_SLACK_DB} dB of the best)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
