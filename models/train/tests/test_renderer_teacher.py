"""The analytic renderer's own fields (`teacher --source renderer`) and the lobes head's
linear-clamped domain they are for."""

import csv
import json
import math
import shutil

import numpy as np
import pytest
import torch
from conftest import check_untrained
from test_train import TINY

from reshader_train.cli import main
from reshader_train.data import FieldTargets, load_example, make_sample
from reshader_train.losses import field_loss, light_share
from reshader_train.model import (
    AMPLITUDE_INIT,
    AMPLITUDE_SEEN,
    LINEAR_GAMMA,
    SHARE_INIT,
    LobeField,
    NetConfig,
    lobe_sum,
    shade_lobes,
    view_directions,
)
from reshader_train.render.analytic import Camera, look_at
from reshader_train.render.decompose import decompose, light_lobes


def mirror_scene(roughness: float = 0.05, f0: float = 0.9) -> dict:
    """A glossy floor under one SG light and a dark sky, nothing else."""
    light = np.array([0.0, 1.0, -1.0]) / math.sqrt(2.0)
    return {
        "floor": {"albedo": [0.1, 0.1, 0.1], "roughness": roughness, "f0": [f0] * 3},
        "objects": [],
        "orbs": [],
        "sky": {"horizon": [0.0] * 3, "zenith": [0.0] * 3, "ground": [0.0] * 3, "power": 1.0},
        "lobes": [{"axis": light.tolist(), "sharpness": 500.0, "amplitude": [50.0] * 3}],
    }


def camera() -> Camera:
    # Looking 45 degrees down towards -z: the floor mirrors the light (45 degrees up
    # towards -z) into the middle of the view.
    return Camera(look_at([0.0, 1.0, 2.0], [0.0, 0.0, 1.0], (0.0, 1.0, 0.0), 0.0), 24, 24, 60)


def test_light_lobes_point_where_the_highlight_is():
    scene, cam = mirror_scene(), camera()
    fields = light_lobes(scene, cam, 1)
    assert fields.shape == (24, 24, 7)
    # At the highlight, the brightest part of the photo and almost all specular, the lobe's
    # axis is the direction back to the camera (w0) and its amplitude the light's peak.
    photo = decompose(scene, cam, 1)
    peak = np.unravel_index(np.argmax(photo["input"].mean(2)), photo["share"].shape[:2])
    assert photo["share"][peak].min() > 0.9
    d = np.array([(peak[1] - cam.cx) / cam.fx, (peak[0] - cam.cy) / cam.fy, 1.0])
    w0 = -d / np.linalg.norm(d)
    assert float(fields[peak][0:3] @ w0) > 0.999
    assert np.allclose(fields[peak][4:7], photo["input"][peak], rtol=0.2)
    assert 1.0 <= fields[..., 3].min() and fields[..., 3].max() <= 2.0e4


def test_a_diffuse_floor_has_no_lobes_and_no_layer():
    scene = mirror_scene(f0=0.0)
    fields = light_lobes(scene, camera(), 2)
    assert not fields[..., 4:7].any() and not fields[..., 11:14].any()
    assert not decompose(scene, camera(), 1)["share"].any()


def test_linear_clamped_views_keep_the_photo_and_never_remove_more_than_it_has():
    torch.manual_seed(0)
    image = torch.rand(1, 3, 8, 8) * 0.9
    image[..., :4] = 1.0  # the left half clipped
    rays = torch.cat([torch.rand(1, 2, 8, 8) - 0.5, torch.ones(1, 1, 8, 8)], 1)
    disparity = torch.full((1, 1, 8, 8), 0.2)
    w0 = view_directions(disparity, rays, torch.zeros(1, 3))
    # One lobe per pixel aimed at its own photo's view, a hundred times brighter than white.
    lobes = torch.cat([w0, torch.full((1, 1, 8, 8), 50.0), torch.full((1, 3, 8, 8), 100.0)], 1)
    kw = {"domain": "linear-clamped", "head": "lobes"}
    assert torch.equal(shade_lobes(image, lobes, disparity, rays, torch.zeros(1, 3), **kw), image)
    away = torch.tensor([[0.3, 0.0, 0.0]])
    moved = shade_lobes(image, lobes, disparity, rays, away, **kw)
    g = lobe_sum(lobes, view_directions(disparity, rays, away)) / 100.0
    # Clipped: the lobe leaves, and only what it still brings is left (clipped at white),
    # not a hole dug 100 below black. Not clipped: the lobe holds no more than the pixel.
    linear = image**LINEAR_GAMMA
    expected = torch.where(image == 1.0, (100.0 * g).clamp(max=1.0), linear * g)
    assert torch.allclose(moved, expected.clamp(min=1e-4) ** (1 / LINEAR_GAMMA), atol=1e-5)
    plain = shade_lobes(image, lobes, disparity, rays, away, domain="linear")
    assert (plain <= moved + 1e-6).all() and (plain < moved - 0.01).any()


