"""Caffe2's int8 arithmetic in numpy, to check the converter's reading of the graph.

Caffe2 runs Int8Conv and Int8Add with QNNPACK, whose requantisation is fixed point: a conv
accumulator is multiplied by a Q31 multiplier (rounded half up) then shifted right (rounded
half away from zero); an add scales both inputs by 22-bit multipliers. ONNX's QLinearConv
rounds acc * scale once, half to even, so the two differ by one level on a few per cent of
values. This module reproduces the fixed-point form; it is slow (tens of seconds per photo)
and is a verification tool, not the runtime.
"""

from __future__ import annotations

import numpy as np

from .caffe2_model import Caffe2Model, Op, Quant


def _f32_bits(x: float) -> int:
    return int(np.array(x, np.float32).view(np.uint32))


def _round_shift(v: np.ndarray, shift: int) -> np.ndarray:
    """v / 2**shift rounded half away from zero, in integers."""
    mask = (1 << shift) - 1
    remainder = (v & mask) - (v < 0)
    return (v >> shift) + (remainder > (mask >> 1))


def requantize(acc: np.ndarray, scale: np.float32) -> np.ndarray:
    """QNNPACK's conv requantisation of int64 accumulators by a float32 scale in (0, 1)."""
    bits = _f32_bits(scale)
    multiplier = ((bits & 0x7FFFFF) | 0x800000) << 7
    shift = 126 - (bits >> 23)
    q31 = (acc * multiplier + (1 << 30)) >> 31
    return _round_shift(q31, shift)


def _conv(model: Caffe2Model, x: np.ndarray, op: Op) -> np.ndarray:
    xq = model.quant[op.inputs[0]]
    w, b = model.weights[op.inputs[1]], model.weights[op.inputs[2]]
    kernel = w.values.astype(np.float64) - w.zero_point  # [M, kH, kW, C/group]
    m, kh, kw, cg = kernel.shape
    s = op.strides[0]
    top, left, bottom, right = op.pads
    xp = np.pad((x - xq.zero_point).astype(np.float64), ((0, 0), (top, bottom), (left, right)))
    ho = (xp.shape[1] - kh) // s + 1
    wo = (xp.shape[2] - kw) // s + 1
    acc = np.zeros((m, ho, wo))
    for dy in range(kh):
        for dx in range(kw):
            patch = xp[:, dy : dy + s * (ho - 1) + 1 : s, dx : dx + s * (wo - 1) + 1 : s]
            if op.group == 1:
                acc += np.tensordot(kernel[:, dy, dx, :], patch, axes=(1, 0))
            elif cg == 1 and op.group == m == x.shape[0]:
                acc += kernel[:, dy, dx, 0, None, None] * patch
            else:
                raise ValueError(f"{op.output}: grouped conv other than depthwise")
    # Products and sums of 8-bit values stay far below 2**53: float64 sums are exact.
    acc = acc.astype(np.int64) + b.values.astype(np.int64)[:, None, None]
    scale = np.float32(np.float32(xq.scale) * np.float32(w.scale)) / np.float32(op.out_q.scale)
    return np.clip(requantize(acc, np.float32(scale)) + op.out_q.zero_point, 0, 255)


def _add(a: np.ndarray, aq: Quant, b: np.ndarray, bq: Quant, yq: Quant) -> np.ndarray:
    a_scale = np.float32(aq.scale) / np.float32(yq.scale)
    b_scale = np.float32(bq.scale) / np.float32(yq.scale)
    exponent = (_f32_bits(max(a_scale, b_scale)) >> 23) - 127
    shift = 21 - exponent
    a_mul = int(np.rint(a_scale * np.float32(2.0**shift)))
    b_mul = int(np.rint(b_scale * np.float32(2.0**shift)))
    acc = a_mul * (a - aq.zero_point) + b_mul * (b - bq.zero_point)
    return np.clip(_round_shift(acc, shift) + yq.zero_point, 0, 255)


def run_int8(model: Caffe2Model, image: np.ndarray) -> tuple[np.ndarray, Quant]:
    """Run the graph on a 1x3xHxW float32 image; returns the uint8 output and its Quant."""
    blobs: dict[str, np.ndarray] = {}
    for op in model.ops:
        if op.kind == "Quantize":
            q = op.out_q
            v = np.rint(image[0].astype(np.float32) / np.float32(q.scale)) + q.zero_point
            blobs[op.output] = np.clip(v, 0, 255).astype(np.int64)
        elif op.kind == "Conv":
            blobs[op.output] = _conv(model, blobs[op.inputs[0]], op)
        elif op.kind == "Add":
            a, b = op.inputs
            blobs[op.output] = _add(blobs[a], model.quant[a], blobs[b], model.quant[b], op.out_q)
        elif op.kind == "ResizeNearest":
            fy, fx = (int(v) for v in op.resize_scale)
            if (fy, fx) != op.resize_scale:
                raise ValueError(f"{op.output}: non-integer resize scale {op.resize_scale}")
            blobs[op.output] = blobs[op.inputs[0]].repeat(fy, axis=1).repeat(fx, axis=2)
        elif op.kind == "Dequantize":
            return blobs[op.inputs[0]].astype(np.uint8), model.quant[op.inputs[0]]
    raise ValueError("graph has no Int8Dequantize")
