"""`reshader-train export`: ONNX models and their manifests (models/MANIFEST.md schema).

For one checkpoint and precision this writes `reshade-<size>-<precision>.onnx` (image,
disparity, camera -> reshaded) and, with --split, the pair `...-encoder.onnx` (image,
disparity -> bottleneck, skip0..skip4) and `...-decoder.onnx` (image, bottleneck, skips,
camera -> reshaded), each beside a JSON manifest. Every graph is checked with onnx.checker
and run by onnxruntime against PyTorch before it is written; the measured difference and
the tolerance go into the manifest's "validation".

A checkpoint of the lobe head (model.LobeField) takes no camera: it is written as one graph
per precision, `reshade-<size>-<precision>-lobes.onnx` (image, disparity, rays -> lobes),
which the runtime runs once per photo before evaluating the closed form of
model.shade_lobes per view; --split does not apply to it.

Precisions:
- fp32: opset 17, H and W dynamic (the runtime pins them at load), constants folded.
- fp16: weights and activations in half precision; inputs and outputs stay float32 (Casts at
  the graph boundary).
- int8: QDQ on the convolutions only (see quantize.py): from a `quantize` (QAT) checkpoint,
  or post-training quantisation of a float checkpoint calibrated on --calibration crops.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import io
import json
import os
import shlex
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .model import (
    ALIGN,
    DISPARITY_DEPTH,
    DISPARITY_FREQUENCIES,
    LOBE_LAYOUT,
    SIZES,
    SLIDE_LAYOUT,
    CameraMLP,
    DecoderGraph,
    EncoderGraph,
    LobeGraph,
    NetConfig,
    ReshadeNet,
    conv_flops,
    count_parameters,
    shade_lobes,
)
from .quantize import (
    INT8_FORMS,
    SCHEME,
    WEIGHT_LEVELS,
    QuantConv2d,
    calibrate,
    command_line,
    is_quantized,
    load_any_checkpoint,
    quantize_network,
    set_input_quantization,
    training_crops,
)

OPSET = 17
FORMAT = "reshader-manifest/1"
PRECISIONS = ("fp32", "fp16", "int8")
FLOPS_SIZE = (384, 640)
LICENCE = "MIT OR Apache-2.0"
# |onnxruntime - PyTorch| accepted on the parity input, per precision (largest and mean). fp32
# differs only by summation order; fp16 is compared with the float32 network (half-precision
# storage and arithmetic); int8 with the same fake-quantised network in PyTorch, where a value
# on a rounding boundary may land one quantisation step away (measured on the lite network at
# 384x640: largest 1.2e-2, mean 1.7e-3).
TOLERANCE = {"fp32": 1e-4, "fp16": 2e-2, "int8": 5e-2}
MEAN_TOLERANCE = {"fp32": 1e-5, "fp16": 2e-3, "int8": 5e-3}

IMAGE = {"color": "srgb", "range": [0, 1], "channel_order": "rgb", "mean": None, "std": None}
DISPARITY_ENCODING = {
    "formula": "clamp(0.25/depth, 0, 1)",
    "frequencies": DISPARITY_FREQUENCIES,
    "pi": False,
    "in_graph": True,
}
CAMERA = {
    "convention": "opencv",
    "meaning": "novel camera centre in the input camera frame, scene units",
    "training_offset_range": [0.1, 0.3],
}


class ExportError(RuntimeError):
    pass


# --- tensor descriptions -------------------------------------------------------------------


def _dims(level: int) -> tuple[str, str]:
    return ("H", "W") if level == 0 else (f"H/{2**level}", f"W/{2**level}")


def tensor_specs(cfg: NetConfig) -> dict[str, dict]:
    """Manifest entries of every tensor a reshade graph may take or give."""
    specs = {
        "image": {
            "layout": "NCHW",
            "shape": [1, 3, "H", "W"],
            "range": [0, 1],
            "description": "input photo, sRGB-encoded RGB in [0,1], padded to multiples of 32",
        },
        "disparity": {
            "layout": "NCHW",
            "shape": [1, 1, "H", "W"],
            "range": [0, 1],
            "description": "d = clamp(0.25/depth, 0, 1); frequency-encoded inside the graph",
        },
        "camera": {
            "layout": "NC",
            "shape": [1, 3],
            "range": None,
            "description": "novel camera centre (tx, ty, tz) in the input camera's OpenCV frame",
        },
        "reshaded": {
            "layout": "NCHW",
            "shape": [1, 3, "H", "W"],
            "range": None,
            "description": "input + tanh(residual): crop the padding and clamp to [0,1]",
        },
        "rays": {
            "layout": "NCHW",
            "shape": [1, 3, "H", "W"],
            "range": None,
            "description": "K^-1 [u, v, 1] = ((u - cx)/fx, (v - cy)/fy, 1) per pixel (u, v) of "
            "this input, intrinsics at its resolution, pixel centres at integer coordinates "
            "(OpenCV: x right, y down, z forward); padding replicates the last row and column",
        },
        "lobes": {
            "layout": "NCHW",
            "shape": [1, cfg.out_channels, "H", "W"],
            "range": None,
            "description": f"{cfg.lobes} lobes per pixel, lobe j in channels 7j..7j+6 = "
            f"{', '.join(LOBE_LAYOUT)}: unit axis in the input camera frame, sharpness > 0, "
            "signed RGB amplitude (display encoding)"
            + (
                f"; then {', '.join(SLIDE_LAYOUT)}: the share of the photo per colour that "
                "slides as a reflection, and how far behind the surface its image lies"
                if cfg.head == "lobes-slide"
                else ""
            )
            + "; see the manifest's shading",
        },
    }
    last = len(cfg.widths) - 1
    specs["bottleneck"] = {
        "layout": "NCHW",
        "shape": [1, cfg.widths[last], *_dims(last)],
        "range": None,
        "description": "encoder features at H/32 (view independent)",
    }
    for i in range(last):
        specs[f"skip{i}"] = {
            "layout": "NCHW",
            "shape": [1, cfg.widths[i], *_dims(i)],
            "range": None,
            "description": f"encoder skip features at {'full' if i == 0 else f'1/{2**i}'} "
            "resolution (view independent)",
        }
    return {k: {"name": k, "dtype": "float32", **v} for k, v in specs.items()}


@dataclass(frozen=True)
class GraphKind:
    suffix: str  # "" | "-encoder" | "-decoder"
    task: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]


SINGLE = GraphKind("", "reshade", ("image", "disparity", "camera"), ("reshaded",))
ENCODER = GraphKind(
    "-encoder", "reshade-encoder", EncoderGraph.input_names, EncoderGraph.output_names
)
DECODER = GraphKind(
    "-decoder", "reshade-decoder", DecoderGraph.input_names, DecoderGraph.output_names
)
LOBES = GraphKind("-lobes", "reshade-lobes", LobeGraph.input_names, LobeGraph.output_names)
# The lobe heads the runtime evaluates (src/reshade/net/lobes.rs); lobes-flow is not one.
EXPORTED_LOBE_HEADS = ("lobes", "lobes-slide")


def graph_kinds(cfg: NetConfig, split: bool) -> tuple[GraphKind, ...]:
    """The graphs one precision is written as: the lobe head has one, the others the single
    graph and, with `split`, the encoder/decoder pair."""
    if cfg.head in EXPORTED_LOBE_HEADS:
        return (LOBES,)
    return (SINGLE, ENCODER, DECODER) if split else (SINGLE,)


def graph_module(net: ReshadeNet, kind: GraphKind) -> nn.Module:
    if kind is ENCODER:
        return EncoderGraph(net)
    if kind is DECODER:
        return DecoderGraph(net)
    if kind is LOBES:
        return LobeGraph(net)
    return net


def dynamic_axes(cfg: NetConfig, names: tuple[str, ...]) -> dict[str, dict[int, str]]:
    specs = tensor_specs(cfg)
    return {
        n: {2: specs[n]["shape"][2], 3: specs[n]["shape"][3]}
        for n in names
        if specs[n]["layout"] == "NCHW"
    }


# --- inputs used for tracing and parity -----------------------------------------------------


# The parity input's camera: a 60 degree horizontal field of view, square pixels, the
# principal point at the image centre (as the runtime assumes for a photo).
PARITY_HFOV_DEG = 60.0


def parity_intrinsics(height: int, width: int) -> dict[str, float]:
    """fx, fy, cx, cy (pixel centres at integer coordinates) of the parity input."""
    fx = 0.5 * width / float(np.tan(np.radians(PARITY_HFOV_DEG / 2)))
    return {"fx": fx, "fy": fx, "cx": (width - 1) / 2, "cy": (height - 1) / 2}


def pixel_rays(intrinsics: dict[str, float], height: int, width: int) -> torch.Tensor:
    """(1, 3, H, W) K^-1 [u, v, 1] for pixel centres at integer coordinates."""
    u = (torch.arange(width, dtype=torch.float32) - intrinsics["cx"]) / intrinsics["fx"]
    v = (torch.arange(height, dtype=torch.float32) - intrinsics["cy"]) / intrinsics["fy"]
    rays = torch.ones(3, height, width)
    rays[0] = u[None, :]
    rays[1] = v[:, None]
    return rays[None]


def parity_inputs(height: int, width: int) -> dict[str, torch.Tensor]:
    """A closed-form photo-like input (documented in the README so the runtime can rebuild it):
    image[c,y,x] = 0.1 + 0.1 c + 0.2 x/W + 0.5 exp(-((x - 0.4 W)^2 + (y - 0.45 H)^2) / (2 s^2)),
    s = 0.15 min(H, W); depth[y,x] = 1.5 + x/W + y/H, disparity = 0.25 / depth; rays of
    parity_intrinsics (for the lobe head)."""
    y = torch.arange(height, dtype=torch.float32)[:, None]
    x = torch.arange(width, dtype=torch.float32)[None, :]
    s = 0.15 * min(height, width)
    blob = 0.5 * torch.exp(-((x - 0.4 * width) ** 2 + (y - 0.45 * height) ** 2) / (2 * s * s))
    image = torch.stack([0.1 + 0.1 * c + 0.2 * x / width + blob for c in range(3)])
    depth = 1.5 + x / width + y / height
    return {
        "image": image[None],
        "disparity": (0.25 / depth)[None, None],
        "rays": pixel_rays(parity_intrinsics(height, width), height, width),
    }


def graph_inputs(net: ReshadeNet, kind: GraphKind, feed: dict) -> dict[str, torch.Tensor]:
    """The named inputs of `kind`, computing encoder outputs with `net` for the decoder."""
    if kind is not DECODER:
        return {n: feed[n] for n in kind.inputs}
    with torch.no_grad():
        outs = EncoderGraph(net)(feed["image"], feed["disparity"])
    return {
        **dict(zip(EncoderGraph.output_names, outs, strict=True)),
        "image": feed["image"],
        "camera": feed["camera"],
    }


# --- precision transforms -------------------------------------------------------------------


class FloatIsland(nn.Module):
    """Keeps `inner` in float32 inside a float16 graph (tract 0.23.9 cannot type a float16
    Gemm); the camera MLP is a few thousand multiply-adds, so this costs nothing."""

    def __init__(self, inner: nn.Module) -> None:
        super().__init__()
        self.inner = inner.float()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.inner(x.float()).half()


class HalfBoundary(nn.Module):
    """Runs `inner` in float16 with float32 inputs and outputs (camera MLP in float32)."""

    def __init__(self, inner: nn.Module) -> None:
        super().__init__()
        self.inner = copy.deepcopy(inner).half()
        for module in list(self.inner.modules()):
            for name, child in module.named_children():
                if isinstance(child, CameraMLP):
                    setattr(module, name, FloatIsland(child))

    def forward(self, *xs: torch.Tensor):
        out = self.inner(*(x.half() for x in xs))
        if isinstance(out, tuple):
            return tuple(o.float() for o in out)
        return out.float()


class HalfLobes(nn.Module):
    """The lobe graph with the convolutions in float16 and the lobe field (axes, sharpness up
    to 2e4, amplitudes: a few operations per pixel) in float32, fed the float32 rays: the
    sharpness is an exponential of the network's output and the axes are normalised, which
    float16 would round visibly after the closed form's exp(sharpness (mu . w - 1))."""

    def __init__(self, net: ReshadeNet) -> None:
        super().__init__()
        self.encoder = copy.deepcopy(net.encoder).half()
        self.decoder = copy.deepcopy(net.decoder).half()
        self.lobe_field = copy.deepcopy(net.lobe_field).float()

    def forward(self, image: torch.Tensor, disparity: torch.Tensor, rays: torch.Tensor):
        bottleneck, skips = self.encoder(image.half(), disparity.half())
        raw = self.decoder.features(skips, bottleneck, None).float()
        return self.lobe_field(raw, rays, image)


