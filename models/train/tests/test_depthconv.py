"""Tests of the Tiefenrausch Caffe2 -> ONNX converter.

The real-model tests read ../shared/third_party/tiefenrausch (relative to the repository) and
skip, saying so, when that folder is absent.
"""

import struct
from pathlib import Path

import numpy as np
import pytest

from reshader_train.depthconv.caffe2_model import Caffe2ModelError, load_caffe2_model
from reshader_train.depthconv.preprocess import area_resize, network_input, network_size
from reshader_train.depthconv.protobuf import NetDef, ProtobufError, fields, read_netdef

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from reshader_train.depthconv.onnx_export import build_onnx  # noqa: E402

SOURCE = Path(__file__).resolve().parents[3] / "../shared/third_party/tiefenrausch"
needs_source = pytest.mark.skipif(
    not (SOURCE / "model/tiefenrausch.pb").is_file(),
    reason=f"Tiefenrausch model folder absent: {SOURCE.resolve()}",
)


# --- a tiny protobuf encoder, only for building test NetDefs ---------------------------------


def _varint(v: int) -> bytes:
    v &= (1 << 64) - 1
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        out.append(b | (0x80 if v else 0))
        if not v:
            return bytes(out)


def _len(num: int, payload: bytes) -> bytes:
    return _varint(num << 3 | 2) + _varint(len(payload)) + payload


def _arg(name: str, *, f=None, i=None, s=None, ints=()) -> bytes:
    out = _len(1, name.encode())
    if f is not None:
        out += _varint(2 << 3 | 5) + struct.pack("<f", f)
    if i is not None:
        out += _varint(3 << 3) + _varint(i)
    if s is not None:
        out += _len(4, s)
    for v in ints:
        out += _varint(6 << 3) + _varint(v)
    return out


def _op(kind: str, inputs, outputs, args) -> bytes:
    out = b"".join(_len(1, n.encode()) for n in inputs)
    out += b"".join(_len(2, n.encode()) for n in outputs)
    out += _len(4, kind.encode())
    return out + b"".join(_len(5, a) for a in args)


def _net(name: str, ops, ext_in=(), ext_out=()) -> bytes:
    out = _len(1, name.encode()) + b"".join(_len(2, o) for o in ops)
    out += b"".join(_len(7, n.encode()) for n in ext_in)
    return out + b"".join(_len(8, n.encode()) for n in ext_out)


def _q(scale, zp):
    return [_arg("Y_scale", f=scale), _arg("Y_zero_point", i=zp)]


# --- protobuf reader ---------------------------------------------------------------------------


def test_reader_decodes_varints_packed_and_nested_fields():
    packed = _len(6, b"".join(_varint(v) for v in (3, 300, -2)))
    arg = _len(1, b"k") + packed + _varint(2 << 3 | 5) + struct.pack("<f", 0.25)
    buf = _len(1, b"net") + _len(2, _len(4, b"Int8Add") + _len(5, arg)) + _len(8, b"out")
    net = NetDef.parse(buf)
    assert net.name == "net" and net.external_output == ["out"]
    a = net.op[0].arg["k"]
    assert net.op[0].type == "Int8Add" and a.ints == [3, 300, -2] and a.f == 0.25


def test_reader_rejects_truncated_bytes_naming_the_file(tmp_path):
    bad = tmp_path / "broken.pb"
    bad.write_bytes(_len(1, b"net")[:-1] + b"\x12\xff")
    with pytest.raises(ProtobufError, match="broken.pb"):
        read_netdef(bad)
    with pytest.raises(ProtobufError):
        fields(b"\x0f")  # wire type 7 does not exist


# --- conversion semantics on a tiny hand-made network ------------------------------------------


