"""`reshader-train compare`: two models' scores on the same views, view by view."""

import json

import pytest

from reshader_train import cli
from reshader_train.compare import differences, parts, report


def _row(split, example, psnr_input, psnr_ours):
    return {
        "split": split,
        "scene": "procedural",
        "example": example,
        "psnr_input": psnr_input,
        "psnr_ours": psnr_ours,
    }


BEFORE = [
    _row("studio", "a", 30.0, 31.0),
    _row("studio", "b", 45.0, 44.0),
    _row("studio", "c", 25.0, 26.0),
    _row("diffuse", "d", 90.0, 90.0),
]
# "b" (a near-exact view) loses 8 dB more, "c" gains 0.5 dB more, the matte scene 40 dB.
AFTER = [
    _row("studio", "a", 30.0, 31.0),
    _row("studio", "b", 45.0, 36.0),
    _row("studio", "c", 25.0, 26.5),
    _row("diffuse", "d", 90.0, 50.0),
]


def test_parts_and_the_view_that_makes_a_mean():
    rows = differences(BEFORE, AFTER)
    assert {name: len(rs) for name, rs in parts(rows).items()} == {
        "changing": 2,
        "static": 1,
        "studio": 3,
        "diffuse": 1,
    }
    text = report(rows, worst=1)
    studio = next(line for line in text.splitlines() if line.startswith("studio"))
    # mean (0 - 8 + 0.5) / 3, median 0, one view worse, +0.25 without the worst.
    assert studio.split() == ["studio", "3", "-2.50", "+0.00", "1", "+0.25"]
    worse = text.split("most worse (glossy families):\n")[1].splitlines()[0]
    assert worse.startswith("  studio/b: input 45.0 dB, gain -1.00 -> -9.00 dB (-8.00)")
    better = text.split("most better (glossy families):\n")[1].splitlines()[0]
    assert better.startswith("  studio/c")
    assert "diffuse/d" not in text


def test_scores_of_different_views_are_refused():
    with pytest.raises(ValueError, match="not of the same views"):
        differences(BEFORE, AFTER[:3])
    with pytest.raises(ValueError, match="not of the same views"):
        differences(BEFORE, [*AFTER[:3], _row("diffuse", "e", 90.0, 90.0)])


def test_the_command(tmp_path, capsys):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"examples": BEFORE}))
    b.write_text(json.dumps({"examples": AFTER}))
    assert cli.main(["compare", str(a), str(b), "--worst", "2"]) == 0
    assert "studio/b" in capsys.readouterr().out
    assert cli.main(["compare", str(a), str(tmp_path / "missing.json")]) == 2
    assert "missing.json" in capsys.readouterr().err
