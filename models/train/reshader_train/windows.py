"""Which window of kept checkpoints to average: a table of `evaluate --json` scores of
each window's mean on the validation scenes, and the window with the best gain on the
views whose shading changes among those that keep the static views (`choose`;
`recipes/choose-window`).

    python -m reshader_train.windows FROM-TO=SCORES.json ...
"""

import json
import sys
from pathlib import Path

from .evaluate import gains_by_change

STATIC_SLACK_DB = 0.1


def gains(examples: list[dict]) -> dict:
    """Mean gain and counts of the changing and the static views, and how many of the
    changing views improved."""
    out = {}
    for part, g in gains_by_change(examples).items():
        out[part] = sum(g) / len(g) if g else float("nan")
        out[f"{part}_views"] = len(g)
        if part == "changing":
            out["improved"] = sum(x > 0 for x in g)
    return out


def choose(scores: dict[str, dict], static_slack: float = STATIC_SLACK_DB) -> str:
    """Among the windows whose static views lose at most `static_slack` dB more than
    the best window's, the one whose changing views gain most (the first of equals): the
    model card's bars judge both, and a window's static views move by tenths of a dB
    where its changing views move by hundredths."""
    if not scores:
        raise ValueError("no windows to choose from")
    floor = max(s["static"] for s in scores.values()) - static_slack
    return max(
        (w for w, s in scores.items() if s["static"] >= floor),
        key=lambda w: scores[w]["changing"],
    )


def table(scores: dict[str, dict]) -> str:
    lines = ["| window | changing | improved | static |", "| --- | --- | --- | --- |"]
    for window, s in scores.items():
        lines.append(
            f"| {window} | {s['changing']:+.2f} dB ({s['changing_views']}) | {s['improved']} "
            f"| {s['static']:+.2f} dB ({s['static_views']}) |"
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
    print(
        f"chosen: {choose(scores)} (the best changing views among the windows whose static "
        f"views are within {STATIC_SLACK_DB} dB of the best)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
