"""`reshader-train convert-depth`: Caffe2 Tiefenrausch -> ONNX int8 + fp32, manifests, LICENSE.

Writes into --out: tiefenrausch-int8.onnx, tiefenrausch-fp32.onnx, a reshader-manifest/1 JSON
beside each (with the errors measured by onnxruntime against the reference disparities shipped
with the model) and the model's LICENSE. Nothing is written unless both graphs convert, pass
the ONNX checker and correlate with the reference at least --min-pearson.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from .caffe2_model import Caffe2Model, Caffe2ModelError, load_caffe2_model
from .onnx_export import INPUT_NAME, OUTPUT_NAME, build_onnx
from .preprocess import LONG_SIDE, MULTIPLE
from .protobuf import ProtobufError
from .verify import (
    disparity_errors,
    emulation_agreement,
    identical_levels,
    onnxruntime_outputs,
    reference_pairs,
)

NAME = "tiefenrausch"
VERSION = "1.0.0"
COMMAND = (
    "reshader-train convert-depth --source ../shared/third_party/tiefenrausch --out models/depth"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--source",
        type=Path,
        required=True,
        help="folder with model/tiefenrausch.pb, model/tiefenrausch_init.pb, LICENSE, "
        "input/*.jpg and output/*.npy (e.g. ../shared/third_party/tiefenrausch)",
    )
    parser.add_argument("--out", type=Path, default=Path("models/depth"), help="output folder")
    parser.add_argument(
        "--int8-form",
        choices=("qlinear", "qdq"),
        default="qlinear",
        help="QLinearConv (default: tract runs it with int8 kernels) or QuantizeLinear/"
        "DequantizeLinear around float Conv",
    )
    parser.add_argument(
        "--emulate",
        action="store_true",
        help="also run the numpy emulation of Caffe2's QNNPACK arithmetic (slow) and record "
        "how many output levels equal the reference's in the int8 manifest",
    )
    parser.add_argument(
        "--min-pearson",
        type=float,
        default=0.999,
        help="refuse to write models whose disparity correlates less with the reference",
    )


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_atomic(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _manifest(
    model: Caffe2Model, precision: str, form: str, onnx_file: Path, errors: list, sources: dict
) -> dict:
    out_q = model.quant[model.ops[-1].inputs[0]]
    out_range = [-out_q.zero_point * out_q.scale, (255 - out_q.zero_point) * out_q.scale]
    return {
        "format": "reshader-manifest/1",
        "name": onnx_file.stem,
        "version": VERSION,
        "task": "depth",
        "precision": precision,
        "file": onnx_file.name,
        "sha256": _sha256(onnx_file),
        "inputs": [
            {
                "name": INPUT_NAME,
                "dtype": "float32",
                "layout": "NCHW",
                "shape": [1, 3, "H", "W"],
                "range": [0.0, 1.0],
                "description": "RGB photo in [0,1], area-resized so the longer side is 384 "
                "(aspect kept, shorter side truncated), then each side rounded down to a "
                "multiple of 32",
            }
        ],
        "outputs": [
            {
                "name": OUTPUT_NAME,
                "dtype": "float32",
                "layout": "NCHW",
                "shape": [1, 1, "H", "W"],
                "range": [round(v, 6) for v in out_range],
                "description": "natural log of relative (affine-ambiguous) disparity; "
                "disparity = exp(output), larger = nearer",
            }
        ],
        "size_multiple": MULTIPLE,
        "image": {
            "color": "srgb",
            "range": [0, 1],
            "channel_order": "rgb",
            "mean": None,
            "std": None,
        },
        "depth": {
            "input_size": {"policy": "longest-side", "size": LONG_SIDE, "multiple": MULTIPLE},
            "resize": "area",
            "normalisation": "rgb [0,1], no mean/std",
            "output_kind": "log-disparity",
        },
        "architecture": {
            "size": "tiefenrausch (AS + quant)",
            "graph_form": form,
            "caffe2_ops": model.op_counts(),
            "parameters": model.parameter_count(),
        },
        "training": None,
        "validation": {
            "engine": "onnxruntime CPU",
            "metric": "disparity = exp(output) vs the original Caffe2 output (output/*.npy): "
            "relative error |d - ref| / ref, and Pearson correlation",
            "photos": errors,
        },
        "licence": "MIT (Copyright (c) 2020 Facebook Research); LICENSE beside this file",
        "source": "facebookresearch/one_shot_3d_photography, model/tiefenrausch.pb and "
        "model/tiefenrausch_init.pb (Kopf et al. 2020, 'One Shot 3D Photography', "
        "Tiefenrausch AS + quant); converted by reshader-train convert-depth",
        "source_sha256": sources,
        "conversion_command": COMMAND,
    }


def _measure(
    path: Path, pairs: list, out_scale: float, min_pearson: float
) -> tuple[list[np.ndarray], list[dict]]:
    """onnxruntime outputs on the reference photos and their errors; refuses poor models."""
    outputs = onnxruntime_outputs(path, pairs)
    errors = []
    for (photo, ref_path), y in zip(pairs, outputs, strict=True):
        ref = np.load(ref_path)
        e = disparity_errors(photo.name, y, ref).as_dict()
        e["identical_output_levels"] = identical_levels(y, ref, out_scale)
        print(
            f"{path.name} {photo.name}: max rel {e['max_rel']:.4f}, mean rel "
            f"{e['mean_rel']:.5f}, pearson {e['pearson']:.6f}, identical levels "
            f"{e['identical_output_levels']:.3f}"
        )
        if not e["pearson"] >= min_pearson:
            raise Caffe2ModelError(
                f"{path.name} on {photo.name}: pearson {e['pearson']:.6f} < {min_pearson}"
            )
        errors.append(e)
    return outputs, errors


def convert(
    source: Path, out: Path, int8_form: str, min_pearson: float, emulate: bool = False
) -> list[dict]:
    """Convert, verify and write both models; returns the manifests written."""
    predict, init = source / "model/tiefenrausch.pb", source / "model/tiefenrausch_init.pb"
    licence = source / "LICENSE"
    if not licence.is_file():
        raise FileNotFoundError(f"{licence}: missing; the MIT licence must ship with the model")
    model = load_caffe2_model(predict, init)
    pairs = reference_pairs(source)
    out.mkdir(parents=True, exist_ok=True)
    sources = {p.name: _sha256(p) for p in (predict, init)}
    out_q = model.quant[model.ops[-1].inputs[0]]
    with tempfile.TemporaryDirectory(dir=out, prefix=".convert-depth.") as tmp:
        staged, outputs = [], {}
        for precision, form in (("int8", int8_form), ("fp32", "fp32")):
            path = Path(tmp) / f"{NAME}-{precision}.onnx"
            path.write_bytes(build_onnx(model, form).SerializeToString())
            path.chmod(0o644)
            outputs[precision], errors = _measure(path, pairs, out_q.scale, min_pearson)
            staged.append((path, _manifest(model, precision, form, path, errors, sources)))
        int8_vs_fp32 = [
            disparity_errors(photo.name, yi, np.exp(yf)).as_dict()
            for (photo, _), yi, yf in zip(pairs, outputs["int8"], outputs["fp32"], strict=True)
        ]
        for _, manifest in staged:
            manifest["validation"]["int8_vs_fp32"] = int8_vs_fp32
        if emulate:
            agreement = emulation_agreement(model, pairs)
            for a in agreement:
                print(f"QNNPACK emulation {a}")
            staged[0][1]["validation"]["caffe2_qnnpack_emulation"] = agreement
        for path, manifest in staged:
            os.replace(path, out / path.name)
            text = json.dumps(manifest, indent=2) + "\n"
            write_atomic(out / f"{path.stem}.json", text.encode())
        write_atomic(out / "LICENSE", licence.read_bytes())
    return [m for _, m in staged]


def run(args: argparse.Namespace) -> int:
    try:
        convert(args.source, args.out, args.int8_form, args.min_pearson, args.emulate)
    except (OSError, ProtobufError, Caffe2ModelError, ValueError) as err:
        print(f"reshader-train convert-depth: {err}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}/{NAME}-int8.onnx, {NAME}-fp32.onnx, their manifests and LICENSE")
    return 0