def half_module(net: ReshadeNet, kind: GraphKind) -> nn.Module:
    if kind is LOBES:
        return HalfLobes(net)
    return HalfBoundary(graph_module(net, kind))


def dequantized_float_net(qnet: ReshadeNet) -> tuple[ReshadeNet, dict[str, dict]]:
    """The float network with the quantised convolutions unwrapped, and per conv weight name
    its QDQ parameters (input scale/zero point, int8 weight, weight scales)."""
    net = copy.deepcopy(qnet)
    params: dict[str, dict] = {}
    for module in list(net.modules()):
        for name, child in module.named_children():
            if isinstance(child, QuantConv2d):
                setattr(module, name, child.conv)
                params[id(child.conv)] = _conv_qparams(child)
    named = {
        f"{mod_name}.weight": params[id(m)]
        for mod_name, m in net.named_modules()
        if id(m) in params
    }
    return net, named


def _conv_qparams(q: QuantConv2d) -> dict:
    with torch.no_grad():
        in_scale, in_zero = q.act.qparams()
        w_scale, _ = q.weight_qparams()
        w = q.conv.weight
        w_int = torch.clamp(
            torch.round(w / w_scale[:, None, None, None]), -WEIGHT_LEVELS, WEIGHT_LEVELS
        )
    return {
        "in_scale": float(in_scale),
        "in_zero": int(in_zero),
        "w_scale": w_scale.numpy().astype(np.float32),
        "w_int": w_int.numpy().astype(np.int8),
    }


