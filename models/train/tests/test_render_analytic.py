"""The analytic family: numpy ray casting and closed-form shading, no Mitsuba needed."""

import json
import math
import os

import numpy as np

from reshader_train.cli import main
from reshader_train.data import list_examples, load_example
from reshader_train.render import analytic
from reshader_train.render.cameras import Camera, look_at

SIZE = 48


def dark_sky() -> dict:
    return {"zenith": [0.0] * 3, "horizon": [0.0] * 3, "ground": [0.0] * 3, "power": 1.0}


def chrome(roughness: float = 0.02) -> dict:
    return {"kind": "metal", "albedo": [0.0] * 3, "roughness": roughness, "f0": [0.9] * 3}


def matte(rgb) -> dict:
    return {"kind": "matte", "albedo": list(rgb), "roughness": 1.0, "f0": [0.0] * 3}


def scene(floor: dict, objects=(), orbs=(), lobes=(), sky=None) -> dict:
    return {
        "family": "analytic",
        "floor": floor,
        "objects": list(objects),
        "orbs": list(orbs),
        "lobes": list(lobes),
        "sky": sky or dark_sky(),
    }


def orb(centre, radius=0.1, radiance=50.0) -> dict:
    return {"centre": list(centre), "radius": radius, "radiance": [radiance] * 3}


def test_the_cli_writes_complete_examples_that_the_trainer_loads(tmp_path):
    out = tmp_path / "data"
    args = ["render", "--scenes", "analytic", "--out", str(out), "--count", "3", "--seed", "4"]
    assert main([*args, "--size", "40x32", "--spp", "4"]) == 0
    folders = list_examples(out)
    assert len(folders) == 3
    for folder in folders:
        ex = load_example(folder)
        assert ex.input.shape == ex.reshaded.shape == (32, 40, 3)
        assert np.isfinite(ex.input.astype(np.float32)).all() and ex.input.mean() > 0
        meta = json.loads((folder / "meta.json").read_text())
        assert meta["scene"]["family"] == "analytic" and meta["spp"] == 4
        assert 0.1 <= np.linalg.norm(meta["novel_offset"]) <= 0.3
    # Resumable and deterministic: a second run skips, a fresh folder renders the same.
    assert main([*args, "--size", "40x32", "--spp", "4"]) == 0
    again = tmp_path / "again"
    assert main([*args[:4], str(again), *args[5:], "--size", "40x32", "--spp", "4"]) == 0
    for a, b in zip(folders, list_examples(again), strict=True):
        np.testing.assert_array_equal(load_example(a).reshaded, load_example(b).reshaded)


def test_change_seeds_and_mitsuba_options_are_refused(capsys):
    args = ["render", "--scenes", "analytic", "--out", "/nonexistent", "--count", "1"]
    assert main([*args, "--change-seeds", "2"]) == 2
    assert "no sampling noise" in capsys.readouterr().err
    assert main([*args, "--layouts", "3"]) == 2
    assert "--layouts does not apply" in capsys.readouterr().err


def camera() -> Camera:
    return Camera(look_at([0, 1.5, 3], [0, 0, 0]), SIZE, SIZE, 30.0)


def test_a_mirror_highlight_moves_as_the_mirror_geometry_predicts():
    light = np.array([0.0, 1.5, -3.0])
    s = scene(chrome(), orbs=[orb(light)])
    cam = camera()
    offset = np.array([0.5, 0.0, 0.0])  # to the camera's right
    views = analytic.render_pair(s, cam, cam.translated(offset), spp=9)

    def highlight(image):
        lum = image.mean(-1)
        lum = np.where(lum > 0.2 * lum.max(), lum, 0)
        v, u = np.mgrid[0 : lum.shape[0], 0 : lum.shape[1]]
        return np.array([(lum * u).sum(), (lum * v).sum()]) / lum.sum()

    def mirror_point(eye):  # where the eye-to-mirrored-light line crosses the floor
        mirrored = light * [1, -1, 1]
        t = eye[1] / (eye[1] - mirrored[1])
        return eye + t * (mirrored - eye)

    # The orb itself is above the frame; only its reflection is in it.
    expect_in = cam.project(mirror_point(cam.centre))[0, :2]
    expect_resh = cam.project(mirror_point(cam.translated(offset).centre))[0, :2]
    assert expect_resh[0] - expect_in[0] > 3
    np.testing.assert_allclose(highlight(views["input"]), expect_in, atol=1.0)
    np.testing.assert_allclose(highlight(views["reshaded"]), expect_resh, atol=1.0)


def test_diffuse_scenes_and_the_input_camera_reshade_to_exactly_the_input():
    ball = {"shape": "sphere", "centre": [0.0, 0.4, 0.0], "radius": 0.4}
    lobes = [{"axis": [0.3, 0.8, 0.5], "sharpness": 400.0, "amplitude": [30.0] * 3}]
    sky = {"zenith": [0.3] * 3, "horizon": [0.5] * 3, "ground": [0.1] * 3, "power": 1.0}
    glossy = scene(
        chrome(0.1), [{**ball, "material": chrome(0.05)}], [orb([1, 1.5, 1])], lobes, sky
    )
    diffuse = scene(matte([0.5, 0.4, 0.3]), [{**ball, "material": matte([0.2, 0.6, 0.2])}],
                    [orb([1, 1.5, 1])], lobes, sky)  # fmt: skip
    cam = camera()
    moved = cam.translated([0.3, 0.1, 0.0])
    same = analytic.render_pair(glossy, cam, cam, spp=4)
    np.testing.assert_array_equal(same["reshaded"], same["input"])
    assert same["invalid"].max() == 0
    still = analytic.render_pair(diffuse, cam, moved, spp=4)
    valid = still["invalid"] == 0
    np.testing.assert_array_equal(still["reshaded"][valid], still["input"][valid])
    changed = analytic.render_pair(glossy, cam, moved, spp=4)
    assert np.abs(changed["reshaded"] - changed["input"]).max() > 0.1
    # The floor behind the ball, hidden from the moved camera, is invalid; nothing else.
    assert 0 < (changed["invalid"] > 0).mean() < 0.2


