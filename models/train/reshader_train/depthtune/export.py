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


def tuned_model(base: Path, weights: dict[str, torch.Tensor]) -> onnx.ModelProto:
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
            array = weights[weight_key(init.name)].cpu().numpy().astype(np.float32)
            init.CopyFrom(numpy_helper.from_array(array, init.name))
    onnx.checker.check_model(model)
    return model


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
    base: Path, tuned: onnx.ModelProto, photos: list[Path], sheet: Path | None = None
) -> list[dict]:
    """How far the tuned graph moved each photo's disparity from the base graph's; with
    `sheet`, a PNG with one row per photo: the network's input, the base's disparity and
    the tuned one's (near = white)."""
    import onnxruntime as ort

    sessions = [
        ort.InferenceSession(str(base), providers=["CPUExecutionProvider"]),
        ort.InferenceSession(tuned.SerializeToString(), providers=["CPUExecutionProvider"]),
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


def export(args) -> None:
    state = torch.load(args.checkpoint, weights_only=False)
    model = tuned_model(args.base, state["weights"])
    manifest = json.loads(args.base.with_suffix(".json").read_text())
    data = model.SerializeToString()
    manifest.update(
        name=args.out.stem,
        version=args.version,
        file=args.out.name,
        sha256=hashlib.sha256(data).hexdigest(),
        training={
            "from": f"{manifest['name']} {manifest['version']}",
            "command": state["command"],
            "steps": state["step"],
            "wall_time_s": round(state["wall_time_s"]),
            "examples": state["examples"],
            "checkpoint": str(args.checkpoint),
        },
        validation={
            "engine": "onnxruntime CPU",
            "metric": "disparity exp(output) of this graph against the base graph's, after an "
            "affine fit: Pearson correlation and mean relative difference",
            "photos": photo_agreement(args.base, model, args.photos, args.sheet),
        },
    )
    write_atomic(args.out, data)
    write_atomic(args.out.with_suffix(".json"), (json.dumps(manifest, indent=2) + "\n").encode())
    print(f"export-depth: wrote {args.out} and {args.out.with_suffix('.json')}")


def run(args) -> int:
    try:
        export(args)
    except (GraphError, OSError, KeyError, ValueError) as err:
        print(f"reshader-train export-depth: {err}", file=sys.stderr)
        return 2
    return 0