# Convolutions with fixed kernels (the x2 upsampling's blur, the flow head's image gradient)
# are not parameters of the network and stay float.
FIXED_CONV_SCOPES = ("/upsample.", "/gradient/")


def is_fixed_conv(node) -> bool:
    return any(scope in node.name for scope in FIXED_CONV_SCOPES)


def insert_conv_qdq(model, qparams: dict[str, dict], activations: bool = True) -> None:
    """Rewrites every Conv whose weight is in `qparams`: an int8 weight initialiser with a
    per-channel DequantizeLinear and, with `activations`, QuantizeLinear -> DequantizeLinear on
    its input (uint8, per tensor). Nothing else is touched, so the float ops stay float."""
    from onnx import TensorProto, helper, numpy_helper

    g = model.graph
    inits = {i.name: i for i in g.initializer}
    new_nodes = []
    done = set()
    for node in g.node:
        if node.op_type == "Conv" and node.input[1] in qparams:
            w_name = node.input[1]
            p = qparams[w_name]
            if w_name not in inits:
                raise ExportError(f"conv weight {w_name} is not an initialiser")
            if w_name not in done:
                g.initializer.remove(inits[w_name])
                g.initializer.extend(
                    [
                        numpy_helper.from_array(p["w_int"], f"{w_name}_int8"),
                        numpy_helper.from_array(p["w_scale"], f"{w_name}_scale"),
                        numpy_helper.from_array(
                            np.zeros_like(p["w_scale"], dtype=np.int8), f"{w_name}_zero"
                        ),
                    ]
                )
                new_nodes.append(
                    helper.make_node(
                        "DequantizeLinear",
                        [f"{w_name}_int8", f"{w_name}_scale", f"{w_name}_zero"],
                        [w_name],
                        name=f"{w_name}_dequantize",
                        axis=0,
                    )
                )
                done.add(w_name)
            if not activations:
                new_nodes.append(node)
                continue
            x = node.input[0]
            stem = f"{w_name.removesuffix('.weight')}.input"
            g.initializer.extend(
                [
                    helper.make_tensor(f"{stem}_scale", TensorProto.FLOAT, [], [p["in_scale"]]),
                    helper.make_tensor(f"{stem}_zero", TensorProto.UINT8, [], [p["in_zero"]]),
                ]
            )
            new_nodes += [
                helper.make_node(
                    "QuantizeLinear",
                    [x, f"{stem}_scale", f"{stem}_zero"],
                    [f"{stem}_q"],
                    name=f"{stem}_quantize",
                ),
                helper.make_node(
                    "DequantizeLinear",
                    [f"{stem}_q", f"{stem}_scale", f"{stem}_zero"],
                    [f"{stem}_dq"],
                    name=f"{stem}_dequantize",
                ),
            ]
            node.input[0] = f"{stem}_dq"
        new_nodes.append(node)
    plain = [
        n.input[1]
        for n in g.node
        if n.op_type == "Conv" and n.input[1] not in done and not is_fixed_conv(n)
    ]
    if plain:
        raise ExportError(f"convolutions without quantisation parameters: {plain}")
    del g.node[:]
    g.node.extend(new_nodes)