def test_linear_clamped_amplitudes_start_faint_and_stay_positive():
    field = LobeField(1, "lobes", "linear-clamped")
    rays = torch.cat([torch.zeros(1, 2, 4, 4), torch.ones(1, 1, 4, 4)], 1)
    out = field(torch.zeros(1, 7, 4, 4), rays)
    assert torch.allclose(out[:, 4:7], torch.full_like(out[:, 4:7], AMPLITUDE_INIT), rtol=1e-4)
    far = field(torch.full((1, 7, 4, 4), -50.0), rays)[:, 4:7]
    bright = field(torch.full((1, 7, 4, 4), 50.0), rays)[:, 4:7]
    assert (far > 0).all() and far.max() < 1e-5 and bright.min() > 1e3
    assert AMPLITUDE_INIT < AMPLITUDE_SEEN


def test_photo_amplitudes_are_a_share_of_the_pixel_s_own_light():
    torch.manual_seed(0)
    field = LobeField(1, "lobes", "linear-clamped", "photo")
    image = torch.rand(1, 3, 4, 4) * 0.8 + 0.1
    rays = torch.cat([torch.rand(1, 2, 4, 4) - 0.5, torch.ones(1, 1, 4, 4)], 1)
    w0 = view_directions(torch.zeros(1, 1, 4, 4), rays, torch.zeros(1, 3))
    raw = 0.3 * torch.randn(1, 7, 4, 4)  # sharpness 24-380
    raw[:, 0:3] *= 0.1  # axes within a few degrees of the view
    raw[:, 4:7] = 0.0  # the untrained share
    out = field(raw, rays, image)
    # What the lobe shows at the photo's view is the share times the pixel's linear light,
    # whatever the axis and sharpness: those move the light, not how much of it there is.
    at_photo = lobe_sum(out, w0)
    assert torch.allclose(at_photo, SHARE_INIT * image**LINEAR_GAMMA, rtol=1e-4)
    assert 0.0 < (raw[:, 0:4].abs().max()) and not torch.allclose(out[:, 3], out[:, 3].mean())
    # A sharp lobe far from the view would need an amplitude past any float: it is capped.
    raw[:, 0:3], raw[:, 3] = torch.tensor([5.0, 5.0, 5.0])[:, None, None], 50.0
    far = field(raw, rays, image)
    assert torch.isfinite(far).all() and torch.allclose(far[:, 4:7].max(), torch.tensor(1e4))
    with pytest.raises(ValueError, match="need the photo"):
        field(raw, rays)


def test_photo_amplitudes_need_the_linear_clamped_domain():
    with pytest.raises(ValueError, match="linear-clamped"):
        NetConfig(widths=(4,) * 6, head="lobes", domain="display", amplitude="photo")
    with pytest.raises(ValueError, match="unknown lobe amplitude"):
        NetConfig(widths=(4,) * 6, head="lobes", domain="linear-clamped", amplitude="fixed")


def test_hdr_fields_are_tone_mapped_with_the_sample():
    fields = np.zeros((2, 2, 11), np.float32)
    fields[..., 4:7] = 0.1  # a lobe of HDR peak 0.1
    fields[0, 0, 4:7] = 50.0  # and a clipped one
    fields[..., 7:10] = 0.5  # half the light slides
    hdr = np.full((2, 2, 3), 0.1, np.float32)
    t = FieldTargets(fields, 1, hdr=True).tone_mapped(hdr, 5.0, 2.2)
    assert np.allclose(t.fields[1, 1, 4:7], 0.5)  # exposure x peak at gamma 2.2
    assert np.allclose(t.fields[0, 0, 4:7], 250.0)
    # The display share of the layer: 1 - (0.5 * 0.5)^(1/2.2) / 0.5^(1/2.2)
    assert np.allclose(t.fields[1, 1, 7:10], 1 - 0.5 ** (1 / 2.2), atol=1e-5)
    gamma4 = FieldTargets(fields, 1, hdr=True).tone_mapped(hdr, 5.0, 4.0)
    assert np.allclose(gamma4.fields[1, 1, 4:7], 0.5 ** (2.2 / 4.0))
    assert FieldTargets(fields, 1).tone_mapped(hdr, 5.0, 2.2) is not None
    assert np.array_equal(FieldTargets(fields, 1).tone_mapped(hdr, 5.0, 2.2).fields, fields)