def _tiny_model(tmp_path, w_u8, bias, kernel):
    """Input (3 channels) -> Int8Quantize -> Int8Conv -> Int8Dequantize, as Caffe2 NetDefs."""
    x_s, x_z, w_s, w_z, y_s, y_z = 1 / 128, 128, 0.02, 128, 0.01, 100
    m, kh, kw, c = w_u8.shape
    init = _net(
        "init",
        [
            _op(
                "Int8GivenTensorFill",
                [],
                ["w"],
                [_arg("values", s=w_u8.tobytes()), _arg("shape", ints=w_u8.shape)] + _q(w_s, w_z),
            ),
            _op(
                "Int8GivenIntTensorFill",
                [],
                ["b"],
                [_arg("values", ints=bias.tolist()), _arg("shape", ints=[m])] + _q(x_s * w_s, 0),
            ),
        ],
    )
    conv_args = [
        _arg("kernels", ints=[kh, kw]),
        _arg("strides", ints=[1, 1]),
        _arg("pads", ints=[kh // 2] * 4),
        _arg("dilations", ints=[1, 1]),
        _arg("group", i=1),
        _arg("order", s=b"NHWC"),
    ]
    predict = _net(
        "predict",
        [
            _op("NCHW2NHWC", ["x"], ["x_nhwc"], []),
            _op("Int8Quantize", ["x_nhwc"], ["xq"], _q(x_s, x_z)),
            _op("Int8Conv", ["xq", "w", "b"], ["yq"], conv_args + _q(y_s, y_z)),
            _op("Int8Dequantize", ["yq"], ["y"], []),
        ],
        ext_in=["x", "w", "b"],
        ext_out=["y"],
    )
    (tmp_path / "p.pb").write_bytes(predict)
    (tmp_path / "i.pb").write_bytes(init)
    return load_caffe2_model(tmp_path / "p.pb", tmp_path / "i.pb"), (x_s, x_z, w_s, w_z, y_s, y_z)


def _expected_int8(x, w_u8, bias, q):
    """Caffe2 Int8Conv by hand: NHWC kernels [M, kH, kW, C], uint8 output clamped to [0, 255]."""
    x_s, x_z, w_s, w_z, y_s, y_z = q
    xq = np.clip(np.rint(x / x_s) + x_z, 0, 255) - x_z  # [C, H, W]
    m, kh, kw, c = w_u8.shape
    pad = np.pad(xq, ((0, 0), (kh // 2, kh // 2), (kw // 2, kw // 2)))
    h, w = x.shape[1:]
    acc = np.zeros((m, h, w)) + bias[:, None, None]
    wz = w_u8.astype(np.int64) - w_z
    for dy in range(kh):
        for dx in range(kw):
            acc += np.einsum("mc,chw->mhw", wz[:, dy, dx, :], pad[:, dy : dy + h, dx : dx + w])
    yq = np.clip(np.rint(acc * (x_s * w_s / y_s)) + y_z, 0, 255)
    return (yq - y_z) * y_s


@pytest.mark.parametrize("form", ["qlinear", "qdq", "fp32"])
def test_tiny_conv_matches_caffe2_semantics(tmp_path, form):
    rng = np.random.default_rng(1)
    w_u8 = rng.integers(60, 200, size=(4, 3, 3, 3), dtype=np.uint8)  # not symmetric in kH/kW/C
    bias = rng.integers(-3000, 3000, size=4).astype(np.int32)
    model, q = _tiny_model(tmp_path, w_u8, bias, 3)
    x = rng.random((1, 3, 8, 6), dtype=np.float32)
    sess = ort.InferenceSession(build_onnx(model, form).SerializeToString())
    (y,) = sess.run(None, {"image": x})
    expected = _expected_int8(x[0].astype(np.float64), w_u8, bias, q)
    step = q[4]
    if form == "fp32":
        # No rounding of activations: within one output step plus input rounding effects.
        assert np.abs(y[0] - expected).max() <= 2.5 * step
    else:
        assert np.abs(y[0] - expected).max() <= step * 1.001  # ties may round the other way
        assert np.mean(np.abs(y[0] - expected) < 1e-6) > 0.95


def test_unsupported_op_is_named(tmp_path):
    (tmp_path / "p.pb").write_bytes(_net("p", [_op("Int8Sigmoid", ["x"], ["y"], [])], ["x"], ["y"]))
    (tmp_path / "i.pb").write_bytes(_net("i", [_op("Int8GivenIntTensorFill", [], ["b"], [])]))
    with pytest.raises(Caffe2ModelError):
        load_caffe2_model(tmp_path / "p.pb", tmp_path / "i.pb")
    (tmp_path / "i.pb").write_bytes(_net("i", []))
    with pytest.raises(ProtobufError, match="no operators"):
        load_caffe2_model(tmp_path / "p.pb", tmp_path / "i.pb")


# --- input convention ------------------------------------------------------------------------


def test_network_size_follows_the_original_rounding():
    assert network_size(4032, 3024) == (384, 288)
    assert network_size(1000, 1500) == (256, 384)
    assert network_size(500, 1000) == (192, 384)  # 192 already a multiple of 32
    assert network_size(700, 1000) == (256, 384)  # 268.8 -> 268 -> 256
    with pytest.raises(ValueError):
        network_size(10, 1000)


def test_area_resize_averages_blocks():
    img = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    out = area_resize(img, 2, 3)
    sums = img.reshape(2, 2, 3, 2, 3).astype(int).sum(axis=(1, 3))
    assert np.array_equal(out, (sums + 2) // 4)  # 2x2 blocks: halves round up, as OpenCV's
    out = area_resize(img[:3, :3], 1, 1)
    assert out[0, 0].tolist() == np.rint(img[:3, :3].mean(axis=(0, 1))).tolist()
    flat = np.full((9, 7, 3), 77, np.uint8)
    assert np.all(area_resize(flat, 4, 3) == 77)  # non-integer factors keep a constant


# --- the real model --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def real_model():
    return load_caffe2_model(
        SOURCE / "model/tiefenrausch.pb", SOURCE / "model/tiefenrausch_init.pb"
    )


@needs_source
def test_reads_the_shipped_netdefs(real_model):
    predict = read_netdef(SOURCE / "model/tiefenrausch.pb")
    assert predict.external_input[0] == "0" and predict.external_output == ["623"]
    assert real_model.op_counts() == {
        "Quantize": 1,
        "Conv": 146,
        "Add": 39,
        "ResizeNearest": 5,
        "Dequantize": 1,
    }
    assert real_model.parameter_count() == 3_550_841
    first = real_model.weights["1.first.conv.weight_int8"]
    assert first.values.shape == (48, 3, 3, 3) and first.values.dtype == np.uint8
    assert first.zero_point == 128 and first.scale == pytest.approx(0.041535206)
    bias = real_model.weights["1.first.conv.bias_int8"]
    assert bias.values.dtype == np.int32 and bias.values[:3].tolist() == [4191, 4589, -4144]


# Measured with onnxruntime 1.31 on x86-64 (see models/depth/README.md); the bounds leave a
# little room for other onnxruntime builds, whose int8 rounding ties may differ.
TOLERANCE = {
    ("qlinear", "columns"): (0.08, 0.006),
    ("qlinear", "pumpkin"): (0.35, 0.016),
    ("fp32", "columns"): (0.05, 0.008),
    ("fp32", "pumpkin"): (0.30, 0.014),
}


@needs_source
@pytest.mark.parametrize("form", ["qlinear", "fp32"])
def test_onnxruntime_matches_reference_disparity(real_model, form):
    model = build_onnx(real_model, form)
    onnx.checker.check_model(model, full_check=True)
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    from reshader_train.depthconv.preprocess import load_rgb
    from reshader_train.depthconv.verify import disparity_errors

    for photo in ("columns", "pumpkin"):
        x = network_input(load_rgb(SOURCE / f"input/{photo}.jpg"))
        (y,) = sess.run(None, {"image": x})
        e = disparity_errors(photo, y, np.load(SOURCE / f"output/{photo}.npy"))
        max_rel, mean_rel = TOLERANCE[(form, photo)]
        assert e.pearson > 0.999, e
        assert e.max_rel < max_rel and e.mean_rel < mean_rel, e


# --- the QNNPACK emulation used to check the reading of the graph --------------------------


def test_qnnpack_requantize_rounds_ties_up_unlike_onnx():
    from reshader_train.depthconv.qnnpack import requantize

    acc = np.array([5, 7, 4, -3, 1000])
    assert requantize(acc, np.float32(0.5)).tolist() == [3, 4, 2, -1, 500]
    rng = np.random.default_rng(0)
    acc = rng.integers(-(2**20), 2**20, size=10_000)
    scale = np.float32(0.0123)
    diff = requantize(acc, scale) - np.rint(acc * np.float64(scale))
    assert np.abs(diff).max() <= 1 and np.mean(diff != 0) < 0.01


def test_qnnpack_emulation_of_tiny_conv(tmp_path):
    from reshader_train.depthconv.qnnpack import run_int8

    rng = np.random.default_rng(2)
    w_u8 = rng.integers(60, 200, size=(4, 3, 3, 3), dtype=np.uint8)
    bias = rng.integers(-3000, 3000, size=4).astype(np.int32)
    model, q = _tiny_model(tmp_path, w_u8, bias, 3)
    x = rng.random((1, 3, 8, 6), dtype=np.float32)
    y8, yq = run_int8(model, x)
    expected = _expected_int8(x[0].astype(np.float64), w_u8, bias, q)
    assert y8.dtype == np.uint8 and (yq.scale, yq.zero_point) == (pytest.approx(q[4]), q[5])
    assert np.abs((y8.astype(np.int64) - yq.zero_point) * yq.scale - expected).max() <= q[4] * 1.001


@needs_source
def test_convert_command_writes_models_manifests_and_licence(tmp_path):
    import hashlib
    import json

    from reshader_train.cli import main

    source = tmp_path / "src"
    for sub in ("model", "input", "output"):
        (source / sub).mkdir(parents=True)
    for rel in ("model/tiefenrausch.pb", "model/tiefenrausch_init.pb", "LICENSE"):
        (source / rel).symlink_to(SOURCE.resolve() / rel)
    (source / "input/columns.jpg").symlink_to(SOURCE.resolve() / "input/columns.jpg")
    (source / "output/columns.npy").symlink_to(SOURCE.resolve() / "output/columns.npy")
    out = tmp_path / "depth"
    assert main(["convert-depth", "--source", str(source), "--out", str(out)]) == 0
    assert (out / "LICENSE").read_bytes() == (SOURCE / "LICENSE").read_bytes()
    for precision in ("int8", "fp32"):
        manifest = json.loads((out / f"tiefenrausch-{precision}.json").read_text())
        onnx_bytes = (out / manifest["file"]).read_bytes()
        assert manifest["format"] == "reshader-manifest/1"
        assert manifest["name"] == f"tiefenrausch-{precision}" and manifest["task"] == "depth"
        assert manifest["precision"] == precision
        assert manifest["sha256"] == hashlib.sha256(onnx_bytes).hexdigest()
        assert manifest["depth"]["input_size"] == {
            "policy": "longest-side",
            "size": 384,
            "multiple": 32,
        }
        assert manifest["depth"]["output_kind"] == "log-disparity"
        assert manifest["image"]["mean"] is None and manifest["size_multiple"] == 32
        (photo,) = manifest["validation"]["photos"]
        assert photo["photo"] == "columns.jpg" and photo["pearson"] > 0.999
    assert not list(out.glob(".*")), "temporary files left behind"


def test_convert_command_reports_missing_source(tmp_path, capsys):
    from reshader_train.cli import main

    assert main(["convert-depth", "--source", str(tmp_path), "--out", str(tmp_path / "o")]) == 1
    assert "LICENSE" in capsys.readouterr().err
