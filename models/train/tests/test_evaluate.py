import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from reshader_train import cli
from reshader_train.evaluate import (
    load_evaluated_model,
    masked_psnr,
    masked_ssim,
    pad_to_multiple,
    summarise,
    view_gate,
)
from reshader_train.model import ReshadeNet, net_config
from reshader_train.synthetic import write_dataset


def test_masked_psnr_ignores_invalid_pixels():
    target = torch.full((3, 8, 8), 0.5)
    pred = target + 0.1
    mask = torch.ones(1, 8, 8)
    mask[..., :4] = 0
    pred[..., :4] = 1.0  # large errors only where invalid
    assert masked_psnr(pred, target, mask) == pytest.approx(20.0, abs=1e-4)


def test_ssim_identity_and_noise():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(3, 32, 32, generator=g)
    mask = torch.ones(1, 32, 32)
    assert masked_ssim(a, a, mask) == pytest.approx(1.0, abs=1e-5)
    noisy = (a + 0.2 * torch.randn(3, 32, 32, generator=g)).clamp(0, 1)
    assert masked_ssim(noisy, a, mask) < 0.9


def test_pad_to_multiple_replicates_edges():
    x = torch.arange(6.0).view(1, 1, 2, 3)
    p = pad_to_multiple(x, 4)
    assert p.shape == (1, 1, 4, 4)
    assert torch.equal(p[..., :2, :3], x) and p[0, 0, 3, 3] == x[0, 0, 1, 2]


def test_summary_gain_and_scenes():
    rows = [
        {
            "split": "val",
            "scene": "a",
            "psnr_input": 30.0,
            "psnr_ours": 32.0,
            "ssim_input": 0.9,
            "ssim_ours": 0.95,
        },
        {
            "split": "val",
            "scene": "b",
            "psnr_input": 20.0,
            "psnr_ours": 21.0,
            "ssim_input": 0.8,
            "ssim_ours": 0.85,
        },
    ]
    for r, valid in zip(rows, (100, 300), strict=True):
        r["valid_values"] = valid
        for method in ("input", "ours"):
            r[f"mse_{method}"] = 10 ** (-r[f"psnr_{method}"] / 10)
    s = summarise(rows)
    assert s["val"]["gain_db"] == pytest.approx(1.5) and s["val"]["count"] == 2
    assert s["val"]["gain_median_db"] == pytest.approx(1.5) and s["val"]["improved"] == 2
    # Pooled: the mean squared error over all valid values, so the 300-value image weighs 3x.
    pooled = 10 * math.log10(1 / ((1e-3 * 100 + 1e-2 * 300) / 400))
    assert s["val"]["pooled_psnr_input"] == pytest.approx(pooled)
    assert s["val/a"]["psnr_ours"] == 32.0 and "val/b" in s
    assert "all" not in s  # one folder: no union row
    test_row = {**rows[0], "split": "test", "psnr_ours": 29.0}
    both = summarise([*rows, test_row])
    assert both["all"]["count"] == 3 and both["all"]["improved"] == 2
    assert both["all"]["gain_db"] == pytest.approx((2.0 + 1.0 - 1.0) / 3)
    assert list(both)[0] == "all" and both["test"]["count"] == 1
    static = {**rows[0], "split": "test", "psnr_input": 50.0, "psnr_ours": 49.5}
    parts = summarise([*rows, static])["all"]
    assert parts["gain_changing_db"] == pytest.approx(1.5) and parts["count_changing"] == 2
    assert parts["gain_static_db"] == pytest.approx(-0.5) and parts["count_static"] == 1
    assert summarise(rows)["val"]["gain_static_db"] is None