def remove_identities(model) -> None:
    """The exporter turns shared constants into Identity nodes; point consumers at the source."""
    g = model.graph
    outputs = {o.name for o in g.output}
    alias = {
        n.output[0]: n.input[0]
        for n in g.node
        if n.op_type == "Identity" and n.output[0] not in outputs
    }
    keep = [n for n in g.node if not (n.op_type == "Identity" and n.output[0] in alias)]
    for n in keep:
        for i, name in enumerate(n.input):
            while name in alias:
                name = alias[name]
            n.input[i] = name
    del g.node[:]
    g.node.extend(keep)


# --- export and check -----------------------------------------------------------------------


def to_onnx(module: nn.Module, cfg: NetConfig, kind: GraphKind, feed: dict):
    import onnx

    buf = io.BytesIO()
    args = tuple(feed[n] for n in kind.inputs)
    with warnings.catch_warnings():
        # The size check in Encoder.forward is a Python branch: fine to trace as constant.
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        torch.onnx.export(
            module,
            args,
            buf,
            dynamo=False,
            opset_version=OPSET,
            do_constant_folding=True,
            input_names=list(kind.inputs),
            output_names=list(kind.outputs),
            dynamic_axes=dynamic_axes(cfg, kind.inputs + kind.outputs),
        )
    model = onnx.load_from_string(buf.getvalue())
    remove_identities(model)
    if kind is LOBES:
        # The exporter leaves the concatenated channel axis symbolic; the manifest and the
        # runtime know it is 7K.
        (out,) = model.graph.output
        out.type.tensor_type.shape.dim[1].dim_value = cfg.out_channels
    return model


def run_onnxruntime(model_bytes: bytes, feed: dict[str, torch.Tensor]) -> list[np.ndarray]:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(model_bytes, opts, providers=["CPUExecutionProvider"])
    names = [i.name for i in sess.get_inputs()]
    return sess.run(None, {n: feed[n].numpy() for n in names})


