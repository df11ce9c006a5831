import csv
import json
import math

import numpy as np
import pytest
import torch
from conftest import check_untrained
from test_data import fake_example
from test_train import TINY

from reshader_train.cli import main
from reshader_train.data import (
    Augment,
    FieldTargets,
    load_field_targets,
    make_sample,
    teacher_settings,
)
from reshader_train.losses import field_loss, fraction_distance
from reshader_train.synthetic import write_dataset


def test_teacher_fits_every_example_once(analytic, capsys):
    data, fields = analytic
    names = sorted(p.name for p in data.iterdir() if (p / "meta.json").exists())
    assert sorted(p.stem for p in fields.glob("*.npy")) == names
    a = np.load(fields / f"{names[0]}.npy")
    assert a.dtype == np.float16 and a.shape == (7 + 4, 32, 32)  # one lobe and the layer
    settings = json.loads((fields / "teacher.json").read_text())
    assert (settings["head"], settings["lobes"]) == ("lobes-slide", 1)
    capsys.readouterr()
    argv = ["teacher", "--data", str(data), "--out", str(fields), "--steps", "20", "--smooth", "4"]
    assert main(argv) == 0  # resumed: nothing left to fit
    assert "3 of 3 already fitted" in capsys.readouterr().err
    assert main([*argv[:-2], "--smooth", "2"]) == 1  # another fit into the same folder
    assert "use another --out" in capsys.readouterr().err
    assert not list(fields.glob(".tmp-*"))


def test_teacher_needs_several_cameras(tmp_path, capsys):
    one = write_dataset(tmp_path / "one", 2, 32, 32, seed=0)
    assert main(["teacher", "--data", str(one), "--out", str(tmp_path / "f")]) == 1
    assert "has one target" in capsys.readouterr().err
    assert (
        main(["teacher", "--data", str(one), "--out", str(tmp_path / "f"), "--shard", "2/2"]) == 2
    )


def axis_teacher(ex, lobes=2):
    """Fields whose every lobe axis is the pixel's own view direction (minus its ray), and
    whose scalars are a ramp, so that each symmetry is visible in them."""
    rays = make_sample(ex, None, None, None)["rays"].numpy().transpose(1, 2, 0)
    w0 = -rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    h, w = rays.shape[:2]
    ramp = np.arange(h * w, dtype=np.float32).reshape(h, w, 1) / (h * w)
    per_lobe = [np.concatenate([w0, ramp, ramp, ramp, ramp], -1) for _ in range(lobes)]
    return FieldTargets(np.concatenate([*per_lobe, ramp, ramp, ramp, ramp], -1), lobes)


@pytest.mark.parametrize("dihedral", [False, True])
def test_fitted_axes_turn_with_the_rays(dihedral):
    """Each flip and transpose moves the fitted fields with the image and turns their axes
    as it turns the rays: an axis that was the view direction stays the view direction."""
    ex = fake_example()
    ex.teacher = axis_teacher(ex)
    aug = Augment(disparity_scale=(1.0, 1.0), still=0.0, dihedral=dihedral)
    seen = set()
    for seed in range(16):
        s = make_sample(ex, None, np.random.default_rng(seed), aug)
        rays = s["rays"]
        w0 = -rays / rays.norm(dim=0, keepdim=True)
        for j in range(2):
            assert torch.allclose(s["teacher"][7 * j : 7 * j + 3], w0, atol=1e-3), f"seed {seed}"
        seen.add(tuple(s["teacher"][3, 0, :2].tolist()))
    assert len(seen) > 1  # the ramp was mirrored by some draws


def test_field_targets_are_checked_against_the_example(analytic, tmp_path):
    data, fields = analytic
    name = next(fields.glob("*.npy")).stem
    assert teacher_settings(fields)["lobes"] == 1
    t = load_field_targets(fields, name, (32, 32), 1)
    assert t.fields.shape == (32, 32, 11) and t.lobes == 1
    with pytest.raises(Exception, match="expected \\(C, 16, 16\\)"):
        load_field_targets(fields, name, (16, 16), 1)
    with pytest.raises(Exception, match="run `teacher`"):
        load_field_targets(fields, "no-such-example", (32, 32), 1)
    with pytest.raises(Exception, match="fit it with `reshader-train teacher`"):
        teacher_settings(tmp_path)


def test_field_loss_is_zero_at_the_teacher_and_weighs_axes_by_amplitude():
    torch.manual_seed(0)
    t = torch.rand(2, 11, 8, 8)
    t[:, 0:3] = t[:, 0:3] / t[:, 0:3].norm(dim=1, keepdim=True)
    assert float(field_loss(t, t, 1)) == pytest.approx(0.0, abs=1e-6)
    turned = t.clone()
    turned[:, 0:3] = -t[:, 0:3]
    assert float(field_loss(turned, t, 1)) > 0.1
    faint = t.clone()
    faint[:, 4:7] = 0.0  # no amplitude: the axis cannot matter
    turned[:, 4:7] = 0.0
    assert float(field_loss(turned, faint, 1)) == pytest.approx(0.0, abs=1e-6)


def test_squared_fraction_distance_prefers_the_mean_where_l1_prefers_zero():
    # A pixel the teacher slides in one example in four: L1's best guess is 0, the
    # squared distance's is the mean; both cost mean(t) for a network that slides nothing.
    t = torch.zeros(4, 3, 1, 1)
    t[0] = 0.4
    nothing, mean = torch.zeros_like(t), torch.full_like(t, 0.1)
    l1 = [float(fraction_distance(p, t, "l1")) for p in (nothing, mean)]
    sq = [float(fraction_distance(p, t, "squared")) for p in (nothing, mean)]
    assert l1[0] < l1[1] and sq[1] < sq[0]
    assert sq[0] == pytest.approx(float(t.mean())) == pytest.approx(l1[0])
    with pytest.raises(ValueError, match="fraction distance"):
        fraction_distance(t, t, "l2")


