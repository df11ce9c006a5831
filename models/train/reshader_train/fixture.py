"""`reshader-train fixture`: the tiny reshading model the runtime's unit tests load.

A network of widths 4,4,8,8,8,8 (one conv per block, camera MLP 3-16-125) is initialised
from a fixed seed and trained briefly (masked L1, Adam) on the synthetic dataset of
synthetic.py, whose "reshaded" image moves a highlight blob in proportion to the camera
offset: the camera dependence is real, and camera (0,0,0) should give the input back. It is
exported in fp32, fp16 and int8 (post-training calibrated), single graph and split pair,
with manifests, plus `parity.json`: PyTorch's outputs on a closed-form input for two cameras
and the tolerance each precision meets with onnxruntime.
"""

from __future__ import annotations

import argparse
import base64
import copy
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from .data import Augment, ReshadeDataset
from .export import (
    DECODER,
    ENCODER,
    ExportInfo,
    export_precision,
    parity_inputs,
    run_onnxruntime,
)
from .model import ReshadeNet, net_config
from .quantize import calibrate, quantize_network, training_crops
from .synthetic import write_dataset

WIDTHS = "4,4,4,4,4,4"
CAMERAS = ((0.0, 0.0, 0.0), (0.2, -0.1, 0.15))
STEM = "reshade-fixture"
IDENTITY_PER_BATCH = 2  # of 8
# Floors of the stated tolerances (the measured difference is doubled, never below these).
TOLERANCE_FLOOR = {"fp32": 1e-5, "fp16": 1e-3, "int8": 1e-4}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, help="folder (models/fixtures)")
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--examples", type=int, default=32, help="synthetic training examples")
    p.add_argument("--height", type=int, default=32, help="parity input height")
    p.add_argument("--width", type=int, default=64, help="parity input width")


def train_tiny(steps: int, seed: int, data: Path) -> tuple[ReshadeNet, float]:
    """Masked L1 training from a fixed seed; returns the network and its last-50-step loss."""
    torch.manual_seed(seed)
    net = ReshadeNet(net_config(WIDTHS))
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    losses = []
    for b in training_crops(data, steps, 8, 64, seed):
        # The generator's reshaded image is the input when the offset is zero; show the
        # network that case often so that the runtime can test identity at camera (0,0,0).
        b["camera"][:IDENTITY_PER_BATCH] = 0.0
        b["target"][:IDENTITY_PER_BATCH] = b["image"][:IDENTITY_PER_BATCH]
        pred = net(b["image"], b["disparity"], b["camera"])
        loss = ((pred - b["target"]).abs() * b["mask"]).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    return net.eval(), float(np.mean(losses[-50:]))


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype="<f4").tobytes()).decode()


def onnx_output(out: Path, stem: str, split: bool, feed: dict) -> np.ndarray:
    if not split:
        return run_onnxruntime((out / f"{stem}.onnx").read_bytes(), feed)[0]
    enc = run_onnxruntime((out / f"{stem}{ENCODER.suffix}.onnx").read_bytes(), feed)
    dfeed = {**dict(zip(ENCODER.outputs, map(torch.from_numpy, enc), strict=True)), **feed}
    return run_onnxruntime((out / f"{stem}{DECODER.suffix}.onnx").read_bytes(), dfeed)[0]