def check_parity(
    model_bytes: bytes, reference: nn.Module, kind: GraphKind, feed: dict, precision: str
) -> dict:
    with torch.no_grad():
        ref = reference(*(feed[n] for n in kind.inputs))
    ref = ref if isinstance(ref, tuple) else (ref,)
    got = run_onnxruntime(model_bytes, feed)
    worst, mean = 0.0, 0.0
    for name, r, o in zip(kind.outputs, ref, got, strict=True):
        if tuple(r.shape) != o.shape:
            raise ExportError(
                f"{name}: onnxruntime gives shape {o.shape}, PyTorch {tuple(r.shape)}"
            )
        r = r.numpy()
        if kind is LOBES:
            cfg = reference.net.cfg
            log_amp = cfg.domain == "linear-clamped"
            r, o = (comparable_lobes(x, cfg.lobes, log_amp) for x in (r, o))
        diff = np.abs(r - o)
        worst = max(worst, float(diff.max()))
        mean = max(mean, float(diff.mean()))
    tol, mean_tol = TOLERANCE[precision], MEAN_TOLERANCE[precision]
    if not (worst <= tol and mean <= mean_tol):
        raise ExportError(
            f"{precision} {kind.task}: onnxruntime differs from PyTorch by {worst:.3g} at most "
            f"and {mean:.3g} on average (tolerances {tol:g}, {mean_tol:g})"
        )
    out = {"max_abs": worst, "mean_abs": mean, "tolerance": tol, "mean_tolerance": mean_tol}
    if kind is LOBES:
        out["compared"] = (
            "lobes, sharpness and amplitudes (from 1e-6) as their logs (axes absolute; "
            "sharpness and amplitudes relative)"
            if reference.net.cfg.domain == "linear-clamped"
            else "lobes, sharpness as its log (axes, amplitudes absolute; sharpness relative)"
        )
        out["shaded"] = shaded_parity(feed, ref[0], torch.from_numpy(got[0]), reference)
    return out


# Cameras at which an exported lobe graph's shading is compared with PyTorch's: one inside
# the trained offsets and one beyond them (the closed form defines every camera).
LOBE_PARITY_CAMERAS = ((0.12, -0.05, 0.2), (0.5, 0.0, 0.0))


# Amplitudes of the linear-clamped domain are compared in log from here up: a fainter lobe
# changes nothing past any dead zone.
FAINTEST_COMPARED = 1e-6


def comparable_lobes(fields: np.ndarray, lobes: int, log_amplitude: bool = False) -> np.ndarray:
    """The fields with each of the `lobes` sharpnesses replaced by its logarithm, so that
    one absolute tolerance bounds the axes, amplitudes and the sliding layer's fraction and
    depth absolutely and the sharpness (1..2e4) relatively. `log_amplitude` (the
    linear-clamped domain, whose amplitudes span ten orders): the amplitudes too."""
    out = np.array(fields, dtype=np.float64, copy=True)
    n = len(LOBE_LAYOUT)
    sharp = slice(3, n * lobes, n)
    out[:, sharp] = np.log(np.maximum(out[:, sharp], 1e-30))
    if log_amplitude:
        for j in range(lobes):
            amp = out[:, n * j + 4 : n * j + 7]
            out[:, n * j + 4 : n * j + 7] = np.log(np.maximum(amp, FAINTEST_COMPARED))
    return out


def shaded_parity(feed: dict, ref: torch.Tensor, got: torch.Tensor, reference: nn.Module) -> dict:
    """The largest difference (display units, clamped to [0,1]) between the closed form on
    PyTorch's lobes and on onnxruntime's, per camera of LOBE_PARITY_CAMERAS."""
    cfg = reference.net.cfg
    result = {}
    for cam in LOBE_PARITY_CAMERAS:
        c = torch.tensor([cam])
        a, b = (
            shade_lobes(
                feed["image"],
                lobes,
                feed["disparity"],
                feed["rays"],
                c,
                cfg.deadzone,
                domain=cfg.domain,
                head=cfg.head,
            )
            .clamp(0.0, 1.0)
            .numpy()
            for lobes in (ref, got)
        )
        result[str(list(cam))] = float(np.abs(a - b).max())
    return result


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


@dataclass
class ExportInfo:
    """What the manifest says about where a model came from."""

    size: str
    version: str = "0.1.0"
    training: dict | None = None
    validation: dict | None = None
    source: str = ""
    licence: str = LICENCE


def architecture(cfg: NetConfig, size: str, kind: GraphKind) -> dict:
    net = ReshadeNet(cfg).eval()
    flops = conv_flops(net, *FLOPS_SIZE)
    part = {"": "all", "-encoder": "encoder", "-decoder": "decoder", "-lobes": "all"}[kind.suffix]
    module = {"all": net, "encoder": net.encoder, "decoder": net.decoder}[part]
    gflops = (flops["encoder"] + flops["decoder"] if part == "all" else flops[part]) / 1e9
    arch = {
        "size": size,
        "widths": list(cfg.widths),
        "convs": list(cfg.convs),
        "head": cfg.head,
        "out_channels": cfg.out_channels,
        "deadzone": cfg.deadzone,
        "film": cfg.film,
        "parameters": count_parameters(module),
        "gflops_at_384x640": round(gflops, 4),
    }
    if cfg.head in EXPORTED_LOBE_HEADS:
        arch["lobes"] = cfg.lobes
        # Where the graph's amplitudes come from (the runtime reads them as they are).
        arch["amplitude"] = cfg.amplitude
    return arch