def test_train_with_a_teacher_logs_its_term(analytic, tmp_path):
    data, fields = analytic
    run = tmp_path / "run"
    argv = ["train", "--data", str(data), "--run-dir", str(run), "--size", TINY, "--steps", "2",
            "--batch-size", "2", "--crop", "32", "--workers", "0", "--threads", "1",
            "--log-every", "1", "--no-progress", "--head", "lobes-slide", "--lobes", "1",
            "--loss-weights", "1,0,0", "--targets-per-example", "2", "--dihedral",
            "--teacher", str(fields), "--teacher-distance", "squared"]  # fmt: skip
    assert main(argv) == 0
    with open(run / "log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and all(float(r["teacher"]) > 0 for r in rows)
    assert all(float(r["loss"]) > float(r["pixel"]) for r in rows)


def test_the_teacher_weight_falls_to_zero_over_its_decay(analytic, tmp_path):
    data, fields = analytic
    run = tmp_path / "run"
    argv = ["train", "--data", str(data), "--run-dir", str(run), "--size", TINY, "--steps", "3",
            "--batch-size", "2", "--crop", "32", "--workers", "0", "--threads", "1",
            "--log-every", "1", "--no-progress", "--head", "lobes-slide", "--lobes", "1",
            "--loss-weights", "1,0,0", "--teacher", str(fields), "--teacher-weight", "5",
            "--teacher-decay", "2"]  # fmt: skip
    assert main(argv) == 0
    with open(run / "log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    first, last = rows[0], rows[-1]
    taught = float(first["loss"]) - float(first["pixel"])
    assert taught == pytest.approx(5 * float(first["teacher"]), rel=1e-4)
    assert float(last["teacher"]) > 0
    assert float(last["loss"]) == pytest.approx(float(last["pixel"]), rel=1e-6)


def test_train_refuses_another_heads_teacher(analytic, tmp_path, capsys):
    data, fields = analytic
    argv = ["train", "--data", str(data), "--run-dir", str(tmp_path / "r"), "--size", TINY,
            "--steps", "1", "--batch-size", "2", "--crop", "32", "--workers", "0",
            "--head", "lobes", "--lobes", "2", "--teacher", str(fields)]  # fmt: skip
    assert main(argv) == 2
    assert "fields of --head lobes-slide --lobes 1" in capsys.readouterr().err


def test_a_sparse_fit_puts_less_light_in_the_fields(analytic):
    from reshader_train.data import list_examples, load_example
    from reshader_train.field_fit import fit_fields, sparse_penalty

    data, _ = analytic
    ex = load_example(list_examples(data)[0])
    sample = make_sample(ex, None, None, None, targets=ex.target_count)
    penalties = [
        float(sparse_penalty(fit_fields("lobes-slide", 1, sample, 4, 30, 0.05, 0, w), 1))
        for w in (0.0, 1.0)
    ]
    assert penalties[1] < 0.5 * penalties[0]


def test_selection_says_where_and_how_much():
    from reshader_train.teacher_check import selection

    teacher = np.zeros((10, 10))
    teacher[:, :1] = 0.5  # a tenth of the pixels slide
    same = selection(teacher * 0.1, teacher)
    assert same["correlation"] == pytest.approx(1.0)
    assert same["teacher_share_in_top_tenth"] == pytest.approx(1.0)
    assert same["network_mean"] == pytest.approx(0.1 * same["teacher_mean"])
    elsewhere = np.zeros((10, 10))
    elsewhere[:, 5:6] = 0.5
    away = selection(elsewhere, teacher)
    assert away["teacher_share_in_top_tenth"] == 0.0 and away["correlation"] < 0
    # A network that slides the same everywhere picks nothing out.
    flat = selection(np.full((10, 10), 0.05), teacher)
    assert flat["correlation"] == 0.0 and flat["teacher_share_in_top_tenth"] == pytest.approx(0.1)


def test_teacher_check_compares_a_sliding_network_with_its_teacher(analytic, tmp_path, capsys):
    from reshader_train.model import ReshadeNet, net_config

    data, _ = analytic
    # A teacher that slides the left third of every example.
    fields = tmp_path / "fields"
    fields.mkdir()
    (fields / "teacher.json").write_text(json.dumps({"head": "lobes-slide", "lobes": 1}))
    for ex in sorted(p for p in data.iterdir() if (p / "meta.json").exists()):
        f = np.zeros((11, 32, 32), np.float16)
        f[7:10, :, :10] = 0.3
        np.save(fields / f"{ex.name}.npy", f)
    from dataclasses import replace

    cfg = replace(net_config(TINY), head="lobes-slide", lobes=1)
    argv, report = check_untrained(cfg, data, fields, tmp_path)
    assert "3 examples with a sliding teacher" in capsys.readouterr().out
    assert len(report["examples"]) == 3
    assert report["means"]["teacher_mean"] == pytest.approx(0.3 * 10 / 32, rel=1e-3)
    # An untrained layer is the same small fraction everywhere.
    assert report["means"]["network_mean"] == pytest.approx(1 / (1 + math.exp(3)), rel=0.05)
    residual = tmp_path / "residual.pt"
    cfg = net_config(TINY)
    torch.save({"model": ReshadeNet(cfg).state_dict(), "net_config": cfg.to_json()}, residual)
    assert main([*argv[:2], str(residual), *argv[3:]]) == 2
    assert "has no fields to check" in capsys.readouterr().err
