"""`reshader-train examples`: held-out examples as the runtime reads them, with PyTorch's scores.

The runtime reshades 8-bit photos; the network was evaluated on float images. This writes,
for the first --count examples of a dataset, what a Rust test needs to check the shipped
ONNX files on real data: the evaluation tone mapping of input and ground truth rounded to
8 bits (input.png, reshaded.png), the validity mask (mask.png), the network's disparity
input (disparity.npy, float32 HxW) and, in examples.json, the camera offset and the masked
PSNR of the 8-bit input and of the checkpoint's output on that same 8-bit input. A runtime
that loads the model exported from this checkpoint must reproduce those PSNRs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from .data import DatasetError, list_examples, load_example, make_sample
from .evaluate import load_checkpoint_model, masked_psnr, reshade
from .tonemap import EVAL_EXPOSURE, EVAL_GAMMA


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--checkpoint", type=Path, required=True, help="training checkpoint (.pt)")
    p.add_argument("--data", type=Path, required=True, help="held-out dataset folder")
    p.add_argument("--count", type=int, default=4, help="the first N examples (default 4)")
    p.add_argument("--out", type=Path, required=True, help="output folder")


def quantised(x: torch.Tensor) -> torch.Tensor:
    return torch.round(x.clamp(0, 1) * 255) / 255


def save_png(path: Path, chw: torch.Tensor) -> None:
    hwc = (chw.permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)
    Image.fromarray(hwc[..., 0] if hwc.shape[2] == 1 else hwc).save(path, format="PNG")


def write_example(net, folder: Path, out: Path) -> dict:
    s = make_sample(load_example(folder), crop=None, rng=None, aug=None)
    image, target, mask = quantised(s["image"]), quantised(s["target"]), s["mask"]
    ours = reshade(net, image, s["disparity"], s["camera"], s["rays"])
    out.mkdir(parents=True, exist_ok=True)
    save_png(out / "input.png", image)
    save_png(out / "reshaded.png", target)
    save_png(out / "mask.png", mask)
    np.save(out / "disparity.npy", s["disparity"][0].numpy().astype(np.float32))
    return {
        "example": folder.name,
        "camera": [float(c) for c in s["camera"]],
        "psnr_input": masked_psnr(image, target, mask),
        "psnr_ours_pytorch": masked_psnr(ours, target, mask),
    }


def run(args: argparse.Namespace) -> int:
    try:
        net, ckpt = load_checkpoint_model(args.checkpoint)
    except (FileNotFoundError, ValueError) as err:
        print(f"examples: {err}", file=sys.stderr)
        return 2
    try:
        folders = list_examples(args.data)[: args.count]
    except DatasetError as err:
        print(f"examples: {err}", file=sys.stderr)
        return 2
    if not folders:
        print(f"examples: {args.data} holds no complete example", file=sys.stderr)
        return 2
    rows = [write_example(net, f, args.out / f.name) for f in folders]
    report = {
        "checkpoint": str(args.checkpoint),
        "checkpoint_sha256": hashlib.sha256(args.checkpoint.read_bytes()).hexdigest(),
        "step": ckpt.get("step"),
        "data": str(args.data),
        "exposure": EVAL_EXPOSURE,
        "gamma": EVAL_GAMMA,
        "examples": rows,
    }
    tmp = args.out / ".examples.json.tmp"
    tmp.write_text(json.dumps(report, indent=2) + "\n")
    os.replace(tmp, args.out / "examples.json")
    for r in rows:
        gain = r["psnr_ours_pytorch"] - r["psnr_input"]
        print(f"{r['example']}: input {r['psnr_input']:.2f} dB, ours {gain:+.2f} dB")
    return 0