# What the runtime evaluates per view from a lobe graph's output (model.shade_lobes).
LOBE_SHADING = (
    "per view with camera centre c (input camera frame, the camera block's units) and pixel "
    "ray r, disparity d: w = normalize(4 d c - r), w0 = normalize(-r); change = sum_j a_j "
    "(exp(lambda_j (mu_j . w - 1)) - exp(lambda_j (mu_j . w0 - 1))); change' = soft threshold "
    "by deadzone (0 where |change| <= deadzone, else change -+ deadzone, per channel); "
    "reshaded = clamp(image + change', 0, 1); c = 0 gives the image exactly"
)
# The linear-clamped domain's closed form (model.shade_lobes), in place of LOBE_SHADING's
# last two steps.
CLAMPED_SHADING = (
    "domain linear-clamped, per colour: L = max(image, 0)^2.2, S = sum_j a_j exp(lambda_j "
    "(mu_j . w - 1)), S0 the same at w0; clipped = image >= 1 - 0.5/255; k = 1 where clipped, "
    "else min(1, L / max(S0, 1e-12)); dug = max(S0 - L, 0) where clipped, else 0; change = "
    "soft threshold by deadzone of min(L + k (S - S0) + dug, 1) - L; reshaded = image where "
    "change = 0, else max(L + change, 1e-4)^(1/2.2)"
)
# The domains the runtime evaluates.
EXPORTED_DOMAINS = ("display", "linear-clamped")
# What lobes-slide adds to the change before the threshold (model.slide_change).
SLIDE_SHADING = (
    "lobes-slide adds to change, before the threshold: S = image * fraction (per colour), "
    "q = d / disparity_depth; with p(z) = (r - z c)_xy / max((r - z c)_z, 0.05), the shift "
    "s = p(q (1 - rho)) - p(q) in normalised coordinates, times (fx, fy) in pixels; "
    "+ S sampled bilinearly at (x - s_x fx, y - s_y fy), coordinates clamped to the image "
    "(pixel centres at integers), - S at the pixel"
)


def lobe_fields(cfg: NetConfig) -> dict:
    """The manifest fields of a lobe graph beyond the common ones (models/MANIFEST.md)."""
    channels = [f"{name}{j}" for j in range(cfg.lobes) for name in LOBE_LAYOUT]
    shading = LOBE_SHADING
    if cfg.head == "lobes-slide":
        channels += list(SLIDE_LAYOUT)
        shading = f"{LOBE_SHADING}. {SLIDE_SHADING}"
    if cfg.domain == "linear-clamped":
        shading = f"{LOBE_SHADING}. In {CLAMPED_SHADING}"
    return {
        "head": cfg.head,
        "lobes": cfg.lobes,
        "lobe_layout": list(LOBE_LAYOUT),
        "channels": channels,
        "deadzone": cfg.deadzone,
        "domain": cfg.domain,
        "disparity_depth": DISPARITY_DEPTH,
        "shading": shading,
    }


def manifest(
    name: str,
    kind: GraphKind,
    precision: str,
    onnx_bytes: bytes,
    cfg: NetConfig,
    info: ExportInfo,
    parity: dict,
) -> dict:
    specs = tensor_specs(cfg)
    validation = dict(info.validation or {})
    validation["onnxruntime_vs_pytorch"] = parity
    body = {
        "format": FORMAT,
        "name": name,
        "version": info.version,
        "task": kind.task,
        "precision": precision,
        "file": f"{name}.onnx",
        "sha256": sha256_bytes(onnx_bytes),
        "inputs": [specs[n] for n in kind.inputs],
        "outputs": [specs[n] for n in kind.outputs],
        "size_multiple": ALIGN,
        "image": IMAGE,
        "disparity_encoding": DISPARITY_ENCODING,
        "camera": CAMERA,
        "architecture": architecture(cfg, info.size, kind),
        "training": info.training,
        "validation": validation,
        "licence": info.licence,
        "source": info.source,
    }
    if kind is LOBES:
        body.update(lobe_fields(cfg))
    return body