def parity_record(net: ReshadeNet, qnet: ReshadeNet, out: Path, height: int, width: int) -> dict:
    """PyTorch references (fp32 network, and the fake-quantised network for int8) and what
    onnxruntime achieves against them for every precision, single graph and split pair."""
    base = parity_inputs(height, width)
    cases, refs = [], {"fp32": [], "int8": []}
    for cam in CAMERAS:
        with torch.no_grad():
            args = (base["image"], base["disparity"], torch.tensor([cam]))
            ref, qref = net(*args).numpy(), qnet(*args).numpy()
        refs["fp32"].append(ref)
        refs["int8"].append(qref)
        cases.append({"camera": list(cam), "reshaded": _b64(ref), "reshaded_int8": _b64(qref)})
    measured = {}
    for precision in ("fp32", "fp16", "int8"):
        worst = mean = 0.0
        for cam, ref in zip(CAMERAS, refs["int8" if precision == "int8" else "fp32"], strict=True):
            feed = {**base, "camera": torch.tensor([cam])}
            for split in (False, True):
                got = onnx_output(out, f"{STEM}-{precision}", split, feed)
                worst = max(worst, float(np.abs(got - ref).max()))
                mean = max(mean, float(np.abs(got - ref).mean()))
        measured[precision] = {
            "reference": "reshaded_int8" if precision == "int8" else "reshaded",
            "onnxruntime_max_abs": worst,
            "onnxruntime_mean_abs": mean,
            "tolerance": float(f"{max(2 * worst, TOLERANCE_FLOOR[precision]):.2g}"),
        }
    int8_vs_fp32 = max(
        float(np.abs(a - b).max()) for a, b in zip(refs["int8"], refs["fp32"], strict=True)
    )
    refs = refs["fp32"]
    image = base["image"].numpy()
    return {
        "format": "reshader-parity/1",
        "model": STEM,
        "height": height,
        "width": width,
        "input": {
            "generator": "closed form, float32, NCHW (x, y pixel indices; W, H the size)",
            "image": "image[c,y,x] = 0.1 + 0.1*c + 0.2*x/W + 0.5*exp(-((x - 0.4*W)^2 + "
            "(y - 0.45*H)^2) / (2*s^2)), s = 0.15*min(H, W)",
            "disparity": "disparity[y,x] = 0.25 / (1.5 + x/W + y/H)",
            "image_sum": float(image.astype(np.float64).sum()),
            "disparity_sum": float(base["disparity"].numpy().astype(np.float64).sum()),
        },
        "outputs": "reshaded [1,3,H,W] float32 little-endian, base64: PyTorch fp32 network "
        "(reshaded) and its fake-quantised int8 version (reshaded_int8)",
        "cases": cases,
        "precisions": measured,
        "camera_dependence": {
            "mean_abs_between_cameras": float(np.abs(refs[1] - refs[0]).mean()),
            "max_abs_between_cameras": float(np.abs(refs[1] - refs[0]).max()),
            "identity_max_abs_at_camera_0": float(np.abs(refs[0] - image).max()),
            "identity_mean_abs_at_camera_0": float(np.abs(refs[0] - image).mean()),
        },
        "int8_vs_fp32_max_abs": int8_vs_fp32,
    }


def make_fixture(out: Path, steps: int, seed: int, examples: int, height: int, width: int):
    t0 = time.time()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        data = write_dataset(Path(tmp) / "synthetic", examples, 64, 64, seed=seed)
        net, loss = train_tiny(steps, seed, data)
        qnet = quantize_network(copy.deepcopy(net))
        calibrate(qnet, training_crops(data, 8, 8, 64, seed + 1))
        n_examples = len(ReshadeDataset(data))
    wall = round(time.time() - t0, 1)
    command = (
        f"reshader-train fixture --out {out} --steps {steps} --seed {seed} "
        f"--examples {examples} --height {height} --width {width}"
    )
    info = ExportInfo(
        size="fixture",
        training={
            "command": command,
            "data": f"synthetic.write_dataset({examples} examples, 64x64, seed {seed}); "
            f"crops 64, {Augment()}",
            "feature_network": "none (masked L1 only: a test fixture)",
            "steps": steps,
            "wall_time_s": wall,
        },
        validation={"train_l1_last50": loss, "train_examples": n_examples},
        source=f"{command} (torch {torch.__version__})",
    )
    for precision, model in (("fp32", net), ("fp16", net), ("int8", qnet)):
        export_precision(model, precision, out, f"{STEM}-{precision}", info, True, height, width)
    record = parity_record(net, qnet, out, height, width)
    tmp = out / ".parity.json.tmp"
    tmp.write_text(json.dumps(record, indent=1) + "\n")
    os.replace(tmp, out / "parity.json")
    return record


def run(args: argparse.Namespace) -> int:
    record = make_fixture(args.out, args.steps, args.seed, args.examples, args.height, args.width)
    total = sum(p.stat().st_size for p in args.out.iterdir() if p.is_file())
    print(json.dumps({k: record[k] for k in ("precisions", "camera_dependence")}, indent=1))
    print(f"{args.out}: {total / 1024:.0f} KB in {len(list(args.out.iterdir()))} files")
    return 0
