"""The Tiefenrausch Caffe2 int8 network as plain data: ops with their quantisation parameters.

Caffe2's int8 tensors are uint8 with a per-tensor scale and zero point (real = scale * (q - zp)),
laid out NHWC; convolution kernels are stored as [M, kH, kW, C/group]. This module reads both
NetDefs, checks that every op is one the exporter understands, and hands the exporter the
weights already transposed to ONNX's [M, C/group, kH, kW].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .protobuf import Argument, NetDef, OperatorDef, read_netdef

SUPPORTED_OPS = (
    "NCHW2NHWC",
    "Int8Quantize",
    "Int8Conv",
    "Int8Add",
    "Int8ResizeNearest",
    "Int8Dequantize",
)


class Caffe2ModelError(ValueError):
    """The NetDefs are readable but describe a network the converter cannot express."""


@dataclass
class QTensor:
    """A uint8 (weights) or int32 (bias) constant with its quantisation parameters."""

    values: np.ndarray
    scale: float
    zero_point: int


@dataclass
class Quant:
    scale: float
    zero_point: int


@dataclass
class Op:
    """One int8 op of the predict net, reduced to what the exporter needs."""

    kind: str
    inputs: list[str]
    output: str
    out_q: Quant | None
    kernel: list[int] = field(default_factory=list)
    strides: list[int] = field(default_factory=list)
    pads: list[int] = field(default_factory=list)  # ONNX order: top, left, bottom, right
    dilations: list[int] = field(default_factory=list)
    group: int = 1
    resize_scale: tuple[float, float] = (1.0, 1.0)


@dataclass
class Caffe2Model:
    name: str
    input_name: str
    output_name: str
    ops: list[Op]
    weights: dict[str, QTensor]
    quant: dict[str, Quant]  # every int8 blob produced by the graph

    def op_counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for op in self.ops:
            counts[op.kind] = counts.get(op.kind, 0) + 1
        return counts

    def parameter_count(self) -> int:
        return sum(int(t.values.size) for t in self.weights.values())


def _arg(op: OperatorDef, name: str, where: str) -> Argument:
    if name not in op.arg:
        raise Caffe2ModelError(f"{where}: {op.type} op {op.output} lacks argument '{name}'")
    return op.arg[name]


def _quant(op: OperatorDef, where: str) -> Quant:
    scale = _arg(op, "Y_scale", where).f
    zp = _arg(op, "Y_zero_point", where).i
    if scale is None or zp is None or not scale > 0 or not 0 <= zp <= 255:
        raise Caffe2ModelError(f"{where}: {op.output}: bad Y_scale/Y_zero_point {scale}/{zp}")
    return Quant(float(scale), int(zp))


def _fill(op: OperatorDef, where: str) -> QTensor:
    shape = _arg(op, "shape", where).ints
    values = _arg(op, "values", where)
    q = _quant(op, where)
    if op.type == "Int8GivenTensorFill":
        if values.s is None:
            raise Caffe2ModelError(f"{where}: {op.output[0]}: uint8 values missing")
        arr = np.frombuffer(values.s, dtype=np.uint8)
    elif op.type == "Int8GivenIntTensorFill":
        arr = np.asarray(values.ints, dtype=np.int64)
        if arr.size and (arr.min() < -(2**31) or arr.max() >= 2**31):
            raise Caffe2ModelError(f"{where}: {op.output[0]}: int32 values out of range")
        arr = arr.astype(np.int32)
    else:
        raise Caffe2ModelError(f"{where}: unsupported init op {op.type} for {op.output}")
    if arr.size != int(np.prod(shape)):
        raise Caffe2ModelError(
            f"{where}: {op.output[0]}: {arr.size} values for shape {list(shape)}"
        )
    return QTensor(arr.reshape(shape), q.scale, q.zero_point)


def _conv(op: OperatorDef, where: str, weights: dict[str, QTensor]) -> Op:
    order = _arg(op, "order", where).s
    if order != b"NHWC":
        raise Caffe2ModelError(f"{where}: {op.output[0]}: order {order!r}, expected NHWC")
    kernel = list(_arg(op, "kernels", where).ints)
    pads = list(_arg(op, "pads", where).ints)  # Caffe2: top, left, bottom, right
    group = op.arg["group"].i if "group" in op.arg else 1
    w = weights.get(op.input[1])
    if w is None or len(op.input) != 3 or op.input[2] not in weights:
        raise Caffe2ModelError(f"{where}: {op.output[0]}: weight or bias not in the init net")
    if list(w.values.shape[1:3]) != kernel:
        raise Caffe2ModelError(
            f"{where}: {op.output[0]}: kernel {kernel} vs weight shape {list(w.values.shape)}"
        )
    return Op(
        kind="Conv",
        inputs=list(op.input),
        output=op.output[0],
        out_q=_quant(op, where),
        kernel=kernel,
        strides=list(_arg(op, "strides", where).ints),
        pads=pads,
        dilations=list(op.arg["dilations"].ints) if "dilations" in op.arg else [1, 1],
        group=int(group or 1),
    )


def _convert_op(op: OperatorDef, where: str, weights: dict[str, QTensor]) -> Op | None:
    if op.type not in SUPPORTED_OPS:
        raise Caffe2ModelError(f"{where}: unsupported op type {op.type} (output {op.output})")
    if op.type == "NCHW2NHWC":
        return None  # ONNX stays NCHW throughout; the layout change has no counterpart.
    if op.type == "Int8Conv":
        return _conv(op, where, weights)
    if op.type == "Int8Quantize":
        return Op("Quantize", list(op.input), op.output[0], _quant(op, where))
    if op.type == "Int8Dequantize":
        return Op("Dequantize", list(op.input), op.output[0], None)
    if op.type == "Int8Add":
        return Op("Add", list(op.input), op.output[0], _quant(op, where))
    hs, ws = _arg(op, "height_scale", where).f, _arg(op, "width_scale", where).f
    return Op(
        "ResizeNearest",
        list(op.input),
        op.output[0],
        _quant(op, where),
        resize_scale=(float(hs), float(ws)),
    )


def _resolve_blob_names(ops: list[Op], net: NetDef) -> list[Op]:
    """Route around NCHW2NHWC: the op consuming its output reads the NCHW input directly."""
    alias: dict[str, str] = {}
    for op in net.op:
        if op.type == "NCHW2NHWC":
            alias[op.output[0]] = op.input[0]
    for op in ops:
        op.inputs = [alias.get(n, n) for n in op.inputs]
    return ops


def _propagate_quant(ops: list[Op], weights: dict[str, QTensor], where: str) -> dict[str, Quant]:
    quant: dict[str, Quant] = {}
    for op in ops:
        if op.kind != "Quantize":
            for name in op.inputs:
                if name not in quant and name not in weights:
                    raise Caffe2ModelError(f"{where}: blob {name} used before it is produced")
        if op.out_q is not None:
            quant[op.output] = op.out_q
    return quant


def load_caffe2_model(predict_path: Path, init_path: Path) -> Caffe2Model:
    """Read the predict and init NetDefs into a Caffe2Model, validating what the exporter needs."""
    predict, init = read_netdef(predict_path), read_netdef(init_path)
    weights = {}
    for op in init.op:
        if len(op.output) != 1:
            raise Caffe2ModelError(f"{init_path}: fill op with {len(op.output)} outputs")
        weights[op.output[0]] = _fill(op, str(init_path))
    if not predict.external_input or not predict.external_output:
        raise Caffe2ModelError(f"{predict_path}: external_input/external_output missing")
    where = str(predict_path)
    ops = [o for o in (_convert_op(op, where, weights) for op in predict.op) if o is not None]
    ops = _resolve_blob_names(ops, predict)
    return Caffe2Model(
        name=predict.name,
        input_name=predict.external_input[0],
        output_name=predict.external_output[0],
        ops=ops,
        weights=weights,
        quant=_propagate_quant(ops, weights, where),
    )