def export_precision(
    net: ReshadeNet,
    precision: str,
    out_dir: Path,
    stem: str,
    info: ExportInfo,
    split: bool,
    height: int,
    width: int,
    camera: tuple[float, float, float] = (0.12, -0.05, 0.2),
    int8_form: str = "qdq",
) -> list[Path]:
    """Writes the single graph (and the split pair) for `net` at `precision`; returns the
    manifest paths. `net` is float, or quantised (calibrated) for int8; `int8_form` is a key
    of quantize.INT8_FORMS."""
    import onnx

    if height % ALIGN or width % ALIGN:
        raise ExportError(f"--height/--width must be multiples of {ALIGN}, got {height}x{width}")
    if (precision == "int8") != is_quantized(net):
        raise ExportError(
            "int8 export needs a quantised network (QAT checkpoint or --calibration); "
            "fp32/fp16 need a float one"
        )
    net = net.eval()
    cfg = net.cfg
    feed = {**parity_inputs(height, width), "camera": torch.tensor([camera])}
    qparams: dict[str, dict] = {}
    float_net = net
    if int8_form not in INT8_FORMS:
        raise ExportError(f"unknown int8 form {int8_form!r}: use one of {sorted(INT8_FORMS)}")
    if precision == "int8":
        if int8_form == "weights":
            net = copy.deepcopy(net)
            set_input_quantization(net, False)
        float_net, qparams = dequantized_float_net(net)
    written = []
    out_dir.mkdir(parents=True, exist_ok=True)
    for kind in graph_kinds(cfg, split):
        name = f"{stem}{kind.suffix}"
        gfeed = graph_inputs(net, kind, feed)
        if precision == "fp16":
            module = half_module(float_net, kind)
        else:
            module = graph_module(float_net, kind)
        model = to_onnx(module, cfg, kind, gfeed)
        if precision == "int8":
            # The lobe graph holds the network as `net`, so its weights are named net.<name>.
            prefix = "net." if kind is LOBES else ""
            named = {f"{prefix}{k}": v for k, v in qparams.items()}
            insert_conv_qdq(model, named, activations=int8_form == "qdq")
        try:
            onnx.checker.check_model(model, full_check=True)
        except onnx.checker.ValidationError as err:
            raise ExportError(f"{name}: exported graph fails onnx.checker: {err}") from err
        data = model.SerializeToString()
        parity = check_parity(data, graph_module(net, kind), kind, gfeed, precision)
        parity["input"] = f"parity_inputs({height}, {width}), camera {list(camera)}"
        if kind is LOBES:
            parity["input"] = f"parity_inputs({height}, {width}) with parity_intrinsics"
        body = manifest(name, kind, precision, data, cfg, info, parity)
        atomic_write_bytes(out_dir / f"{name}.onnx", data)
        atomic_write_bytes(out_dir / f"{name}.json", (json.dumps(body, indent=2) + "\n").encode())
        written.append(out_dir / f"{name}.json")
    return written


# --- provenance from the checkpoint ---------------------------------------------------------


def train_command(ckpt_path: Path, ckpt: dict) -> str:
    if ckpt.get("command"):  # `import` records the source's command and its own
        return ckpt["command"]
    config = ckpt_path.parent / "config.json"
    if config.is_file():
        try:
            return json.loads(config.read_text())["command"]
        except (ValueError, KeyError):
            pass
    args = ckpt.get("args") or {}
    parts = ["reshader-train", "train"]
    for k in ("data", "val_data", "run_dir", "size", "steps", "batch_size", "crop", "seed"):
        if args.get(k) is not None:
            parts += [f"--{k.replace('_', '-')}", str(args[k])]
    return " ".join(shlex.quote(p) for p in parts)


def train_wall_time(ckpt_path: Path) -> float | None:
    """Sum of the training segments in log.csv (elapsed_s restarts at every resume)."""
    import csv

    log = ckpt_path.parent / "log.csv"
    if not log.is_file():
        return None
    total, last = 0.0, 0.0
    with open(log, newline="") as f:
        for row in csv.DictReader(f):
            t = float(row["elapsed_s"])
            if t < last:
                total += last
            last = t
    return round(total + last, 1)


def training_info(ckpt_path: Path, ckpt: dict) -> dict:
    args = ckpt.get("args") or {}
    command = train_command(ckpt_path, ckpt)
    steps = int(ckpt.get("base_step", ckpt.get("step", 0)) or 0)
    wall = train_wall_time(ckpt_path) or ckpt.get("wall_time_s")
    data = str(args.get("data", "unknown"))
    if "quantization" in ckpt:
        base = Path(ckpt["base_checkpoint"])
        base_command = ckpt.get("base_command") or train_command(base, ckpt)
        command = f"{base_command} && {ckpt['qat_command']}"
        base_wall = train_wall_time(base) or ckpt.get("base_wall_time_s") or 0.0
        wall = float(base_wall) + float(ckpt.get("qat_wall_time_s", 0.0))
        steps += int(ckpt.get("qat_steps", 0))
        if ckpt.get("qat_data") and ckpt["qat_data"] != data:
            data = f"{data} (QAT: {ckpt['qat_data']})"
    return {
        "command": command,
        "data": data,
        "feature_network": ckpt.get("feature_net", "unknown"),
        "steps": steps,
        "wall_time_s": wall,
    }


def size_name(cfg: NetConfig) -> str:
    """The named size whose widths, conv counts and camera MLP `cfg` has (the output head and
    dead zone are not part of the size), else "custom"."""
    for name, c in SIZES.items():
        if (c.widths, c.convs, c.camera_hidden) == (cfg.widths, cfg.convs, cfg.camera_hidden):
            return name
    return "custom"