def test_log_amplitude_distance_is_zero_at_the_teacher_and_bounded():
    torch.manual_seed(0)
    t = torch.rand(2, 7, 8, 8)
    t[:, 0:3] = t[:, 0:3] / t[:, 0:3].norm(dim=1, keepdim=True)
    t[:, 3:4] = 10.0
    t[:, 4:7] = 10.0 ** torch.empty(2, 3, 8, 8).uniform_(-4, 4)
    assert float(field_loss(t, t, 1, log_amplitude=True)) == pytest.approx(0.0, abs=1e-6)
    far = t.clone()
    far[:, 4:7] = 1e9
    assert float(field_loss(far, t, 1, log_amplitude=True)) <= 1.0 + 2.0
    # Below the starting amplitude nothing pulls a lobe further down.
    faint, fainter = t.clone(), t.clone()
    faint[:, 4:7], fainter[:, 4:7] = 1e-3, 1e-4
    zero = t.clone()
    zero[:, 4:7] = 0.0
    assert float(field_loss(faint, zero, 1, log_amplitude=True)) == pytest.approx(0.0, abs=1e-6)
    assert float(field_loss(fainter, zero, 1, log_amplitude=True)) == pytest.approx(0.0, abs=1e-6)
    # ... and a lobe too faint still climbs towards a teacher's bright one.
    fainter.requires_grad_(True)
    field_loss(fainter, t, 1, log_amplitude=True).backward()
    lit = t[:, 4:7] > 1e-3
    assert (fainter.grad[:, 4:7][lit] < 0).all() and (fainter.grad[:, 4:7][~lit] == 0).all()


def test_balanced_amplitudes_weigh_a_few_lit_pixels_as_much_as_the_unlit_rest():
    """One lit pixel in 64: a network that puts every lobe between the two teachers is
    pulled up by the balanced distance, down by the plain one."""
    t = torch.zeros(1, 7, 8, 8)
    t[:, 2] = 1.0
    t[:, 3] = 10.0
    t[:, 4:7, 0, 0] = 1.0
    guess = t.clone()
    guess[:, 4:7] = 10.0**-2.0
    for balance, direction in ((False, 1.0), (True, -1.0)):
        g = guess.clone().requires_grad_(True)
        field_loss(g, t, 1, log_amplitude=True, balance=balance).backward()
        assert float(g.grad[:, 4:7].sum()) * direction > 0
    # Balanced and plain agree where the teacher lights every pixel.
    lit = t.clone()
    lit[:, 4:7] = 1.0
    plain = field_loss(guess, lit, 1, log_amplitude=True)
    balanced = field_loss(guess, lit, 1, log_amplitude=True, balance=True)
    assert float(balanced) == pytest.approx(float(plain))


def test_shares_settle_on_the_mean_share_where_the_log_distance_settles_on_the_floor():
    """Where the photo cannot tell a lit pixel (share 1/2) from its unlit twins, a network
    must give them one lobe: compared by shares it is pulled towards the mean share, where
    the log distance pulls it down to the unlit pixels' floor."""
    rays = torch.cat([torch.zeros(1, 2, 4, 4), torch.ones(1, 1, 4, 4)], 1)
    image = torch.full((1, 3, 4, 4), 0.5)
    linear = 0.5**LINEAR_GAMMA
    w0 = view_directions(torch.zeros(1, 1, 4, 4), rays, torch.zeros(1, 3))
    t = torch.cat([w0, torch.full((1, 1, 4, 4), 100.0), torch.zeros(1, 3, 4, 4)], 1)
    t[:, 4:7, :, :2] = linear  # share 1, u / (1 + u) = 1/2, in half the pixels
    # One lobe everywhere, at a quarter of the lit share: the mean of the squared share
    # distance is at the mean (1/4, u = 1/3); the log distance's, at the unlit floor.
    guess = t.clone()
    guess[:, 4:7] = linear / 3.0
    assert float(light_share(guess, torch.full_like(image, linear), w0).mean()) == (
        pytest.approx(0.25)
    )
    for share, settled in ((True, True), (False, False)):
        g = guess.clone().requires_grad_(True)
        photo = (image, rays) if share else None
        field_loss(g, t, 1, log_amplitude=True, photo=photo).backward()
        grad = float(g.grad[:, 4:7].sum())
        assert (abs(grad) < 1e-6) if settled else grad > 0, (share, grad)
    assert float(field_loss(t, t, 1, log_amplitude=True, photo=(image, rays))) == 0.0


