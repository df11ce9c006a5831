import base64
import copy
import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from reshader_train import cli
from reshader_train.data import DatasetError
from reshader_train.export import (
    DECODER,
    ENCODER,
    MEAN_TOLERANCE,
    SINGLE,
    TOLERANCE,
    ExportError,
    ExportInfo,
    export_precision,
    parity_inputs,
    run_onnxruntime,
)
from reshader_train.model import EncoderGraph, ReshadeNet, net_config
from reshader_train.quantize import (
    calibrate,
    quantize_network,
    set_input_quantization,
    training_crops,
)
from reshader_train.synthetic import write_dataset

TINY = "4,4,4,4,4,4"
H, W = 32, 64
SCHEMA_KEYS = {
    "format", "name", "version", "task", "precision", "file", "sha256", "inputs", "outputs",
    "size_multiple", "image", "disparity_encoding", "camera", "architecture", "training",
    "validation", "licence", "source",
}  # fmt: skip
FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("ds") / "train", 3, 32, 32, seed=0)


@pytest.fixture(scope="module")
def nets(data):
    torch.manual_seed(0)
    net = ReshadeNet(net_config(TINY)).eval()
    # A visible residual: the default last layer starts the network near the identity.
    torch.nn.init.normal_(net.decoder.out.weight, std=0.3)
    q = quantize_network(copy.deepcopy(net))
    calibrate(q, training_crops(data, 2, 2, 32, seed=0))
    return {"fp32": net, "fp16": net, "int8": q.eval()}


@pytest.fixture(scope="module")
def exported(nets, tmp_path_factory):
    out = tmp_path_factory.mktemp("onnx")
    info = ExportInfo(size="tiny", validation={"psnr": 30.0})
    for precision, net in nets.items():
        export_precision(net, precision, out, f"reshade-tiny-{precision}", info, True, H, W)
    export_precision(
        nets["int8"], "int8", out, "reshade-tiny-int8-wo", info, False, H, W, int8_form="weights"
    )
    return out


def random_feed(seed=1):
    g = torch.Generator().manual_seed(seed)
    return {
        "image": torch.rand(1, 3, H, W, generator=g),
        "disparity": torch.rand(1, 1, H, W, generator=g),
        "camera": torch.tensor([[0.15, -0.1, 0.25]]),
    }


def split_output(out, stem, feed):
    enc = run_onnxruntime((out / f"{stem}-encoder.onnx").read_bytes(), feed)
    skips = dict(zip(EncoderGraph.output_names, map(torch.from_numpy, enc), strict=True))
    return run_onnxruntime((out / f"{stem}-decoder.onnx").read_bytes(), {**feed, **skips})[0]


@pytest.mark.parametrize("precision", ["fp32", "fp16", "int8"])
def test_onnx_matches_pytorch_within_tolerance(exported, nets, precision):
    feed = random_feed()
    with torch.no_grad():
        ref = nets[precision](feed["image"], feed["disparity"], feed["camera"]).numpy()
    got = run_onnxruntime((exported / f"reshade-tiny-{precision}.onnx").read_bytes(), feed)[0]
    assert got.shape == (1, 3, H, W)
    assert np.abs(got - ref).max() <= TOLERANCE[precision]
    assert np.abs(got - ref).mean() <= MEAN_TOLERANCE[precision]
    # The camera matters: a different camera gives a different image.
    other = run_onnxruntime(
        (exported / f"reshade-tiny-{precision}.onnx").read_bytes(),
        {**feed, "camera": torch.zeros(1, 3)},
    )[0]
    assert np.abs(other - got).max() > 10 * TOLERANCE["fp32"]


@pytest.mark.parametrize("precision", ["fp32", "fp16", "int8"])
def test_split_pair_equals_single_graph(exported, precision):
    feed = random_feed(2)
    stem = f"reshade-tiny-{precision}"
    single = run_onnxruntime((exported / f"{stem}.onnx").read_bytes(), feed)[0]
    split = split_output(exported, stem, feed)
    assert np.abs(single - split).max() <= 1e-5


