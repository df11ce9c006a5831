"""Express a Caffe2Model as ONNX, in one of three forms.

- "qlinear": int8 end to end where ONNX has an int8 op. QuantizeLinear on the input,
  QLinearConv for every Int8Conv (uint8 activations and weights with their zero points, int32
  bias at scale x_scale * w_scale, exactly as stored), and DequantizeLinear -> float op ->
  QuantizeLinear around Int8Add and Int8ResizeNearest, for which standard ONNX has no int8 op.
- "qdq": the same quantisation written as QuantizeLinear/DequantizeLinear pairs around float
  Conv/Add/Resize, with uint8 weights and int32 biases kept as initialisers behind
  DequantizeLinear.
- "fp32": weights dequantised to float and activations not rounded, but every activation is
  still clamped to the real range its uint8 blob can hold, [-zp * s, (255 - zp) * s]. Caffe2's
  Int8Conv clamps its output to [0, 255], so an output zero point of 0 is a fused ReLU, and the
  network was trained with these ranges: without the clamps the float network diverges
  (measured: correlation 0.13 with the reference on columns.jpg).

Both int8 forms reproduce Caffe2's requantisation up to rounding ties: Caffe2 (QNNPACK)
rounds its fixed-point requantisation half away from zero, ONNX rounds half to even.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from .caffe2_model import Caffe2Model, Caffe2ModelError, Op, Quant

FORMS = ("qlinear", "qdq", "fp32")
INPUT_NAME = "image"
OUTPUT_NAME = "log_disparity"
OPSET = 13
IR_VERSION = 7


class _Builder:
    def __init__(self, model: Caffe2Model, form: str):
        self.m = model
        self.form = form
        self.nodes: list[onnx.NodeProto] = []
        self.inits: list[onnx.TensorProto] = []
        self._consts: set[str] = set()
        self._dequantized: set[str] = set()

    def node(self, op_type: str, inputs: list[str], output: str, **attrs) -> str:
        self.nodes.append(helper.make_node(op_type, inputs, [output], name=output, **attrs))
        return output

    def const(self, name: str, value: np.ndarray) -> str:
        if name not in self._consts:
            self._consts.add(name)
            self.inits.append(numpy_helper.from_array(value, name))
        return name

    def qparams(self, blob: str, q: Quant) -> tuple[str, str]:
        s = self.const(f"{blob}.scale", np.array(q.scale, dtype=np.float32))
        z = self.const(f"{blob}.zero_point", np.array(q.zero_point, dtype=np.uint8))
        return s, z

    def quantize(self, x: str, blob: str) -> str:
        return self.node("QuantizeLinear", [x, *self.qparams(blob, self.m.quant[blob])], blob)

    def dequantize(self, blob: str) -> str:
        """One DequantizeLinear per blob, shared by all its float consumers."""
        name = f"{blob}.dq"
        if name not in self._dequantized:
            self._dequantized.add(name)
            self.node("DequantizeLinear", [blob, *self.qparams(blob, self.m.quant[blob])], name)
        return name

    def act(self, blob: str) -> str:
        """The float value of an activation blob, as the form carries it."""
        return blob if self.form == "fp32" else self.dequantize(blob)

    def finish(self, blob_float: str, blob: str) -> None:
        """Give an op's float result the blob's name: quantised in the int8 forms, clamped to
        the blob's quantisation range (without rounding) in fp32."""
        if self.form != "fp32":
            self.quantize(blob_float, blob)
            return
        q = self.m.quant[blob]
        lo = self.const(f"{blob}.min", np.array(-q.zero_point * q.scale, np.float32))
        hi = self.const(f"{blob}.max", np.array((255 - q.zero_point) * q.scale, np.float32))
        self.node("Clip", [blob_float, lo, hi], blob)


def _conv_attrs(op: Op) -> dict:
    return {
        "kernel_shape": op.kernel,
        "strides": op.strides,
        "pads": op.pads,
        "dilations": op.dilations,
        "group": op.group,
    }


def _nchw_weight(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values.transpose(0, 3, 1, 2))