@pytest.fixture(scope="module")
def renderer_fields(analytic, tmp_path_factory):
    """test_teacher's analytic examples and the renderer's two lobes for each."""
    data, _ = analytic
    fields = tmp_path_factory.mktemp("renderer") / "lobes"
    argv = ["teacher", "--source", "renderer", "--head", "lobes", "--lobes", "2"]
    assert main([*argv, "--data", str(data), "--out", str(fields)]) == 0
    return data, fields


def test_renderer_teacher_writes_hdr_lobes_for_the_clamped_domain(renderer_fields):
    data, fields = renderer_fields
    settings = json.loads((fields / "teacher.json").read_text())
    assert settings == {
        "head": "lobes",
        "lobes": 2,
        "source": "renderer",
        "units": "hdr",
        "domain": "linear-clamped",
    }
    names = sorted(p.name for p in data.iterdir() if (p / "meta.json").exists())
    a = np.load(fields / f"{names[0]}.npy")
    assert a.dtype == np.float16 and a.shape == (14, 32, 32)
    ex = load_example(data / names[0])
    ex.teacher = FieldTargets(a.astype(np.float32).transpose(1, 2, 0), 2, hdr=True)
    s = make_sample(ex, crop=None, rng=None, aug=None, targets=2)
    assert s["teacher"].shape == (14, 32, 32) and torch.isfinite(s["teacher"]).all()


def test_renderer_teacher_refuses_examples_it_did_not_render(renderer_fields, tmp_path, capsys):
    data, _ = renderer_fields
    name = sorted(p.name for p in data.iterdir() if (p / "meta.json").exists())[0]
    argv = ["teacher", "--source", "renderer", "--head", "lobes", "--out", str(tmp_path / "f")]
    for change, says in (("family", "not an analytic example"), ("seed", "does not draw again")):
        copy = tmp_path / change
        shutil.copytree(data / name, copy / name)
        meta = json.loads((copy / name / "meta.json").read_text())
        if change == "family":
            meta["scene"]["family"] = "highlights"
        else:
            meta["seed"] += 1
        (copy / name / "meta.json").write_text(json.dumps(meta))
        assert main([*argv, "--data", str(copy)]) == 1
        assert says in capsys.readouterr().err
        assert not list((tmp_path / "f").glob("*.npy"))


def tiny_lobe_training(data, run_dir) -> list[str]:
    """`train` of a tiny lobes K = 2 network for two steps on `data`."""
    return ["train", "--data", str(data), "--run-dir", str(run_dir), "--size", TINY,
            "--steps", "2", "--batch-size", "2", "--crop", "32", "--workers", "0",
            "--threads", "1", "--log-every", "1", "--no-progress", "--head", "lobes",
            "--lobes", "2", "--loss-weights", "1,0,0", "--targets-per-example", "2"]  # fmt: skip


def teacher_column(run_dir) -> list[float]:
    with open(run_dir / "log.csv", newline="") as f:
        return [float(r["teacher"]) for r in csv.DictReader(f)]


def test_train_with_renderer_lobes_needs_their_domain(renderer_fields, tmp_path, capsys):
    data, fields = renderer_fields
    argv = [*tiny_lobe_training(data, tmp_path / "run"), "--teacher", str(fields)]
    assert main(argv) != 0
    assert "--lobe-domain linear-clamped" in capsys.readouterr().err
    assert main([*argv, "--lobe-domain", "linear-clamped"]) == 0
    taught = teacher_column(tmp_path / "run")
    assert len(taught) == 2 and all(math.isfinite(t) for t in taught)


def test_train_with_photo_amplitudes_taught_by_shares(renderer_fields, tmp_path, capsys):
    data, fields = renderer_fields
    argv = [*tiny_lobe_training(data, tmp_path / "run"), "--teacher-share", "--lobe-domain",
            "linear-clamped"]  # fmt: skip
    assert main(argv) != 0
    assert "--teacher-share needs --teacher" in capsys.readouterr().err
    assert main([*argv, "--teacher", str(fields), "--lobe-amplitude", "photo"]) == 0
    taught = teacher_column(tmp_path / "run")
    assert len(taught) == 2 and all(0 < t < 10 for t in taught)