def test_depth_is_the_z_distance_of_the_input_view():
    s = scene(matte([0.5] * 3), [{"shape": "box", "centre": [0, 0.3, 0], "half": [0.3] * 3,
                                  "yaw": 0.5, "material": matte([0.5] * 3)}])  # fmt: skip
    cam = Camera(look_at([0, 2.0, 0.0001], [0, 0, 0]), SIZE, SIZE, 40.0)  # straight down
    depth = analytic.render_pair(s, cam, cam, spp=1)["depth"]
    centre = depth[SIZE // 2 - 1 : SIZE // 2 + 1, SIZE // 2 - 1 : SIZE // 2 + 1]
    np.testing.assert_allclose(centre, 2.0 - 0.6, atol=1e-3)  # the box's top face
    np.testing.assert_allclose(depth[0, 0], 2.0, atol=1e-3)  # the floor, at the corner
    assert math.isfinite(float(depth.max()))


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.name != "meta.json"}


def _meta(folder):
    meta = json.loads((folder / "meta.json").read_text())
    meta.pop("render_seconds")
    return meta


def test_several_targets_are_written_deterministically_and_resume(tmp_path):
    common = ["render", "--scenes", "analytic", "--count", "2", "--seed", "5"]
    common += ["--size", "32x32", "--spp", "1"]
    one, three = tmp_path / "one", tmp_path / "three"
    assert main([*common, "--out", str(one)]) == 0
    assert main([*common, "--out", str(three), "--targets", "3"]) == 0
    for a, b in zip(list_examples(one), list_examples(three), strict=True):
        # The first target is the one-target render's, byte for byte.
        files = _files(b)
        assert {k: v for k, v in files.items() if k in _files(a)} == _files(a)
        assert set(files) - set(_files(a)) == {
            "reshaded-1.exr", "reshaded-2.exr", "mask-1.png", "mask-2.png"
        }  # fmt: skip
        meta = _meta(b)
        assert {k: v for k, v in meta.items() if k != "extra_targets"} == _meta(a)
        extra = meta["extra_targets"]
        assert [e["reshaded"] for e in extra] == ["reshaded-1.exr", "reshaded-2.exr"]
        assert [e["mask"] for e in extra] == ["mask-1.png", "mask-2.png"]
        offsets = [meta["novel_offset"]] + [e["offset"] for e in extra]
        assert all(0.1 <= np.linalg.norm(o) <= 0.3 for o in offsets)
        assert len({tuple(o) for o in offsets}) == 3
        ex = load_example(b)
        assert ex.target_count == 3
        for k, e in enumerate(extra, 1):
            assert np.allclose(ex.target(k).offset, e["offset"])
            assert ex.target(k).reshaded.shape == (32, 32, 3)
            assert not np.array_equal(ex.target(k).reshaded, ex.reshaded)
    # A fresh render gives the same files; so does one resumed after an interruption.
    again = tmp_path / "again"
    assert main([*common, "--out", str(again), "--targets", "3"]) == 0
    first, second = list_examples(three)
    import shutil

    shutil.rmtree(second)
    (three / f".tmp-{second.name}").mkdir()
    assert main([*common, "--out", str(three), "--targets", "3"]) == 0
    for a, b in zip(list_examples(three), list_examples(again), strict=True):
        assert _files(a) == _files(b) and _meta(a) == _meta(b)


def test_targets_must_be_one_or_more_and_input_only_renders_none(capsys):
    args = ["render", "--out", "/nonexistent", "--count", "1", "--targets", "2"]
    assert main([*args, "--scenes", "procedural", "--input-only"]) == 2
    assert "--input-only renders no reshaded target" in capsys.readouterr().err
    assert main([*args, "--scenes", "analytic", "--targets", "0"]) == 2
    assert "--targets 0" in capsys.readouterr().err


def test_an_unfinished_folder_is_cleared_only_when_its_render_is_gone(tmp_path):
    from reshader_train.render.example import write_example

    dead, live = (
        tmp_path / ".tmp-00001-000000-999999999",
        tmp_path / f".tmp-00001-000000-{os.getppid()}",
    )
    dead.mkdir()
    live.mkdir()
    (tmp_path / ".tmp-00001-000000").mkdir()  # the layout before the process id was added
    image = np.zeros((2, 2, 3), np.float32)
    views = {"input": image, "reshaded": image, "novel": image, "depth": np.ones((2, 2))}
    views["invalid"] = np.zeros((2, 2))
    written = write_example(
        str(tmp_path),
        views,
        {"id": "00001-000000"},
        lambda p, _x: open(p, "w").close(),
        lambda p, _x: open(p, "w").close(),
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["00001-000000", live.name])
    assert sorted(os.listdir(written)) == [
        "depth.exr",
        "input.exr",
        "mask.png",
        "meta.json",
        "novel.exr",
        "reshaded.exr",
    ]
