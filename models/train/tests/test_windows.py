import json

import pytest

from reshader_train import windows


def _view(psnr_input: float, gain: float, scene: str = "tabletop") -> dict:
    return {"psnr_input": psnr_input, "psnr_ours": psnr_input + gain, "scene": scene}


def _matte(psnr_ours: float) -> dict:
    return _view(72.7, psnr_ours - 72.7, scene="diffuse")


def test_gains_split_the_changing_views_from_the_static_ones():
    g = windows.gains([_view(30, 1.0), _view(35, -0.5), _view(45, -0.2), _view(70, 0.0)])
    assert g["changing"] == pytest.approx(0.25)
    assert (g["changing_views"], g["improved"]) == (2, 1)
    assert g["static"] == pytest.approx(-0.1)
    assert g["static_views"] == 2
    assert g["matte_views"] == 0


def test_matte_scenes_are_scored_apart_from_the_static_views():
    g = windows.gains([_view(45, -0.2), _matte(62.0), _matte(58.0)])
    assert g["static"] == pytest.approx(-0.2)
    assert g["static_views"] == 1
    assert g["matte"] == pytest.approx(60.0)
    assert g["matte_views"] == 2


def test_the_window_whose_changing_views_gain_most_is_chosen_and_printed(tmp_path, capsys):
    runs = {
        "1000-4000": [_view(30, 0.5), _view(45, 0.0), _matte(70.0)],
        "5000-8000": [_view(30, 0.9), _view(45, -0.05), _matte(65.0)],
        "9000-12000": [_view(30, 0.7), _view(45, 0.03), _matte(71.0)],
    }
    args = []
    for window, examples in runs.items():
        path = tmp_path / f"{window}.json"
        path.write_text(json.dumps({"examples": examples}))
        args.append(f"{window}={path}")
    assert windows.main(args) == 0
    out = capsys.readouterr().out
    assert "| 5000-8000 | +0.90 dB (1) | 1 | -0.05 dB (1) | 65.0 dB (1) |" in out
    assert "chosen: 5000-8000 " in out


def test_a_window_that_spoils_the_static_views_is_passed_over():
    scores = {
        "a": {"changing": 0.96, "static": -1.74},
        "b": {"changing": 0.94, "static": -1.37},
        "c": {"changing": 0.90, "static": -1.45},
    }
    assert windows.choose(scores) == "b"
    assert windows.choose(scores, static_slack=0.5) == "a"


def test_a_window_that_spoils_the_matte_scenes_is_passed_over(tmp_path, capsys):
    scores = {
        "a": {"changing": 0.99, "static": 0.2, "matte": 59.0},
        "b": {"changing": 0.90, "static": 0.2, "matte": 66.0},
    }
    assert windows.choose(scores) == "b"
    # The static floor is the best among the windows that keep the matte scenes.
    scores["c"] = {"changing": 0.95, "static": 0.5, "matte": 58.0}
    assert windows.choose(scores) == "b"
    path = tmp_path / "a.json"
    path.write_text(json.dumps({"examples": [_view(30, 0.5), _matte(55.0)]}))
    assert windows.main([f"1000-2000={path}"]) == 1
    assert "no window keeps the whole matte scenes at 60 dB" in capsys.readouterr().err


def test_equal_windows_keep_the_first_and_nothing_is_an_error():
    even = {"changing": 0.5, "static": 0.0}
    assert windows.choose({"a": even, "b": even}) == "a"
    with pytest.raises(ValueError):
        windows.choose({})
    assert windows.main(["no-equals-sign"]) == 2
