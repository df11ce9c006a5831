import json

import pytest

from reshader_train.cli import main
from reshader_train.synthetic import write_dataset


@pytest.fixture(scope="module")
def analytic(tmp_path_factory):
    """Four analytic examples with three targets each (32x32)."""
    out = tmp_path_factory.mktemp("fit") / "analytic"
    argv = ["render", "--scenes", "analytic", "--out", str(out), "--count", "4"]
    assert main([*argv, "--size", "32x32", "--spp", "1", "--targets", "3", "--seed", "7"]) == 0
    return out


def test_fields_fitted_to_two_cameras_are_scored_on_the_third(analytic, tmp_path, capsys):
    out = tmp_path / "fit.json"
    argv = ["field-fit", "--data", str(analytic), "--count", "4", "--steps", "40",
            "--smooth", "2", "--json", str(out)]  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "held-out camera" in printed and "lobes-slide" in printed
    result = json.loads(out.read_text())
    rows = result["rows"]
    assert {r["head"] for r in rows} == {"lobes", "lobes-slide"}
    assert len(rows) == 8
    changing = [r for r in rows if r["psnr_input"] < 40]
    assert changing, "the analytic examples should include views whose shading changes"
    # A fit gets closer to the cameras it was fitted to than the photo is.
    assert all(r["fitted_gain_db"] > 0 for r in changing)
    assert [s["head"] for s in result["summary"]] == ["lobes", "lobes-slide"]


def test_field_fit_refuses_what_it_cannot_fit(tmp_path, capsys):
    one_target = write_dataset(tmp_path / "one", 2, 32, 32, seed=0)
    assert main(["field-fit", "--data", str(one_target)]) == 1
    assert "two or more targets" in capsys.readouterr().err
    assert main(["field-fit", "--data", str(one_target), "--heads", "residual"]) == 2
    assert "expected some of" in capsys.readouterr().err