# --- command line ---------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "checkpoint", type=Path, help="training (.pt) or quantised (quantize) checkpoint"
    )
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--precision", nargs="+", choices=PRECISIONS, default=["fp32"])
    p.add_argument("--split", action="store_true", help="also write the encoder/decoder pair")
    p.add_argument("--height", type=int, default=384, help="trace and parity-check height")
    p.add_argument("--width", type=int, default=640, help="trace and parity-check width")
    p.add_argument("--size-name", help="name part after reshade- (default: lite/full/custom)")
    p.add_argument("--metrics", type=Path, help="JSON of validation metrics for the manifest")
    p.add_argument("--calibration", type=Path, help="dataset folder: int8 by PTQ of a float net")
    p.add_argument("--calibration-batches", type=int, default=16)
    p.add_argument("--calibration-crop", type=int, default=128)
    p.add_argument(
        "--int8-form",
        choices=sorted(INT8_FORMS),
        default="qdq",
        help="qdq: conv inputs + weights quantised; weights: int8 weights only (name ...-wo)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--version", default="0.1.0", help="model version for the manifest")


def _load_metrics(path: Path | None) -> dict | None:
    if path is None:
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise ExportError(f"{path}: cannot read metrics JSON ({err})") from err
    if not isinstance(data, dict):
        raise ExportError(f"{path}: metrics must be a JSON object")
    return data


def quantize_check(ckpt: dict) -> dict:
    """The held-out scores `quantize` measured (input, fp32, fp16, PTQ and QAT in both int8
    forms), with where and how, for the int8 manifest."""
    return {
        "command": ckpt.get("qat_command"),
        "target": ckpt.get("quantization", {}).get("qat_target"),
        **ckpt["validation"],
    }


def networks_for(args, net: ReshadeNet, ckpt: dict) -> dict[str, tuple[ReshadeNet, str]]:
    """precision -> (network, name suffix); PTQ int8 models are named ...-int8-ptq."""
    quantized = is_quantized(net)
    out = {}
    for precision in args.precision:
        if precision != "int8":
            if quantized:
                raise ExportError(
                    f"{args.checkpoint}: a quantised checkpoint exports only int8; "
                    "export fp32/fp16 from its base checkpoint"
                )
            out[precision] = (net, precision)
        elif quantized:
            out[precision] = (net, "int8")
        elif args.calibration is None:
            raise ExportError(
                f"{args.checkpoint}: float checkpoint: int8 needs --calibration DATA (PTQ) or a "
                "checkpoint from `reshader-train quantize` (QAT)"
            )
        else:
            q = quantize_network(copy.deepcopy(net))
            crops = training_crops(
                args.calibration, args.calibration_batches, 4, args.calibration_crop, args.seed
            )
            calibrate(q, crops)
            out[precision] = (q, "int8-ptq")
    return out


def run(args: argparse.Namespace) -> int:
    from .data import DatasetError

    try:
        net, ckpt = load_any_checkpoint(args.checkpoint)
        if net.cfg.head == "lobes-flow":
            raise ValueError(
                f"{args.checkpoint}: the lobes-flow head is for training experiments; the "
                f"runtime evaluates {' and '.join(EXPORTED_LOBE_HEADS)} only, so it has no export"
            )
        if net.cfg.domain not in EXPORTED_DOMAINS:
            raise ValueError(
                f"{args.checkpoint}: its lobes add in the {net.cfg.domain} domain; the runtime "
                f"adds them in {' or '.join(EXPORTED_DOMAINS)} only, so it has no export"
            )
        size = args.size_name or size_name(net.cfg)
        base_validation = _load_metrics(args.metrics)
        nets = networks_for(args, net, ckpt)
        if args.split and net.cfg.head in EXPORTED_LOBE_HEADS:
            print(
                "export: the lobe head is one graph per precision (-lobes); --split ignored",
                file=sys.stderr,
            )
        command = command_line("export", args, ("checkpoint",))
        for precision, (model, suffix) in nets.items():
            validation = dict(base_validation or {})
            if precision == "int8":
                method = "qat" if suffix == "int8" else "ptq"
                validation["quantization"] = {
                    **SCHEME,
                    "regions": INT8_FORMS[args.int8_form],
                    "form": args.int8_form,
                    "method": method,
                }
                if args.int8_form == "weights":
                    suffix += "-wo"
                if method == "qat" and ckpt.get("validation"):
                    validation["quantize_check"] = quantize_check(ckpt)
            info = ExportInfo(
                size=size,
                version=args.version,
                training=training_info(args.checkpoint, ckpt),
                validation=validation,
                source=f"{command} (torch {torch.__version__}, opset {OPSET}; checkpoint "
                f"{args.checkpoint.name} step {ckpt.get('step')})",
            )
            for path in export_precision(
                model,
                precision,
                args.out,
                f"reshade-{size}-{suffix}",
                info,
                args.split,
                args.height,
                args.width,
                int8_form=args.int8_form,
            ):
                parity = json.loads(path.read_text())["validation"]["onnxruntime_vs_pytorch"]
                print(f"{path.with_suffix('.onnx')}: max |ort - torch| {parity['max_abs']:.2e}")
    except (ExportError, DatasetError, FileNotFoundError, ValueError) as err:
        print(f"export: {err}", file=sys.stderr)
        return 2
    return 0