def _conv(b: _Builder, op: Op) -> None:
    x, wname, bname = op.inputs
    w, bias = b.m.weights[wname], b.m.weights[bname]
    wq = _nchw_weight(w.values)
    if b.form == "qlinear":
        xs, xz = b.qparams(x, b.m.quant[x])
        ys, yz = b.qparams(op.output, op.out_q)
        ins = [x, xs, xz, b.const(wname, wq)]
        ins += [b.const(f"{wname}.scale", np.array(w.scale, np.float32))]
        ins += [b.const(f"{wname}.zero_point", np.array(w.zero_point, np.uint8))]
        ins += [ys, yz, b.const(bname, bias.values)]
        b.node("QLinearConv", ins, op.output, **_conv_attrs(op))
        return
    if b.form == "qdq":
        wf = b.node(
            "DequantizeLinear",
            [
                b.const(wname, wq),
                b.const(f"{wname}.scale", np.array(w.scale, np.float32)),
                b.const(f"{wname}.zero_point", np.array(w.zero_point, np.uint8)),
            ],
            f"{wname}.dq",
        )
        bscale = np.float32(b.m.quant[x].scale) * np.float32(w.scale)
        bf = b.node(
            "DequantizeLinear",
            [b.const(bname, bias.values), b.const(f"{bname}.scale", np.array(bscale))],
            f"{bname}.dq",
        )
        y = b.node("Conv", [b.act(x), wf, bf], f"{op.output}.f", **_conv_attrs(op))
    else:
        wf = (wq.astype(np.float32) - w.zero_point) * np.float32(w.scale)
        bf = bias.values.astype(np.float64) * bias.scale
        ins = [x, b.const(wname, wf), b.const(bname, bf.astype(np.float32))]
        y = b.node("Conv", ins, f"{op.output}.f", **_conv_attrs(op))
    b.finish(y, op.output)


def _resize(b: _Builder, op: Op) -> None:
    hs, ws = op.resize_scale
    roi = b.const("resize.roi", np.zeros(0, np.float32))
    scales = b.const(f"resize.scales.{hs}x{ws}", np.array([1, 1, hs, ws], np.float32))
    y = b.node(
        "Resize",
        [b.act(op.inputs[0]), roi, scales],
        f"{op.output}.f",
        mode="nearest",
        coordinate_transformation_mode="asymmetric",
        nearest_mode="floor",
    )
    b.finish(y, op.output)


def _add(b: _Builder, op: Op) -> None:
    y = b.node("Add", [b.act(op.inputs[0]), b.act(op.inputs[1])], f"{op.output}.f")
    b.finish(y, op.output)


def _emit(b: _Builder, op: Op) -> None:
    if op.kind == "Quantize":
        b.finish(INPUT_NAME, op.output)
    elif op.kind == "Dequantize":
        b.node("Identity", [b.act(op.inputs[0])], OUTPUT_NAME)
    elif op.kind == "Conv":
        _conv(b, op)
    elif op.kind == "Add":
        _add(b, op)
    elif op.kind == "ResizeNearest":
        _resize(b, op)
    else:
        raise Caffe2ModelError(f"no ONNX mapping for op kind {op.kind}")


def _output_channels(model: Caffe2Model) -> int | str:
    producer = {op.output: op for op in model.ops}.get(model.ops[-1].inputs[0])
    if producer is not None and producer.kind == "Conv":
        return int(model.weights[producer.inputs[1]].values.shape[0])
    return "channels"


def build_onnx(model: Caffe2Model, form: str) -> onnx.ModelProto:
    """Build and check the ONNX model; the input is NCHW float32 RGB in [0, 1]."""
    if form not in FORMS:
        raise ValueError(f"unknown form {form!r}; expected one of {FORMS}")
    ops = model.ops
    if not ops or ops[0].kind != "Quantize" or ops[-1].kind != "Dequantize":
        raise Caffe2ModelError("expected the graph to start with Int8Quantize, end with Dequantize")
    if ops[-1].output != model.output_name:
        raise Caffe2ModelError(f"last op writes {ops[-1].output}, not {model.output_name}")
    b = _Builder(model, form)
    for op in ops:
        _emit(b, op)
    graph = helper.make_graph(
        b.nodes,
        f"tiefenrausch_{form}",
        [helper.make_tensor_value_info(INPUT_NAME, TensorProto.FLOAT, [1, 3, "height", "width"])],
        [
            helper.make_tensor_value_info(
                OUTPUT_NAME, TensorProto.FLOAT, [1, _output_channels(model), "height", "width"]
            )
        ],
        b.inits,
    )
    onnx_model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="reshader-train convert-depth",
    )
    onnx_model.ir_version = IR_VERSION
    onnx.checker.check_model(onnx_model, full_check=True)
    return onnx_model
