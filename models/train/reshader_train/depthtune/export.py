"""`reshader-train export-depth`: a `train-depth` checkpoint written into the fp32 graph.

The tuned weights replace the base graph's convolution initializers (the clips and the
graph stay as they are), so the runtime loads the file as it loads the shipped one. The
manifest is the base's with the name, file, sha256, version and a `training` block; its
`validation` becomes the tuned graph against the base on the photos of `--photos` (how
far the tuning moved real photos' depth: Pearson correlation and mean relative difference
of disparity after the affine fit). Nothing is written unless the checkpoint fits the
graph; the ONNX and its manifest are written beside each other, atomically.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import sys
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from ..depthconv.command import write_atomic
from ..depthconv.preprocess import load_rgb, network_input
from .graph import GraphError, learned_names, weight_key


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("checkpoint", type=Path, help="a train-depth checkpoint (RUN/step-NNNNNN.pt)")
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        help="the ONNX file to write (its manifest goes beside it as .json)",
    )
    p.add_argument(
        "--base",
        type=Path,
        default=Path("models/depth/tiefenrausch-fp32.onnx"),
        help="the graph the run started from (its manifest beside it)",
    )
    p.add_argument("--version", default="1.1.0")
    p.add_argument(
        "--strength",
        type=float,
        default=1.0,
        help="how much of the tuning's change to keep: each weight becomes base + "
        "STRENGTH x (tuned - base); 1 writes the checkpoint as it is, 0 the base "
        "(interpolating towards the base keeps more of its behaviour on real photos)",
    )
    p.add_argument(
        "--int8",
        action="store_true",
        help="also write the int8 graph (QLinearConv) beside --out, its name with int8 for "
        "fp32: the tuned weights quantised at --int8-base's scales and zero points",
    )
    p.add_argument(
        "--int8-base",
        type=Path,
        default=Path("models/depth/tiefenrausch-int8.onnx"),
        help="the int8 form of --base (its manifest beside it)",
    )
    p.add_argument(
        "--photos",
        type=Path,
        nargs="*",
        default=[],
        help="real photos to compare the tuned depth with the base's on",
    )
    p.add_argument(
        "--sheet",
        type=Path,
        default=None,
        help="also write a PNG of those photos: the network's input, the base's disparity "
        "and the tuned one's (near = white), one row per photo",
    )


def tuned_model(
    base: Path, weights: dict[str, torch.Tensor], strength: float = 1.0
) -> onnx.ModelProto:
    """The base graph with the checkpoint's weights, or with the fraction `strength` of
    their change from the base's."""
    model = onnx.load(str(base))
    names = set(learned_names(model))
    missing = [n for n in names if weight_key(n) not in weights]
    if missing or len(weights) != len(names):
        raise GraphError(
            f"checkpoint does not fit {base}: {len(missing)} weights missing, "
            f"{len(weights)} given for {len(names)}"
        )
    for init in model.graph.initializer:
        if init.name in names:
            tuned = weights[weight_key(init.name)].cpu().numpy().astype(np.float32)
            start = numpy_helper.to_array(init).astype(np.float32)
            array = tuned if strength == 1.0 else start + np.float32(strength) * (tuned - start)
            init.CopyFrom(numpy_helper.from_array(array, init.name))
    onnx.checker.check_model(model)
    return model


def quantised_model(int8_base: Path, fp32: onnx.ModelProto) -> tuple[onnx.ModelProto, int]:
    """`int8_base` with each QLinearConv's weights and bias taken from the fp32 graph's
    convolution of the same names, quantised at the base's own scales and zero points
    (the base's fp32 graph gives the base's int8 graph back exactly). Also returns how
    many weights fell outside the 8-bit range and were clipped."""
    model = onnx.load(str(int8_base))
    floats = {i.name: numpy_helper.to_array(i) for i in fp32.graph.initializer}
    inits = {i.name: i for i in model.graph.initializer}
    clipped = 0

    def scalar(name: str) -> float:
        return float(numpy_helper.to_array(inits[name]))

    for node in (n for n in model.graph.node if n.op_type == "QLinearConv"):
        x_scale, w, w_scale, w_zero = node.input[1], node.input[3], node.input[4], node.input[5]
        if w not in floats:
            raise GraphError(f"{int8_base}: {w} has no convolution of that name in the fp32 graph")
        q = np.round(floats[w] / scalar(w_scale)) + scalar(w_zero)
        clipped += int(((q < 0) | (q > 255)).sum())
        inits[w].CopyFrom(numpy_helper.from_array(np.clip(q, 0, 255).astype(np.uint8), w))
        if len(node.input) > 8 and node.input[8]:
            b = node.input[8]
            q_bias = np.round(floats[b] / (scalar(x_scale) * scalar(w_scale)))
            inits[b].CopyFrom(numpy_helper.from_array(q_bias.astype(np.int32), b))
    onnx.checker.check_model(model)
    return model, clipped