@pytest.mark.parametrize("precision", ["fp32", "fp16", "int8"])
def test_manifests_describe_their_graphs(exported, precision):
    for kind in (SINGLE, ENCODER, DECODER):
        name = f"reshade-tiny-{precision}{kind.suffix}"
        m = json.loads((exported / f"{name}.json").read_text())
        assert set(m) == SCHEMA_KEYS
        data = (exported / m["file"]).read_bytes()
        assert m["sha256"] == hashlib.sha256(data).hexdigest()
        assert (m["format"], m["name"], m["task"], m["precision"]) == (
            "reshader-manifest/1",
            name,
            kind.task,
            precision,
        )
        graph = onnx.load_from_string(data).graph
        assert [i["name"] for i in m["inputs"]] == [i.name for i in graph.input]
        assert [o["name"] for o in m["outputs"]] == [o.name for o in graph.output]
        values = list(graph.input) + list(graph.output)
        for spec, value in zip(m["inputs"] + m["outputs"], values, strict=True):
            dims = value.type.tensor_type.shape.dim
            assert value.type.tensor_type.elem_type == onnx.TensorProto.FLOAT
            assert [d.dim_value or d.dim_param for d in dims] == spec["shape"]
        assert m["size_multiple"] == 32
        assert m["disparity_encoding"]["frequencies"] == 5
        assert m["camera"]["convention"] == "opencv"
        assert m["architecture"]["widths"] == [4, 4, 4, 4, 4, 4]
        assert m["architecture"]["parameters"] > 0
        assert m["architecture"]["gflops_at_384x640"] > 0
        assert m["validation"]["psnr"] == 30.0
        parity = m["validation"]["onnxruntime_vs_pytorch"]
        assert parity["max_abs"] <= parity["tolerance"]
    single = json.loads((exported / f"reshade-tiny-{precision}.json").read_text())
    enc, dec = (
        json.loads((exported / f"reshade-tiny-{precision}-{p}.json").read_text())
        for p in ("encoder", "decoder")
    )
    assert (
        enc["architecture"]["parameters"] + dec["architecture"]["parameters"]
        == single["architecture"]["parameters"]
    )


def consumers(graph):
    out = {}
    for n in graph.node:
        for i in n.input:
            out.setdefault(i, []).append(n)
    return out


def test_int8_graph_quantises_only_convolution_inputs_and_weights(exported):
    graph = onnx.load(exported / "reshade-tiny-int8.onnx").graph
    users = consumers(graph)
    inits = {i.name: i for i in graph.initializer}
    convs = [n for n in graph.node if n.op_type == "Conv" and "/upsample." not in n.name]
    blurs = [n for n in graph.node if n.op_type == "Conv" and "/upsample." in n.name]
    assert len(blurs) == 5  # the decoder's fixed upsampling kernels stay float
    quants = [n for n in graph.node if n.op_type == "QuantizeLinear"]
    assert len(quants) == len(convs) == 13
    for q in quants:  # activation Q feeds exactly one DQ, which feeds exactly one Conv input
        (dq,) = users[q.output[0]]
        assert dq.op_type == "DequantizeLinear"
        (conv,) = users[dq.output[0]]
        assert conv.op_type == "Conv" and conv.input[0] == dq.output[0]
        assert inits[q.input[2]].data_type == onnx.TensorProto.UINT8
    for conv in convs:
        (wdq,) = [n for n in graph.node if conv.input[1] in n.output]
        assert wdq.op_type == "DequantizeLinear"
        assert inits[wdq.input[0]].data_type == onnx.TensorProto.INT8
        assert inits[wdq.input[1]].dims == [inits[wdq.input[0]].dims[0]]  # per channel
    dq_total = sum(n.op_type == "DequantizeLinear" for n in graph.node)
    assert dq_total == 2 * len(convs)
    for n in graph.node:  # the float ops never see a quantised tensor
        if n.op_type in ("Expand", "LeakyRelu", "Resize", "Concat", "Gemm", "Tanh"):
            for i in n.input:
                assert not any(p.op_type in ("QuantizeLinear", "DequantizeLinear")
                               for p in graph.node if i in p.output)  # fmt: skip


def test_int8_weights_form_stores_int8_weights_and_float_activations(exported, nets):
    graph = onnx.load(exported / "reshade-tiny-int8-wo.onnx").graph
    ops = [n.op_type for n in graph.node]
    assert ops.count("QuantizeLinear") == 0
    assert ops.count("DequantizeLinear") == ops.count("Conv") - 5 == 13  # 5 float blurs
    feed = random_feed(3)
    q = copy.deepcopy(nets["int8"])
    set_input_quantization(q, False)
    with torch.no_grad():
        ref = q(feed["image"], feed["disparity"], feed["camera"]).numpy()
        full = nets["int8"](feed["image"], feed["disparity"], feed["camera"]).numpy()
    got = run_onnxruntime((exported / "reshade-tiny-int8-wo.onnx").read_bytes(), feed)[0]
    assert np.abs(got - ref).max() <= TOLERANCE["fp32"]  # float activations: fp32 arithmetic
    assert np.abs(got - full).max() > TOLERANCE["fp32"]  # and not the activation-quantised net


def test_export_refuses_wrong_network_or_size(nets, tmp_path):
    info = ExportInfo(size="tiny")
    with pytest.raises(ExportError, match="int8 export needs a quantised network"):
        export_precision(nets["fp32"], "int8", tmp_path, "x", info, False, H, W)
    with pytest.raises(ExportError, match="multiples of 32"):
        export_precision(nets["fp32"], "fp32", tmp_path, "x", info, False, 40, W)
    assert list(tmp_path.iterdir()) == []