def test_teacher_check_reads_a_lobes_network_against_the_renderer(
    renderer_fields, tmp_path, capsys
):
    from dataclasses import replace

    from reshader_train.model import net_config

    data, fields = renderer_fields
    cfg = replace(net_config(TINY), head="lobes", lobes=2, domain="linear-clamped")
    _, report = check_untrained(cfg, data, fields, tmp_path)
    assert "with a lit teacher" in capsys.readouterr().out
    means = report["means"]
    # An untrained network's lobes are all at the starting amplitude, below what a view shows.
    assert means["network_amplitude_lit"] == pytest.approx(math.log10(AMPLITUDE_INIT), abs=0.01)
    assert means["teacher_amplitude_lit"] > math.log10(AMPLITUDE_SEEN)
    assert 0 < means["lit_share"] <= 1
    # Its shares of the pixels' light are as faint; the teacher's lit lobes hold some.
    assert 0 <= means["network_share_lit"] < 0.01 < means["teacher_share_lit"] < 1


def test_depth_normals_of_a_plane_are_its_normal_and_face_the_camera():
    from reshader_train.render.decompose import depth_normals

    ys, xs = np.mgrid[0:5, 0:6].astype(np.float64)
    normal = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    # The plane n . p = 4, parametrised over x and y.
    points = np.stack([xs, ys, (4 - normal[0] * xs - normal[1] * ys) / normal[2]], -1)
    n = depth_normals(points.reshape(-1, 3), 5, 6, np.array([0.0, 0.0, 100.0]))
    assert np.allclose(n, normal, atol=1e-9)
    away = depth_normals(points.reshape(-1, 3), 5, 6, np.array([0.0, 0.0, -100.0]))
    assert np.allclose(away, -normal, atol=1e-9)


def test_a_flat_floor_mirrors_the_same_about_its_depth_as_about_its_surface():
    scene, cam = mirror_scene(), camera()
    assert np.allclose(light_lobes(scene, cam, 1, "depth"), light_lobes(scene, cam, 1), atol=1e-4)


@pytest.mark.parametrize(
    ("option", "value"), [("normals", "depth"), ("reach", "surface"), ("reach", "visible")]
)
def test_renderer_teacher_records_the_fields_it_was_asked_for(
    renderer_fields, tmp_path, option, value
):
    data, _ = renderer_fields
    out = tmp_path / value
    argv = ["teacher", "--source", "renderer", "--head", "lobes", f"--{option}", value]
    assert main([*argv, "--data", str(data), "--out", str(out)]) == 0
    assert json.loads((out / "teacher.json").read_text())[option] == value
    assert len(list(out.glob("*.npy"))) == 3


def test_lobes_at_their_peaks_cover_the_lit_floor_and_agree_at_the_highlight():
    scene, cam = mirror_scene(), camera()
    near = light_lobes(scene, cam, 1)
    whole = light_lobes(scene, cam, 1, reach="surface")
    lit_near, lit_whole = near[..., 4:7].mean(2) > 0, whole[..., 4:7].mean(2) > 0
    assert (lit_whole >= lit_near).all() and lit_whole.sum() > lit_near.sum()
    # Where the photo sees the peak the two are the same lobe.
    photo = decompose(scene, cam, 1)
    peak = np.unravel_index(np.argmax(photo["input"].mean(2)), photo["share"].shape[:2])
    assert np.allclose(whole[peak], near[peak], rtol=0.05)


def test_visible_lobes_are_the_peak_lobes_the_photo_shows():
    from reshader_train.render.decompose import visible_lobes

    scene, cam = mirror_scene(), camera()
    whole = light_lobes(scene, cam, 1, reach="surface")
    photo = decompose(scene, cam, 1)
    shown = visible_lobes(whole, cam, photo["input"], 1)
    lit_whole, lit_shown = whole[..., 4:7].mean(2) > 0, shown[..., 4:7].mean(2) > 0
    assert (lit_shown <= lit_whole).all() and 0 < lit_shown.sum() < lit_whole.sum()
    peak = np.unravel_index(np.argmax(photo["input"].mean(2)), photo["share"].shape[:2])
    assert np.array_equal(shown[peak], whole[peak])
    # Kept lobes are unchanged; only amplitudes of the others are zeroed.
    assert np.array_equal(shown[lit_shown], whole[lit_shown])
    assert np.array_equal(shown[..., 0:4], whole[..., 0:4])
