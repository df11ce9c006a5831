"""train-depth / export-depth: the shipped depth graph in PyTorch, its loss, fine-tuning
and writing the tuned weights back (no Mitsuba needed)."""

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from onnx import numpy_helper
from PIL import Image

from reshader_train.cli import main
from reshader_train.data import DatasetError, load_example
from reshader_train.depthtune.data import Pair, paint_decals, training_crop
from reshader_train.depthtune.export import quantised_model
from reshader_train.depthtune.graph import DepthGraph
from reshader_train.depthtune.keep import keep_loss
from reshader_train.depthtune.loss import aligned, depth_loss
from reshader_train.synthetic import write_exr

BASE = Path(__file__).resolve().parents[2] / "depth" / "tiefenrausch-fp32.onnx"
INT8 = BASE.with_name("tiefenrausch-int8.onnx")


def _example(folder: Path, rng, size=(64, 64)) -> None:
    """A bright box in front of a textured wall: a photo and its depth, input-only."""
    h, w = size
    folder.mkdir(parents=True)
    depth = np.full((h, w), 4.0, np.float32)
    y0, x0 = rng.integers(8, h // 2), rng.integers(8, w // 2)
    depth[y0 : y0 + h // 3, x0 : x0 + w // 3] = 1.5
    rgb = 0.01 + 0.02 * rng.random((h, w, 3)).astype(np.float32)
    rgb[depth < 2] += np.array([0.05, 0.02, 0.01], np.float32)
    write_exr(folder / "input.exr", {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})
    write_exr(folder / "depth.exr", {"Y": depth})
    (folder / "meta.json").write_text(json.dumps({"id": folder.name, "input_only": True}))


@pytest.fixture(scope="module")
def depth_data(tmp_path_factory):
    root = tmp_path_factory.mktemp("depth")
    rng = np.random.default_rng(3)
    for i in range(4):
        _example(root / "train" / "fam" / f"{i:05d}", rng)
    for i in range(2):
        _example(root / "val" / f"{i:05d}", rng)
    return root


def test_the_graph_in_torch_matches_onnxruntime():
    net = DepthGraph.load(BASE)
    x = np.random.default_rng(0).random((1, 3, 64, 96), dtype=np.float32)
    with torch.no_grad():
        ours = net(torch.from_numpy(x)).numpy()
    (theirs,) = ort.InferenceSession(str(BASE)).run(None, {"image": x})
    assert np.abs(ours - theirs).max() < 1e-4
    assert ours.std() > 1e-3  # a real output, not a constant


def test_the_loss_ignores_scale_and_shift_but_not_shape():
    target = torch.rand(2, 32, 32) + 0.1
    log_pred = (3.0 * target + 0.5).log()[:, None]
    loss, _ = depth_loss(log_pred, target)
    assert float(loss) < 1e-5
    assert torch.allclose(aligned(3.0 * target + 0.5, target), target, atol=1e-5)
    swapped, _ = depth_loss(target.flip(-1).log()[:, None], target)
    assert float(swapped) > 0.05


def test_train_depth_resumes_and_export_writes_a_loadable_tuned_graph(depth_data, tmp_path):
    run = tmp_path / "run"
    argv = ["train-depth", "--data", str(depth_data / "train"), "--val", str(depth_data / "val"),
            "--out", str(run), "--base", str(BASE), "--crop", "32x32", "--batch", "2",
            "--checkpoint-every", "2", "--val-every", "2", "--threads", "1",
            "--decals", "0.5"]  # fmt: skip
    assert main([*argv, "--steps", "2"]) == 0
    assert main([*argv, "--steps", "4"]) == 0  # resumes from step 2
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [0, 1, 2, 3, 4]
    assert {"data", "grad"} <= set(log[-1]["val"])
    out = tmp_path / "tuned" / "depth-tuned-fp32.onnx"
    photo, sheet = tmp_path / "photo.jpg", tmp_path / "sheets" / "sheet.png"
    Image.fromarray(np.random.default_rng(2).integers(0, 255, (480, 640, 3), np.uint8)).save(photo)
    argv = ["export-depth", str(run / "step-000004.pt"), "--out", str(out), "--base", str(BASE),
            "--photos", str(photo), "--sheet", str(sheet)]  # fmt: skip
    assert main(argv) == 0
    assert Image.open(sheet).size == (3 * 384, 288)  # input, base and tuned disparity
    manifest = json.loads(out.with_suffix(".json").read_text())
    assert manifest["file"] == out.name and manifest["training"]["steps"] == 4
    (row,) = manifest["validation"]["photos"]
    assert row["photo"] == "photo.jpg" and 0 < row["pearson"] < 1
    x = np.random.default_rng(1).random((1, 3, 32, 64), dtype=np.float32)
    (tuned,) = ort.InferenceSession(str(out)).run(None, {"image": x})
    (base,) = ort.InferenceSession(str(BASE)).run(None, {"image": x})
    assert np.abs(tuned - base).max() > 1e-4  # the weights moved ...
    net = DepthGraph.load(BASE)
    net.weights.load_state_dict(torch.load(run / "step-000004.pt", weights_only=False)["weights"])
    with torch.no_grad():
        assert np.abs(net(torch.from_numpy(x)).numpy() - tuned).max() < 1e-4  # ... into the file
    halfway = tmp_path / "halfway-fp32.onnx"
    argv = ["export-depth", str(run / "step-000004.pt"), "--out", str(halfway), "--base", str(BASE),
            "--int8", "--int8-base", str(INT8), "--strength", "0.5"]  # fmt: skip
    assert main(argv) == 0
    (half,) = ort.InferenceSession(str(halfway)).run(None, {"image": x})
    assert 0 < np.abs(half - base).max() < np.abs(tuned - base).max()
    assert json.loads(halfway.with_suffix(".json").read_text())["training"]["strength"] == 0.5
    (half8,) = ort.InferenceSession(str(tmp_path / "halfway-int8.onnx")).run(None, {"image": x})
    # the same weights in 8 bits (the shipped int8 and fp32 graphs agree at 0.97 on this noise)
    assert np.corrcoef(half8.ravel(), half.ravel())[0, 1] > 0.93
    manifest8 = json.loads((tmp_path / "halfway-int8.json").read_text())
    assert manifest8["precision"] == "int8" and manifest8["file"] == "halfway-int8.onnx"
    assert main([*argv[:-1], "1.5"]) == 2  # outside 0..1: refused
    assert main([*argv[:3], str(tmp_path / "no-precision.onnx"), *argv[4:]]) == 2
    assert not (tmp_path / "no-precision.onnx").exists()


def test_the_shipped_fp32_graph_quantises_back_to_the_shipped_int8_graph():
    model, clipped = quantised_model(INT8, onnx.load(BASE))
    shipped = onnx.load(INT8)
    assert clipped == 0
    ours = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    for init in shipped.graph.initializer:
        assert np.array_equal(ours[init.name], numpy_helper.to_array(init)), init.name


def test_a_run_resumes_whatever_order_its_checkpoint_holds_the_weights_in(depth_data, tmp_path):
    run = tmp_path / "run"
    argv = ["train-depth", "--data", str(depth_data / "train"), "--val", str(depth_data / "val"),
            "--out", str(run), "--base", str(BASE), "--crop", "32x32", "--batch", "2",
            "--checkpoint-every", "2", "--val-every", "2", "--threads", "1"]  # fmt: skip
    assert main([*argv, "--steps", "2"]) == 0
    state = torch.load(run / "last.pt", weights_only=False)
    names = list(state["weights"])
    state["weights"] = {n: state["weights"][n] for n in reversed(names)}
    moments = state["optimizer"]["state"]
    state["optimizer"]["state"] = {len(names) - 1 - i: m for i, m in moments.items()}
    torch.save(state, run / "last.pt")
    with (run / "log.jsonl").open("a") as log:  # a step logged after the checkpoint, then killed
        log.write(json.dumps({"step": 3, "loss": 1.0}) + "\n")
    assert main([*argv, "--steps", "3"]) == 0
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [0, 1, 2, 3] and "val" in log[-1]
    resumed = torch.load(run / "last.pt", weights_only=False)["optimizer"]["state"]
    net = DepthGraph.load(BASE)
    for i, (name, weight) in enumerate(net.weights.items()):
        assert resumed[i]["exp_avg"].shape == weight.shape, name


def test_train_depth_names_a_bad_crop_and_a_missing_folder(depth_data, tmp_path, capsys):
    common = ["--val", str(depth_data / "val"), "--out", str(tmp_path / "r"), "--base", str(BASE)]
    assert (
        main(["train-depth", "--data", str(depth_data / "train"), "--crop", "30x32", *common]) == 2
    )
    assert "multiples of 32" in capsys.readouterr().err
    assert main(["train-depth", "--data", str(tmp_path / "nothing"), *common]) == 2
    assert "nothing: dataset folder does not exist" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()  # nothing written for a run that cannot start


def test_a_corrupt_or_foreign_base_graph_is_named(depth_data, tmp_path, capsys):
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a protobuf at all")
    argv = ["train-depth", "--data", str(depth_data / "train"), "--val", str(depth_data / "val"),
            "--out", str(tmp_path / "r"), "--base", str(bad)]  # fmt: skip
    assert main(argv) == 2
    assert "bad.onnx: not a readable ONNX file" in capsys.readouterr().err
    reshade = BASE.parents[1] / "reshade" / "reshade-lite-fp32-decoder.onnx"
    assert main([*argv[:-1], str(reshade)]) == 2
    assert "reshade-lite-fp32-decoder.onnx: unsupported op" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_decals_paint_patterns_without_touching_depth():
    rng = np.random.default_rng(4)
    painted = paint_decals(np.ones((96, 128, 3), np.float32), rng, 4)
    assert painted.min() < 0.5 and (painted == 1).mean() > 0.3  # dark shapes, most untouched
    pair = Pair(
        np.full((96, 128, 3), 0.1, np.float16),
        np.linspace(0.2, 1, 128 * 96, dtype=np.float32).reshape(96, 128),
    )
    for seed in range(4):
        plain_rgb, plain = training_crop(pair, (64, 64), np.random.default_rng(seed))
        rgb, disparity = training_crop(pair, (64, 64), np.random.default_rng(seed), decals=1.0)
        assert np.array_equal(disparity, plain) or np.array_equal(disparity, plain[:, ::-1])
        assert np.ptp(plain_rgb) == 0 and np.ptp(rgb) > 0.1


def test_keep_loss_charges_plates_not_sharpened_steps():
    x = torch.arange(64.0)
    ramp = (1 + ((x - 28) / 8).clamp(0, 1)).expand(1, 1, 64, 64)  # the base network's soft step
    sharp = (1 + (x >= 32).float()).expand(1, 1, 64, 64)  # the same step, sharpened
    plate = ramp.clone()
    plate[..., 8:24, 8:20] += 0.5  # a window brought forward

    def pixelwise(a):
        return float((aligned(a[:, 0], ramp[:, 0]) - ramp[:, 0]).abs().mean() / ramp.mean())

    assert float(keep_loss(ramp.log(), ramp.log())) < 1e-6
    assert float(keep_loss((3 * ramp + 1).log(), ramp.log())) < 1e-5  # scale and shift are free
    assert float(keep_loss(sharp.log(), ramp.log())) < 0.4 * pixelwise(sharp)
    assert float(keep_loss(plate.log(), ramp.log())) > 0.8 * pixelwise(plate)


def test_train_depth_keeps_photos_and_names_a_bad_one(depth_data, tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(5)
    Image.fromarray(rng.integers(0, 255, (48, 80, 3), np.uint8)).save(photos / "a.png")
    run = tmp_path / "run"
    argv = ["train-depth", "--data", str(depth_data / "train"), "--val", str(depth_data / "val"),
            "--out", str(run), "--base", str(BASE), "--crop", "32x32", "--batch", "2",
            "--steps", "1", "--threads", "1", "--keep-photos", str(photos)]  # fmt: skip
    assert main(argv) == 0
    (record,) = [json.loads(r) for r in (run / "log.jsonl").read_text().splitlines()][1:]
    assert record["keep"] >= 0
    (photos / "b.jpg").write_bytes(b"not a jpeg")
    assert main([*argv, "--out", str(tmp_path / "run2")]) == 2  # the last --out counts
    assert "b.jpg" in capsys.readouterr().err and not (tmp_path / "run2").exists()


def test_input_only_examples_are_refused_for_reshading(depth_data):
    with pytest.raises(DatasetError, match="--input-only"):
        load_example(depth_data / "val" / "00000")