def _grey(disparity: np.ndarray) -> np.ndarray:
    """Disparity as 8-bit grey, its 2nd to 98th percentile stretched over the range."""
    lo, hi = np.percentile(disparity, [2, 98])
    grey = np.clip((disparity - lo) / max(hi - lo, 1e-9), 0, 1) * 255
    return np.repeat(grey.astype(np.uint8)[..., None], 3, 2)


def _write_sheet(path: Path, rows: list[np.ndarray]) -> None:
    from PIL import Image

    width = max(r.shape[1] for r in rows)
    padded = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    buf = io.BytesIO()
    Image.fromarray(np.concatenate(padded, 0)).save(buf, format="PNG")
    write_atomic(path, buf.getvalue())


def photo_agreement(
    base: Path | onnx.ModelProto,
    tuned: onnx.ModelProto,
    photos: list[Path],
    sheet: Path | None = None,
) -> list[dict]:
    """How far the tuned graph moved each photo's disparity from the base graph's; with
    `sheet`, a PNG with one row per photo: the network's input, the base's disparity and
    the tuned one's (near = white)."""
    import onnxruntime as ort

    sessions = [
        ort.InferenceSession(
            str(m) if isinstance(m, Path) else m.SerializeToString(),
            providers=["CPUExecutionProvider"],
        )
        for m in (base, tuned)
    ]
    rows, tiles = [], []
    for photo in photos:
        x = network_input(load_rgb(photo))
        maps = [np.exp(s.run(None, {"image": x})[0][0, 0]) for s in sessions]
        tiles.append(
            np.concatenate([(x[0].transpose(1, 2, 0) * 255).astype(np.uint8), *map(_grey, maps)], 1)
        )
        a, b = (m.ravel() for m in maps)
        fit = np.polyfit(b, a, 1)
        rows.append(
            {
                "photo": photo.name,
                "size": [int(x.shape[3]), int(x.shape[2])],
                "pearson": float(np.corrcoef(a, b)[0, 1]),
                "mean_rel_after_fit": float(np.mean(np.abs(np.polyval(fit, b) - a) / a)),
            }
        )
    if sheet is not None and tiles:
        _write_sheet(sheet, tiles)
    return rows


def _manifest(
    base: Path, out: Path, data: bytes, version: str, training: dict, validation: dict
) -> bytes:
    """`base`'s manifest made `out`'s: name, file, sha256, version, training, validation."""
    manifest = json.loads(base.with_suffix(".json").read_text())
    manifest.update(
        name=out.stem,
        version=version,
        file=out.name,
        sha256=hashlib.sha256(data).hexdigest(),
        training={"from": f"{manifest['name']} {manifest['version']}", **training},
        validation={
            "engine": "onnxruntime CPU",
            "metric": "disparity exp(output) of this graph against the reference graph's, "
            "after an affine fit: Pearson correlation and mean relative difference",
            **validation,
        },
    )
    return (json.dumps(manifest, indent=2) + "\n").encode()


def export(args) -> None:
    state = torch.load(args.checkpoint, weights_only=False)
    if not 0.0 <= args.strength <= 1.0:
        raise ValueError(f"--strength {args.strength} is outside 0..1")
    if args.int8 and not args.out.stem.endswith("fp32"):
        raise ValueError(
            f"--int8 names its file after --out, whose name must end in fp32: {args.out}"
        )
    model = tuned_model(args.base, state["weights"], args.strength)
    training = {
        "command": state["command"],
        "steps": state["step"],
        "wall_time_s": round(state["wall_time_s"]),
        "examples": state["examples"],
        "checkpoint": str(args.checkpoint),
        "strength": args.strength,
    }
    data = model.SerializeToString()
    files = {
        args.out: data,
        args.out.with_suffix(".json"): _manifest(
            args.base,
            args.out,
            data,
            args.version,
            training,
            {
                "reference": f"{args.base.name} (the graph tuned)",
                "photos": photo_agreement(args.base, model, args.photos, args.sheet),
            },
        ),
    }
    if args.int8:
        int8, clipped = quantised_model(args.int8_base, model)
        out8 = args.out.with_name(args.out.stem[: -len("fp32")] + "int8.onnx")
        data8 = int8.SerializeToString()
        files[out8] = data8
        files[out8.with_suffix(".json")] = _manifest(
            args.int8_base,
            out8,
            data8,
            args.version,
            {
                **training,
                "quantised": f"at {args.int8_base.name}'s scales; {clipped} weights clipped",
            },
            {
                "reference": f"{args.out.name} (the same weights in fp32)",
                "photos": photo_agreement(model, int8, args.photos),
            },
        )
    for path, content in files.items():
        write_atomic(path, content)
    print("export-depth: wrote " + ", ".join(str(p) for p in files))


def run(args) -> int:
    try:
        export(args)
    except (GraphError, OSError, KeyError, ValueError) as err:
        print(f"reshader-train export-depth: {err}", file=sys.stderr)
        return 2
    return 0