def test_evaluate_command(tmp_path, capsys):
    val = write_dataset(tmp_path / "val", 2, 32, 40, seed=5)
    cfg = net_config("4,8,8,16,16,16")
    net = ReshadeNet(cfg)
    ckpt = tmp_path / "ckpt.pt"
    torch.save(
        {"model": net.state_dict(), "net_config": cfg.to_json(), "step": 7, "feature_net": "test"},
        ckpt,
    )
    sheet, out = tmp_path / "sheet.png", tmp_path / "eval.json"
    code = cli.main(
        [
            "evaluate",
            "--checkpoint",
            str(ckpt),
            "--data",
            str(val),
            "--sheet",
            str(sheet),
            "--json",
            str(out),
            "--threads",
            "1",
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "Input" in text and "Ours" in text and "gain" in text and "LPIPS" in text
    result = json.loads(out.read_text())
    m = result["splits"]["val"]
    assert m["count"] == 2 and m["psnr_input"] > 10
    # A fresh network is near the identity: Ours within a fraction of a dB of Input.
    assert abs(m["gain_db"]) < 0.5
    assert [e["example"] for e in result["examples"]] == ["00000", "00001"]
    with Image.open(sheet) as im:
        assert im.size == (4 * 40, 2 * 32)


def test_evaluate_scores_the_target_asked_for(tmp_path, capsys):
    data = tmp_path / "analytic"
    argv = ["render", "--scenes", "analytic", "--out", str(data), "--count", "2", "--size",
            "32x32", "--spp", "1", "--targets", "3", "--seed", "7"]  # fmt: skip
    assert cli.main(argv) == 0
    cfg = net_config("4,8,8,16,16,16")
    ckpt = tmp_path / "ckpt.pt"
    torch.save({"model": ReshadeNet(cfg).state_dict(), "net_config": cfg.to_json()}, ckpt)
    cameras = {}
    for target in (0, -1, 2):
        out = tmp_path / f"t{target}.json"
        argv = ["evaluate", "--checkpoint", str(ckpt), "--data", str(data), "--json", str(out),
                "--threads", "1", "--target", str(target)]  # fmt: skip
        assert cli.main(argv) == 0
        cameras[target] = [e["psnr_input"] for e in json.loads(out.read_text())["examples"]]
    # The last target is the third: another camera than the first, so other scores.
    assert cameras[-1] == cameras[2] and cameras[-1] != cameras[0]
    argv = ["evaluate", "--checkpoint", str(ckpt), "--data", str(data), "--target", "3"]
    assert cli.main(argv) == 2
    assert "has 3 target(s), no target 3" in capsys.readouterr().err


def test_change_scale_and_view_gate_score_a_bolder_or_no_change(tmp_path):
    val = write_dataset(tmp_path / "val", 2, 32, 40, seed=5)
    cfg = net_config("4,8,8,16,16,16")
    ckpt = tmp_path / "ckpt.pt"
    torch.save({"model": ReshadeNet(cfg).state_dict(), "net_config": cfg.to_json()}, ckpt)
    scores = {}
    for scale, gate in (("0", "0"), ("1", "0"), ("3", "0"), ("1", "1.01")):
        out = tmp_path / f"s{scale}-g{gate}.json"
        argv = ["evaluate", "--checkpoint", str(ckpt), "--data", str(val), "--json", str(out),
                "--threads", "1", "--change-scale", scale, "--view-gate", gate]  # fmt: skip
        assert cli.main(argv) == 0
        report = json.loads(out.read_text())
        assert (report["change_scale"], report["view_gate"]) == (float(scale), float(gate))
        scores[scale, gate] = [(e["psnr_input"], e["psnr_ours"]) for e in report["examples"]]
    # No change is the photo itself, and so is every view past a gate no view can pass;
    # three times the change scores otherwise than once.
    for key in (("0", "0"), ("1", "1.01")):
        assert all(ours == pytest.approx(photo) for photo, ours in scores[key])
    once = [o for _, o in scores["1", "0"]]
    assert [o for _, o in scores["3", "0"]] != pytest.approx(once)
    assert once != pytest.approx([p for p, _ in scores["1", "0"]])


def test_the_view_gate_keeps_the_photo_where_few_pixels_change_by_a_level():
    photo = torch.rand(3, 20, 20, generator=torch.Generator().manual_seed(3))
    view = photo.clone()
    view[1, :2, :] += 0.01  # 40 of 400 pixels (10 %) by two and a half levels
    view[:, 5:, :] += 0.5 / 255  # the rest of the lower rows by half a level
    assert view_gate(photo, view, 0.0) is view
    assert view_gate(photo, view, 0.09) is view
    assert view_gate(photo, view, 0.11) is photo


def test_evaluate_rejects_missing_checkpoint(tmp_path, capsys):
    assert (
        cli.main(["evaluate", "--checkpoint", str(tmp_path / "x.pt"), "--data", str(tmp_path)]) == 2
    )
    assert "x.pt: checkpoint not found" in capsys.readouterr().err


def test_examples_command_writes_what_the_runtime_reads(tmp_path):
    val = write_dataset(tmp_path / "val", 3, 32, 64, seed=2)
    cfg = net_config("4,8,8,16,16,16")
    ckpt = tmp_path / "ckpt.pt"
    torch.save({"model": ReshadeNet(cfg).state_dict(), "net_config": cfg.to_json()}, ckpt)
    out = tmp_path / "examples"
    args = ["examples", "--checkpoint", str(ckpt), "--data", str(val), "--count", "2"]
    assert cli.main([*args, "--out", str(out)]) == 0
    report = json.loads((out / "examples.json").read_text())
    assert [e["example"] for e in report["examples"]] == ["00000", "00001"]
    first = out / "00000"
    with Image.open(first / "input.png") as im:
        assert im.size == (64, 32) and im.mode == "RGB"
    disparity = np.load(first / "disparity.npy")
    assert disparity.shape == (32, 64) and disparity.dtype == np.float32
    # The recorded input PSNR is that of the 8-bit PNGs as written.
    a = np.asarray(Image.open(first / "input.png"), dtype=np.float64) / 255
    b = np.asarray(Image.open(first / "reshaded.png"), dtype=np.float64) / 255
    valid = np.asarray(Image.open(first / "mask.png")) > 127
    mse = ((a - b)[valid] ** 2).mean()
    assert report["examples"][0]["psnr_input"] == pytest.approx(10 * math.log10(1 / mse), abs=1e-3)
    assert cli.main([*args, "--data", str(tmp_path / "nothing"), "--out", str(out)]) == 2


def test_key_spacing_blends_two_key_views_as_the_runtime_does():
    from dataclasses import replace

    from reshader_train.evaluate import reshade, reshade_like_runtime

    torch.manual_seed(3)
    image, disparity = 0.3 + 0.3 * torch.rand(3, 32, 32), torch.rand(1, 32, 32)
    camera = torch.tensor([0.2, 0.05, 0.0])
    paper = ReshadeNet(net_config("4,8,8,16,16,16")).eval()
    torch.nn.init.normal_(paper.decoder.out.weight, std=0.02)
    # Halfway between keys 0.3 apart along x: the mean of the two keys' views (no value
    # here comes near a clamp), and not the view at the camera itself.
    shifts = (torch.tensor([-0.15, 0.0, 0.0]), torch.tensor([0.15, 0.0, 0.0]))
    keys = [reshade(paper, image, disparity, camera + d) for d in shifts]
    blended = reshade_like_runtime(paper, image, disparity, camera, 0.3)
    assert torch.allclose(blended, (keys[0] + keys[1]) / 2, atol=1e-6)
    direct = reshade(paper, image, disparity, camera)
    near = reshade_like_runtime(paper, image, disparity, camera, 0.01)
    assert (blended - direct).abs().max() > 10 * (near - direct).abs().max() > 0
    lobes = ReshadeNet(replace(net_config("4,8,8,16,16,16"), head="lobes")).eval()
    # At scale 1 nothing is resampled. At half scale only the residual is resampled: a
    # constant one (a last layer of bias alone) comes back exactly, on the full image.
    assert torch.allclose(reshade_like_runtime(paper, image, disparity, camera), direct, atol=1e-6)
    torch.nn.init.zeros_(paper.decoder.out.weight)
    torch.nn.init.constant_(paper.decoder.out.bias, 0.05)
    flat = reshade(paper, image, disparity, camera)
    assert not torch.allclose(flat, image, atol=1e-3)
    half = reshade_like_runtime(paper, image, disparity, camera, scale=0.5)
    assert torch.allclose(half, flat, atol=1e-5)
    with pytest.raises(ValueError, match="no key views"):
        reshade_like_runtime(lobes, image, disparity, camera, 0.1)


def test_a_lobe_head_runs_at_a_reduced_working_size_as_the_runtime_does():
    from dataclasses import replace

    from reshader_train.data import pixel_rays
    from reshader_train.evaluate import reshade, reshade_like_runtime

    torch.manual_seed(5)
    image, disparity = 0.3 + 0.3 * torch.rand(3, 32, 48), 0.1 + 0.1 * torch.rand(1, 32, 48)
    rays = torch.from_numpy(pixel_rays((40.0, 40.0, 23.5, 15.5), 0, 0, 32, 48)).permute(2, 0, 1)
    lobes = ReshadeNet(replace(net_config("4,8,8,16,16,16"), head="lobes")).eval()
    torch.nn.init.normal_(lobes.decoder.out.weight, std=0.3)
    camera = torch.tensor([0.2, 0.05, 0.0])
    direct = reshade(lobes, image, disparity, camera, rays)
    full = reshade_like_runtime(lobes, image, disparity, camera, scale=1.0, rays=rays)
    assert torch.allclose(full, direct, atol=1e-5) and (direct - image).abs().max() > 0.01
    # At half size the view still changes, by about as much, and the photo's camera gives
    # the photo: the change is zero there at any size.
    half = reshade_like_runtime(lobes, image, disparity, camera, scale=0.5, rays=rays)
    assert half.shape == image.shape and (half - image).abs().max() > 0.01
    still = reshade_like_runtime(lobes, image, disparity, torch.zeros(3), scale=0.5, rays=rays)
    assert torch.equal(still, image.clamp(0.0, 1.0))
    with pytest.raises(ValueError, match="rays"):
        reshade_like_runtime(lobes, image, disparity, camera, scale=0.5)


def test_transpose_runs_the_network_turned_about_the_diagonal():
    from reshader_train.evaluate import reshade, reshade_like_runtime

    torch.manual_seed(4)
    image, disparity = 0.3 + 0.3 * torch.rand(3, 32, 64), torch.rand(1, 32, 64)
    camera = torch.tensor([0.2, -0.1, 0.05])
    net = ReshadeNet(net_config("4,8,8,16,16,16")).eval()
    torch.nn.init.normal_(net.decoder.out.weight, std=0.02)
    turned = reshade_like_runtime(net, image, disparity, camera, transpose=True)
    assert turned.shape == image.shape
    by_hand = reshade(net, image.mT, disparity.mT, camera[[1, 0, 2]]).mT
    assert torch.allclose(turned, by_hand, atol=1e-6)
    # The camera turns with the image: x and y swapped, not kept.
    unswapped = reshade(net, image.mT, disparity.mT, camera).mT
    assert (turned - unswapped).abs().max() > 1e-4
    assert (turned - reshade(net, image, disparity, camera)).abs().max() > 1e-4


def test_evaluate_scores_a_quantize_checkpoint_in_the_form_it_was_fine_tuned_for(
    tmp_path, act_quant_calls
):
    from reshader_train.quantize import quant_convs

    data = write_dataset(tmp_path / "data", 2, 32, 40, seed=5)
    cfg = net_config("4,8,8,16,16,16")
    torch.manual_seed(0)
    ckpt = tmp_path / "ckpt.pt"
    torch.save({"model": ReshadeNet(cfg).state_dict(), "net_config": cfg.to_json()}, ckpt)
    argv = ["quantize", str(ckpt), "--data", str(data), "--steps", "2", "--batch-size", "2",
            "--crop", "32", "--calib-batches", "1", "--threads", "1"]  # fmt: skip
    assert cli.main(argv + ["--out", str(tmp_path / "w.pt"), "--form", "weights"]) == 0
    assert cli.main(argv + ["--out", str(tmp_path / "q.pt")]) == 0
    calls = act_quant_calls
    scores = {}
    for name in ("ckpt", "w", "q"):
        calls["n"] = 0
        out = tmp_path / f"{name}.json"
        argv = ["evaluate", "--checkpoint", str(tmp_path / f"{name}.pt"), "--data", str(data),
                "--json", str(out), "--threads", "1"]  # fmt: skip
        assert cli.main(argv) == 0
        scores[name] = (
            [e["psnr_ours"] for e in json.loads(out.read_text())["examples"]],
            calls["n"],
        )
    # Weights form: int8 weights (other scores than the float network's), float inputs.
    assert scores["w"][0] != scores["ckpt"][0] and scores["w"][1] == 0
    assert scores["q"][1] > 0 and scores["ckpt"][1] == 0
    net, _ = load_evaluated_model(tmp_path / "w.pt")
    convs = quant_convs(net)
    assert convs and all(c.enabled and not c.quantize_input for c in convs)