def test_cli_exports_ptq_int8_with_provenance(data, tmp_path, capsys):
    torch.manual_seed(0)
    net = ReshadeNet(net_config(TINY))
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"command": "reshader-train train --x 1"}))
    (run / "log.csv").write_text("step,elapsed_s\n1,5.0\n2,10.0\n3,4.0\n")  # resumed once
    ckpt = {"model": net.state_dict(), "net_config": net.cfg.to_json(), "step": 3,
            "feature_net": "hed-test", "args": {"data": str(data)}}  # fmt: skip
    torch.save(ckpt, run / "checkpoint.pt")
    metrics = tmp_path / "m.json"
    metrics.write_text(json.dumps({"psnr_fp32": 31.5}))
    out = tmp_path / "out"
    argv = ["export", str(run / "checkpoint.pt"), "--out", str(out), "--precision", "int8",
            "--height", "32", "--width", "64", "--calibration", str(data),
            "--calibration-batches", "1", "--calibration-crop", "32",
            "--metrics", str(metrics)]  # fmt: skip
    assert cli.main(argv) == 0
    m = json.loads((out / "reshade-custom-int8-ptq.json").read_text())
    assert m["training"] == {
        "command": "reshader-train train --x 1",
        "data": str(data),
        "feature_network": "hed-test",
        "steps": 3,
        "wall_time_s": 14.0,
    }
    assert m["validation"]["psnr_fp32"] == 31.5
    assert m["validation"]["quantization"]["method"] == "ptq"
    assert cli.main(argv[:-4] + ["--calibration", str(tmp_path / "nowhere")]) == 2
    assert "nowhere" in capsys.readouterr().err


def test_quantize_fine_tunes_and_exports_qat(data, tmp_path):
    torch.manual_seed(0)
    net = ReshadeNet(net_config(TINY))
    torch.save(
        {"model": net.state_dict(), "net_config": net.cfg.to_json(), "step": 5,
         "args": {"data": str(data)}},
        tmp_path / "checkpoint.pt",
    )  # fmt: skip
    qat = tmp_path / "qat.pt"
    argv = ["quantize", str(tmp_path / "checkpoint.pt"), "--data", str(data), "--out", str(qat),
            "--steps", "2", "--batch-size", "2", "--crop", "32", "--calib-batches", "1",
            "--val-data", str(data), "--val-examples", "1", "--threads", "1"]  # fmt: skip
    assert cli.main(argv) == 0
    state = torch.load(qat, weights_only=False)
    assert state["quantization"]["method"] == "qat"
    assert set(state["validation"]) == {
        "fp32",
        "fp16",
        "int8_ptq",
        "int8_ptq_weights",
        "int8_qat",
        "int8_qat_weights",
    }
    fp32, fp16 = state["validation"]["fp32"], state["validation"]["fp16"]
    assert set(fp32) == {"psnr_input", "psnr", "ssim_input", "ssim", "count"}
    assert fp32["count"] == 1 and fp16["psnr_input"] == fp32["psnr_input"]
    assert fp16["psnr"] == pytest.approx(fp32["psnr"], abs=0.05)
    moved = (
        state["model"]["encoder.blocks.0.0.conv.weight"]
        - net.state_dict()["encoder.blocks.0.0.weight"]
    )
    assert moved.abs().max() > 0
    out = tmp_path / "out"
    assert cli.main(["export", str(qat), "--out", str(out), "--precision", "int8", "--split",
                     "--height", "32", "--width", "64"]) == 0  # fmt: skip
    m = json.loads((out / "reshade-custom-int8-decoder.json").read_text())
    assert m["validation"]["quantization"]["method"] == "qat"
    check = m["validation"]["quantize_check"]
    assert check["target"] == "fp32" and "reshader-train quantize" in check["command"]
    assert check["int8_qat_weights"]["count"] == 1
    assert m["training"]["steps"] == 7
    assert "reshader-train quantize" in m["training"]["command"]
    assert "--steps 2" in m["training"]["command"]


def decode(b64, h, w):
    return np.frombuffer(base64.b64decode(b64), dtype="<f4").reshape(1, 3, h, w)


