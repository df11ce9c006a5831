"""`headroom` re-renders dataset examples exactly and scores them like `evaluate`."""

import json
import math

import pytest

pytest.importorskip("reshader_train.render.mitsuba_env")

from reshader_train.cli import main  # noqa: E402
from reshader_train.data import list_examples, load_example, make_sample  # noqa: E402
from reshader_train.evaluate import masked_psnr  # noqa: E402

ARGS = ["--count", "2", "--size", "24x16", "--spp", "8", "--seed", "7"]


def test_headroom_input_matches_the_rendered_dataset(tmp_path):
    data = tmp_path / "data"
    assert main(["render", "--out", str(data), *ARGS, "--threads", "2"]) == 0
    report = tmp_path / "headroom.json"
    extra = ["--repeats", "2", "--threads", "2", "--deadzone", "0.49", "--json", str(report)]
    assert main(["headroom", *ARGS, *extra]) == 0
    rows = json.loads(report.read_text())["examples"]
    assert [r["example"] for r in rows] == [0, 1]
    for folder, row in zip(list_examples(data), rows, strict=True):
        s = make_sample(load_example(folder), crop=None, rng=None, aug=None)
        # Same scene, cameras and samples as `render`: the input scores the same (the
        # dataset's float16 cache moves PSNR by a few hundredths at most).
        assert abs(masked_psnr(s["image"], s["target"], s["mask"]) - row["psnr_input"]) < 0.05
        # A second sample seed is a different image of the same truth.
        assert math.isfinite(row["psnr_noise"]) and row["psnr_noise"] < 80
        assert math.isfinite(row["psnr_ours"])
        # A dead zone wider than any change in display levels leaves the input as it is.
        assert row["psnr_deadzone"] == pytest.approx(row["psnr_input"], abs=1e-6)


def test_headroom_refuses_zero_repeats(capsys):
    assert main(["headroom", *ARGS, "--repeats", "0"]) == 2
    assert "--repeats" in capsys.readouterr().err


def test_headroom_refuses_a_dead_zone_out_of_range(capsys):
    assert main(["headroom", *ARGS, "--deadzone", "0.5"]) == 2
    assert "--deadzone" in capsys.readouterr().err