@pytest.mark.skipif(not (FIXTURES / "parity.json").exists(), reason="fixture not generated")
def test_committed_fixture_is_consistent():
    parity = json.loads((FIXTURES / "parity.json").read_text())
    h, w = parity["height"], parity["width"]
    base = parity_inputs(h, w)
    assert float(base["image"].double().sum()) == pytest.approx(parity["input"]["image_sum"])
    for manifest in sorted(FIXTURES.glob("*.json")):
        if manifest.name.startswith("parity"):
            continue
        m = json.loads(manifest.read_text())
        data = (FIXTURES / m["file"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == m["sha256"], manifest
    for case in parity["cases"]:
        feed = {**base, "camera": torch.tensor([case["camera"]])}
        for precision, p in parity["precisions"].items():
            ref = decode(case[p["reference"]], h, w)
            got = run_onnxruntime(
                (FIXTURES / f"reshade-fixture-{precision}.onnx").read_bytes(), feed
            )
            assert np.abs(got[0] - ref).max() <= p["tolerance"], precision
    dep = parity["camera_dependence"]
    assert dep["max_abs_between_cameras"] > 100 * parity["precisions"]["fp32"]["tolerance"]


def test_training_can_start_from_an_exported_fp32_pair(exported, tmp_path):
    from reshader_train.onnx_weights import load_onnx_weights

    torch.manual_seed(3)
    trained = ReshadeNet(net_config(TINY)).eval()
    with torch.no_grad():
        for p in trained.parameters():
            # Trained weights: no two tensors alike (the exporter merges identical ones,
            # such as the zero biases of a fresh network, under one name).
            p.normal_(std=0.1)
    info = ExportInfo(size="tiny", validation={})
    export_precision(trained, "fp32", tmp_path, "trained", info, True, H, W)
    pair = [tmp_path / "trained-encoder.onnx", tmp_path / "trained-decoder.onnx"]
    for files in (pair, [tmp_path / "trained.onnx"]):
        net = ReshadeNet(net_config(TINY))
        assert load_onnx_weights(net, files) == len(list(net.parameters()))
        for (name, got), want in zip(net.named_parameters(), trained.parameters(), strict=True):
            assert torch.equal(got, want), name
    with pytest.raises(ValueError, match="fp32"):  # a half-precision export is refused
        load_onnx_weights(
            ReshadeNet(net_config(TINY)),
            [
                exported / "reshade-tiny-fp16-encoder.onnx",
                exported / "reshade-tiny-fp16-decoder.onnx",
            ],
        )
    with pytest.raises(ValueError, match="network wants"):
        load_onnx_weights(ReshadeNet(net_config("8,8,8,8,8,8")), pair)
    with pytest.raises(ValueError, match="no weights for"):
        load_onnx_weights(ReshadeNet(net_config(TINY)), pair[:1])
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(ValueError, match="junk.onnx"):
        load_onnx_weights(ReshadeNet(net_config(TINY)), [junk])
    # A lobes network takes the residual model's encoder and up-path; its camera-free
    # bottleneck conv weights and its output conv have other shapes and keep their initial
    # values (the bottleneck's bias has the same shape and is copied).
    lobes = ReshadeNet(replace(net_config(TINY), head="lobes"))
    fresh = {n: p.detach().clone() for n, p in lobes.named_parameters()}
    with pytest.raises(ValueError, match="no weights for|network wants"):
        load_onnx_weights(lobes, pair)
    count = load_onnx_weights(lobes, pair, partial=True)
    trained_params = dict(trained.named_parameters())
    for name, got in lobes.named_parameters():
        if name in ("decoder.bottleneck.0.weight", "decoder.out.weight", "decoder.out.bias"):
            assert torch.equal(got, fresh[name]), name
        else:
            assert torch.equal(got, trained_params[name]), name
    assert count == len(fresh) - 3


def test_quantize_weights_form_fine_tunes_with_float_activations(data, tmp_path, act_quant_calls):
    torch.manual_seed(0)
    net = ReshadeNet(net_config(TINY))
    ckpt = tmp_path / "checkpoint.pt"
    torch.save({"model": net.state_dict(), "net_config": net.cfg.to_json(), "step": 5}, ckpt)
    calls = act_quant_calls
    argv = ["quantize", str(ckpt), "--data", str(data), "--steps", "2", "--batch-size", "2",
            "--crop", "32", "--calib-batches", "1", "--threads", "1"]  # fmt: skip
    assert cli.main(argv + ["--out", str(tmp_path / "w.pt"), "--form", "weights"]) == 0
    assert calls["n"] == 0
    state = torch.load(tmp_path / "w.pt", weights_only=False)
    assert state["quantization"]["qat_form"] == "weights"
    assert state["quantization"]["qat_target"] == "fp32"
    assert cli.main(argv + ["--out", str(tmp_path / "q.pt")]) == 0
    assert calls["n"] > 0


def test_quantize_pools_the_crops_of_several_folders(data, tmp_path):
    import shutil

    torch.manual_seed(0)
    net = ReshadeNet(net_config(TINY))
    ckpt = tmp_path / "checkpoint.pt"
    torch.save({"model": net.state_dict(), "net_config": net.cfg.to_json(), "step": 5}, ckpt)
    other = tmp_path / "other-family"
    shutil.copytree(data, other)
    argv = ["quantize", str(ckpt), "--data", str(data), str(other), "--steps", "1",
            "--batch-size", "2", "--crop", "32", "--calib-batches", "1", "--threads", "1",
            "--form", "weights", "--out", str(tmp_path / "w.pt")]  # fmt: skip
    assert cli.main(argv) == 0
    state = torch.load(tmp_path / "w.pt", weights_only=False)
    assert state["qat_data"].split() == [str(data.resolve()), str(other.resolve())]
    with pytest.raises(DatasetError, match="missing"):
        next(training_crops([data, tmp_path / "missing"], 1, 2, 32, seed=0))


def test_flow_head_with_dead_zone_exports_in_every_precision(data, tmp_path):
    from dataclasses import replace

    torch.manual_seed(2)
    cfg = replace(net_config(TINY), head="flow", deadzone=0.004)
    net = ReshadeNet(cfg).eval()
    torch.nn.init.normal_(net.decoder.out.weight, std=0.3)
    q = quantize_network(copy.deepcopy(net))
    calibrate(q, training_crops(data, 2, 2, 32, seed=0))
    info = ExportInfo(size="flow", validation={})
    export_precision(net, "fp32", tmp_path, "flow-fp32", info, True, H, W)
    export_precision(q.eval(), "int8", tmp_path, "flow-int8", info, True, H, W)
    m = json.loads((tmp_path / "flow-fp32-decoder.json").read_text())
    assert m["architecture"]["head"] == "flow" and m["architecture"]["out_channels"] == 15
    assert m["architecture"]["deadzone"] == 0.004
    feed = random_feed()
    with torch.no_grad():
        ref = net(feed["image"], feed["disparity"], feed["camera"]).numpy()
    got = split_output(tmp_path, "flow-fp32", feed)
    assert np.abs(ref - feed["image"].numpy()).max() > 0.05  # a visible change to compare
    assert np.abs(got - ref).max() <= TOLERANCE["fp32"]
    still = split_output(tmp_path, "flow-fp32", {**feed, "camera": torch.zeros(1, 3)})
    assert np.array_equal(still, feed["image"].numpy())  # the input camera keeps the photo
    graph = onnx.load(tmp_path / "flow-int8-decoder.onnx").graph
    gradients = [n for n in graph.node if n.op_type == "Conv" and "/gradient/" in n.name]
    assert len(gradients) == 1
    (source,) = [n for n in graph.node if gradients[0].input[1] in n.output]
    assert source.op_type == "Constant"  # a float kernel, not a dequantised one


def test_import_rebuilds_a_checkpoint_from_an_exported_pair(nets, tmp_path, capsys):
    # Distinct values everywhere: the ONNX exporter merges identical initialisers (such as
    # an untrained network's zero biases) under one name.
    net = copy.deepcopy(nets["fp32"])
    torch.manual_seed(5)
    for p in net.parameters():
        p.data.normal_(0.0, 0.1)
    export_precision(
        net, "fp32", tmp_path, "src", ExportInfo(size="tiny", validation={}), True, H, W
    )
    out = tmp_path / "imported.pt"
    enc, dec = (tmp_path / f"src-{part}.onnx" for part in ("encoder", "decoder"))
    assert cli.main(["import", str(enc), str(dec), "--out", str(out), "--deadzone", "0.01"]) == 0
    state = torch.load(out, weights_only=False)
    assert state["net_config"]["deadzone"] == 0.01
    assert list(state["net_config"]["widths"]) == [4] * 6
    for name, value in net.state_dict().items():
        assert torch.equal(state["model"][name], value), name
    assert state["command"].endswith("--deadzone 0.01")
    assert "reshader-train import" in state["command"]
    # The loss the weights were trained with comes from the source's command.
    assert state.get("pixel_loss") is None  # the test export's command names none
    from reshader_train.from_onnx import loss_options

    line = "reshader-train train --loss-weights 1,0,0 --pixel-loss psnr --steps 9"
    assert loss_options(line) == {"loss_weights": "1,0,0", "pixel_loss": "psnr"}
    bare = tmp_path / "bare.onnx"
    bare.write_bytes(enc.read_bytes())
    assert cli.main(["import", str(bare), "--out", str(tmp_path / "x.pt")]) == 2
    assert "bare.json" in capsys.readouterr().err
    assert not (tmp_path / "x.pt").exists()


def test_qat_learns_the_float_output_or_the_truth(data):
    from reshader_train.quantize import qat_target

    torch.manual_seed(0)
    net = ReshadeNet(net_config(TINY)).eval()
    batch = next(training_crops(data, 1, 2, 32, 0))
    assert torch.equal(qat_target(net, batch, "truth"), batch["target"])
    distilled = qat_target(net, batch, "fp32")
    assert not distilled.requires_grad
    assert torch.equal(distilled, net(batch["image"], batch["disparity"], batch["camera"]))
    assert not torch.equal(distilled, batch["target"])


# --- the lobe head ----------------------------------------------------------------------------

LOBE_TINY = "4,8,8,16,16,16"
LOBE_KEYS = {"head", "lobes", "lobe_layout", "channels", "deadzone", "domain", "disparity_depth",
             "shading"}  # fmt: skip


def lobe_net(seed=0):
    from dataclasses import replace

    torch.manual_seed(seed)
    net = ReshadeNet(replace(net_config(LOBE_TINY), head="lobes", lobes=2, deadzone=0.004))
    torch.nn.init.normal_(net.decoder.out.weight, std=0.3)  # visible lobes
    return net.eval()


def lobe_feed(seed=4):
    from reshader_train.export import parity_intrinsics, pixel_rays

    g = torch.Generator().manual_seed(seed)
    return {
        "image": torch.rand(1, 3, H, W, generator=g),
        "disparity": 0.05 + 0.5 * torch.rand(1, 1, H, W, generator=g),
        "rays": pixel_rays(parity_intrinsics(H, W), H, W),
    }


@pytest.fixture(scope="module")
def lobe_exported(data, tmp_path_factory):
    from reshader_train.quantize import set_input_quantization

    out = tmp_path_factory.mktemp("lobes")
    net = lobe_net()
    q = quantize_network(copy.deepcopy(net))
    calibrate(q, training_crops(data, 2, 2, 32, seed=0))
    set_input_quantization(q, False)
    info = ExportInfo(size="tiny", validation={})
    paths = []
    for precision, model, form in (("fp32", net, "qdq"), ("fp16", net, "qdq"),
                                   ("int8", q.eval(), "weights")):  # fmt: skip
        stem = f"reshade-tiny-{precision}" + ("-wo" if form == "weights" else "")
        # --split does not apply: the lobe head is one graph.
        paths += export_precision(model, precision, out, stem, info, True, H, W, int8_form=form)
    return out, paths, {"fp32": net, "fp16": net, "int8": q}


def test_lobe_head_exports_one_graph_per_precision_with_its_manifest(lobe_exported):
    from reshader_train.export import LOBES
    from reshader_train.model import LOBE_LAYOUT

    out, paths, _ = lobe_exported
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        f"reshade-tiny-{p}-lobes.{ext}"
        for p in ("fp32", "fp16", "int8-wo")
        for ext in ("json", "onnx")
    )
    for path in paths:
        m = json.loads(path.read_text())
        assert set(m) == SCHEMA_KEYS | LOBE_KEYS
        assert (m["task"], m["head"], m["lobes"], m["domain"]) == (
            LOBES.task,
            "lobes",
            2,
            "display",
        )
        assert m["deadzone"] == 0.004 and m["lobe_layout"] == list(LOBE_LAYOUT)
        assert m["channels"][:8] == [*(f"{n}0" for n in LOBE_LAYOUT), "mu_x1"]
        assert m["architecture"]["head"] == "lobes" and m["architecture"]["lobes"] == 2
        assert m["architecture"]["out_channels"] == 14
        data = (out / m["file"]).read_bytes()
        assert m["sha256"] == hashlib.sha256(data).hexdigest()
        graph = onnx.load_from_string(data).graph
        assert [i["name"] for i in m["inputs"]] == ["image", "disparity", "rays"]
        assert [i.name for i in graph.input] == ["image", "disparity", "rays"]
        assert [o["name"] for o in m["outputs"]] == [o.name for o in graph.output] == ["lobes"]
        for spec, value in zip(m["inputs"] + m["outputs"], list(graph.input) + list(graph.output),
                               strict=True):  # fmt: skip
            dims = value.type.tensor_type.shape.dim
            assert [d.dim_value or d.dim_param for d in dims] == spec["shape"]
        parity = m["validation"]["onnxruntime_vs_pytorch"]
        assert parity["max_abs"] <= parity["tolerance"]
        assert set(parity["shaded"]) == {"[0.12, -0.05, 0.2]", "[0.5, 0.0, 0.0]"}


@pytest.mark.parametrize("precision", ["fp32", "fp16", "int8"])
def test_lobe_graph_matches_pytorch_and_shades_like_it(lobe_exported, precision):
    from reshader_train.export import comparable_lobes
    from reshader_train.model import shade_lobes

    out, _, nets = lobe_exported
    net = nets[precision]
    feed = lobe_feed()
    stem = f"reshade-tiny-{'int8-wo' if precision == 'int8' else precision}-lobes"
    (got,) = run_onnxruntime((out / f"{stem}.onnx").read_bytes(), feed)
    with torch.no_grad():
        ref = net.lobes(feed["image"], feed["disparity"], feed["rays"]).numpy()
    assert got.shape == (1, 14, H, W)
    diff = np.abs(comparable_lobes(got, 2) - comparable_lobes(ref, 2))
    assert diff.max() <= TOLERANCE[precision] and diff.mean() <= MEAN_TOLERANCE[precision]

    def shade(lobes, camera):
        args = (feed["image"], torch.from_numpy(lobes), feed["disparity"], feed["rays"])
        return shade_lobes(*args, torch.tensor([camera]), 0.004).clamp(0, 1).numpy()

    for camera in ((0.2, -0.1, 0.15), (0.5, 0.0, 0.0)):
        theirs, ours = shade(got, camera), shade(ref, camera)
        assert np.abs(theirs - ours).max() <= {"fp32": 1e-4, "fp16": 2e-2, "int8": 1e-4}[precision]
        assert np.abs(ours - feed["image"].numpy()).max() > 0.05  # a visible change
    assert np.array_equal(shade(got, (0.0, 0.0, 0.0)), feed["image"].numpy())


def slide_net():
    from dataclasses import replace

    torch.manual_seed(1)
    cfg = replace(net_config(LOBE_TINY), head="lobes-slide", lobes=1, deadzone=0.004)
    net = ReshadeNet(cfg)
    torch.nn.init.normal_(net.decoder.out.weight, std=0.3)
    with torch.no_grad():
        net.decoder.out.bias[7:10] = 3.0  # half the photo slides: a visible layer
    return net.eval()


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_lobes_slide_exports_its_layer_and_shades_like_pytorch(tmp_path, precision):
    from reshader_train.export import run_onnxruntime
    from reshader_train.model import SLIDE_LAYOUT, shade_lobes

    net = slide_net()
    info = ExportInfo(size="tiny", validation={})
    (path,) = export_precision(net, precision, tmp_path, "slide", info, False, H, W)
    m = json.loads(path.read_text())
    assert (m["head"], m["lobes"], m["architecture"]["lobes"]) == ("lobes-slide", 1, 1)
    assert m["channels"][7:] == list(SLIDE_LAYOUT) and m["outputs"][0]["shape"][1] == 11
    assert "lobes-slide adds" in m["shading"]
    feed = lobe_feed()
    (got,) = run_onnxruntime((tmp_path / m["file"]).read_bytes(), feed)
    with torch.no_grad():
        ref = net.lobes(feed["image"], feed["disparity"], feed["rays"])

    def shade(fields, camera):
        args = (feed["image"], torch.as_tensor(fields), feed["disparity"], feed["rays"])
        c = torch.tensor([camera])
        return shade_lobes(*args, c, 0.004, head="lobes-slide").clamp(0, 1).numpy()

    tol = {"fp32": 1e-4, "fp16": 3e-2}[precision]  # fp16 rounds rho: the layer shifts a little
    for camera in ((0.2, -0.1, 0.15), (0.5, 0.0, 0.0)):
        ours = shade(ref, camera)
        assert np.abs(shade(got, camera) - ours).max() <= tol
        assert np.abs(ours - feed["image"].numpy()).max() > 0.05
    assert np.array_equal(shade(got, (0.0, 0.0, 0.0)), feed["image"].numpy())


def lobe_checkpoint(tmp_path, data, net=None):
    """A training checkpoint of `net` (default: lobe_net()) in tmp_path."""
    net = net or lobe_net()
    path = tmp_path / "lobes.pt"
    torch.save({"model": net.state_dict(), "net_config": net.cfg.to_json(), "step": 4,
                "args": {"data": str(data)}}, path)  # fmt: skip
    return path


def export_fp32(ckpt, out) -> int:
    """`export` of `ckpt` at fp32 and 32x64 into `out`; its exit status."""
    return cli.main(["export", str(ckpt), "--out", str(out), "--precision", "fp32",
                     "--height", "32", "--width", "64"])  # fmt: skip


@pytest.mark.parametrize(
    "change, reason",
    [
        ({"domain": "linear"}, "linear domain"),
        ({"head": "lobes-flow"}, "lobes-flow head is for training experiments"),
    ],
)
def test_a_lobe_checkpoint_the_runtime_cannot_evaluate_is_refused_with_the_reason(
    data, tmp_path, capsys, change, reason
):
    ckpt = lobe_checkpoint(tmp_path, data, ReshadeNet(replace(lobe_net().cfg, **change)))
    out = tmp_path / "out"
    assert export_fp32(ckpt, out) != 0
    assert reason in capsys.readouterr().err
    assert not out.exists() or not list(out.iterdir())


def test_a_linear_clamped_lobe_checkpoint_with_photo_amplitudes_exports(data, tmp_path):
    cfg = replace(lobe_net().cfg, domain="linear-clamped", amplitude="photo")
    out = tmp_path / "out"
    assert export_fp32(lobe_checkpoint(tmp_path, data, ReshadeNet(cfg)), out) == 0
    (path,) = out.glob("*.json")
    m = json.loads(path.read_text())
    assert m["domain"] == "linear-clamped" and m["architecture"]["amplitude"] == "photo"
    assert "linear-clamped" in m["shading"]
    parity = m["validation"]["onnxruntime_vs_pytorch"]
    assert "amplitudes" in parity["compared"] and max(parity["shaded"].values()) < 1e-4


def test_cli_exports_a_lobe_checkpoint_and_quantize_fine_tunes_it(data, tmp_path, capsys):
    ckpt = lobe_checkpoint(tmp_path, data)
    out = tmp_path / "out"
    argv = ["export", str(ckpt), "--out", str(out), "--precision", "fp32", "fp16", "--split",
            "--height", "32", "--width", "64"]  # fmt: skip
    assert cli.main(argv) == 0
    assert "--split ignored" in capsys.readouterr().err
    assert sorted(p.name for p in out.glob("*.json")) == [
        "reshade-custom-fp16-lobes.json",
        "reshade-custom-fp32-lobes.json",
    ]
    # QAT in the weights-only form shipped for tract: the samples carry rays and the network
    # takes them as its fourth argument.
    qat = tmp_path / "qat.pt"
    argv = ["quantize", str(ckpt), "--data", str(data), "--out", str(qat), "--steps", "2",
            "--batch-size", "2", "--crop", "32", "--calib-batches", "1", "--form", "weights",
            "--val-data", str(data), "--val-examples", "1", "--threads", "1"]  # fmt: skip
    assert cli.main(argv) == 0
    state = torch.load(qat, weights_only=False)
    assert state["net_config"]["head"] == "lobes"
    assert state["validation"]["int8_qat_weights"]["count"] == 1
    argv = ["export", str(qat), "--out", str(out), "--precision", "int8", "--int8-form",
            "weights", "--height", "32", "--width", "64"]  # fmt: skip
    assert cli.main(argv) == 0
    m = json.loads((out / "reshade-custom-int8-wo-lobes.json").read_text())
    assert m["task"] == "reshade-lobes" and m["precision"] == "int8"
    assert m["validation"]["quantization"]["form"] == "weights"
    assert m["validation"]["quantization"]["method"] == "qat"
    ops = [n.op_type for n in onnx.load(out / m["file"]).graph.node]
    assert ops.count("QuantizeLinear") == 0
    assert ops.count("DequantizeLinear") == ops.count("Conv") - 5  # 5 float upsampling blurs


@pytest.mark.skipif(not (FIXTURES / "parity-lobes.json").exists(), reason="fixture not generated")
@pytest.mark.parametrize("folder, head", [(".", "lobes"), ("slide", "lobes-slide")])
def test_committed_lobe_fixture_is_consistent(folder, head):
    from reshader_train.model import lobe_head_channels, shade_lobes

    fixtures = FIXTURES / folder
    parity = json.loads((fixtures / "parity-lobes.json").read_text())
    assert parity.get("head", "lobes") == head
    h, w, k = parity["height"], parity["width"], parity["lobes"]
    base = parity_inputs(h, w)
    cam = parity["camera"]
    assert float(base["image"].double().sum()) == pytest.approx(parity["input"]["image_sum"])
    assert float(base["rays"][0, 0, 0, 0]) == pytest.approx(-cam["cx"] / cam["fx"])
    lobes = np.frombuffer(base64.b64decode(parity["lobes_fp32"]), dtype="<f4")
    lobes = torch.from_numpy(lobes.reshape(1, lobe_head_channels(head, k), h, w).copy())
    for precision, p in parity["precisions"].items():
        m = json.loads((fixtures / p["model"]).read_text())
        assert (m["task"], m["precision"], m["lobes"], m["head"]) == (
            "reshade-lobes",
            precision,
            k,
            head,
        )
        data = (fixtures / m["file"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == m["sha256"]
        (got,) = run_onnxruntime(data, base)
        for case in parity["cases"]:
            c = torch.tensor([case["camera"]])
            args = (base["image"], torch.from_numpy(got), base["disparity"], base["rays"], c)
            view = shade_lobes(*args, parity["deadzone"], head=head).clamp(0, 1).numpy()
            assert np.abs(view - decode(case[p["reference"]], h, w)).max() <= p["tolerance"]
    # The stored lobes shade to the stored fp32 views. Not bit for bit: torch releases
    # round exp and the normalisations differently (up to 3e-6 seen), a thousandth of a level.
    for case in parity["cases"]:
        c = torch.tensor([case["camera"]])
        view = shade_lobes(base["image"], lobes, base["disparity"], base["rays"], c,
                           parity["deadzone"], head=head).clamp(0, 1).numpy()  # fmt: skip
        assert np.abs(view - decode(case["reshaded"], h, w)).max() <= 1e-5
    dep = parity["camera_dependence"]
    assert dep["[0.0, 0.0, 0.0]"]["max_abs_change"] == 0.0
    assert dep["[0.5, 0.0, 0.0]"]["max_abs_change"] > 0.1


@pytest.mark.parametrize("precision", ["fp32", "int8"])
def test_film_decoder_exports_and_imports_with_its_camera_gains(data, tmp_path, precision):
    torch.manual_seed(3)
    net = ReshadeNet(replace(net_config(TINY), film=True, deadzone=0.008)).eval()
    # Distinct values everywhere (the exporter merges identical initialisers, such as zero
    # biases, under one name) and camera gains far from their zero start.
    for p in net.parameters():
        p.data.normal_(0.0, 0.3)
    if precision == "int8":
        net = quantize_network(copy.deepcopy(net))
        calibrate(net, training_crops(data, 2, 2, 32, seed=0))
        net.eval()
        set_input_quantization(net, False)  # the shipped form: int8 weights, float activations
    info = ExportInfo(size="film", validation={})
    form = {"int8_form": "weights"} if precision == "int8" else {}
    export_precision(net, precision, tmp_path, "film", info, True, H, W, **form)
    m = json.loads((tmp_path / "film-decoder.json").read_text())
    assert m["architecture"]["film"] is True
    feed = random_feed()
    with torch.no_grad():
        ref = net(feed["image"], feed["disparity"], feed["camera"]).numpy()
    got = split_output(tmp_path, "film", feed)
    assert np.abs(got - ref).max() <= TOLERANCE["fp32"]
    if precision == "fp32":
        out = tmp_path / "imported.pt"
        pair = [str(tmp_path / f"film-{part}.onnx") for part in ("encoder", "decoder")]
        assert cli.main(["import", *pair, "--out", str(out)]) == 0
        assert torch.load(out, weights_only=False)["net_config"]["film"] is True
