"""`reshader-train fixture`: the tiny reshading model the runtime's unit tests load.

A network of widths 4,4,8,8,8,8 (one conv per block, camera MLP 3-16-125) is initialised
from a fixed seed and trained briefly (masked L1, Adam) on the synthetic dataset of
synthetic.py, whose "reshaded" image moves a highlight blob in proportion to the camera
offset: the camera dependence is real, and camera (0,0,0) should give the input back. It is
exported in fp32, fp16 and int8 (post-training calibrated), single graph and split pair,
with manifests, plus `parity.json`: PyTorch's outputs on a closed-form input for two cameras
and the tolerance each precision meets with onnxruntime.

`--head lobes` writes the lobe head's fixture beside it instead (the residual files are left
alone): the same widths with 2 lobes and a dead zone, its last convolution drawn with
visible weights (one lobe comes out sharp, sharpness 9-2160, the other broad, 1.6-39), not
trained by default: on the synthetic data the network learns within 100 steps to make its
lobes so sharp (1e3-1e4) that 2 % of the parity input's pixels change, and within 50 steps
with the last convolution free to change none at all (measured; --steps N trains the rest
with the last convolution frozen). Exported as one graph per precision
(`reshade-fixture-<precision>-lobes`, int8 in the weights-only form shipped for tract), and
`parity-lobes.json`: the closed-form input with its camera intrinsics, PyTorch's lobes and
its reshaded images (model.shade_lobes, clamped) for three cameras, one of them beyond the
trained offsets, so that the runtime can check its per-view closed form without Python.

`--head lobes-slide` writes the same for the lobes-slide head (one lobe and the sliding
layer, its fraction biased up so that a fifth of the photo slides), named
`reshade-fixture-slide-<precision>-lobes`; give it a folder of its own (models/fixtures/slide),
as the runtime finds one lobe-head manifest per precision in a folder.

`--head lobes-photo` writes the lobes head with one lobe in the linear-clamped domain, its
amplitudes taken from the photo (`--lobe-amplitude photo`), named
`reshade-fixture-photo-<precision>-lobes`, into a folder of its own (models/fixtures/photo).
"""

from __future__ import annotations

import argparse
import base64
import copy
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from .data import Augment, ReshadeDataset
from .export import (
    DECODER,
    ENCODER,
    LOBES,
    PARITY_HFOV_DEG,
    ExportInfo,
    export_precision,
    parity_inputs,
    parity_intrinsics,
    run_onnxruntime,
)
from .model import LOBE_LAYOUT, ReshadeNet, net_config, shade_lobes
from .quantize import (
    INT8_FORMS,
    SCHEME,
    calibrate,
    quantize_network,
    set_input_quantization,
    training_crops,
)
from .synthetic import write_dataset

WIDTHS = "4,4,4,4,4,4"
CAMERAS = ((0.0, 0.0, 0.0), (0.2, -0.1, 0.15))
STEM = "reshade-fixture"
IDENTITY_PER_BATCH = 2  # of 8
# Floors of the stated tolerances (the measured difference is doubled, never below these).
TOLERANCE_FLOOR = {"fp32": 1e-5, "fp16": 1e-3, "int8": 1e-4}


# The lobe head's fixture.
LOBE_COUNT = 2
LOBE_DEADZONE = 0.004
# The input camera (the photo exactly), one inside the trained offsets, one beyond them.
LOBE_CAMERAS = ((0.0, 0.0, 0.0), (0.2, -0.1, 0.15), (0.5, 0.0, 0.0))
LOBE_INIT_STD = 0.3  # last conv: visible lobes from the first step
# Added to the raw sharpness channels: without it the median sharpness is the network's
# initial 100, at which a 0.2 offset changes 35 % of the parity input's pixels; at -1, 79 %.
LOBE_SHARPNESS_BIAS = -1.0
LOBE_PARITY = "parity-lobes.json"
# The lobes-slide fixture: lobes, name, and the raw fraction's bias (sigmoid(1.5 - 3): a
# fifth of the photo slides, a visible layer).
SLIDE_LOBES = 1
SLIDE_STEM = "reshade-fixture-slide"
SLIDE_FRACTION_RAW_BIAS = 1.5
# The lobes-photo fixture: lobes and name; the raw share's bias lifts the shares from the
# untrained 1e-3 to where a view visibly moves light.
PHOTO_LOBES = 1
PHOTO_STEM = "reshade-fixture-photo"
PHOTO_SHARE_RAW_BIAS = 2.0
# The fixture kinds beyond the residual one: (head, lobes, domain, amplitude, stem).
LOBE_FIXTURES = {
    "lobes": ("lobes", LOBE_COUNT, "display", "free", None),
    "lobes-slide": ("lobes-slide", SLIDE_LOBES, "display", "free", SLIDE_STEM),
    "lobes-photo": ("lobes", PHOTO_LOBES, "linear-clamped", "photo", PHOTO_STEM),
}
STEPS = 1000
LOBE_STEPS = 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, help="folder (models/fixtures)")
    p.add_argument(
        "--head",
        choices=("residual", *LOBE_FIXTURES),
        default="residual",
        help="residual: the encoder/decoder fixture and parity.json; lobes or lobes-slide: that "
        "lobe head's graphs (-lobes) and parity-lobes.json; lobes-photo: the lobes head in the "
        "linear-clamped domain with amplitudes from the photo (lobes-slide and lobes-photo "
        "into folders of their own)",
    )
    p.add_argument(
        "--steps", type=int, help=f"training steps (default {STEPS} residual, {LOBE_STEPS} lobes)"
    )
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


# --- the lobe head ----------------------------------------------------------------------------


def train_tiny_lobes(
    steps: int, seed: int, data: Path, kind: str = "lobes"
) -> tuple[ReshadeNet, float | None]:
    """The lobe head of fixture `kind` (LOBE_FIXTURES) from a fixed seed, its last
    convolution drawn with a visible spread and frozen, then `steps` of masked L1 on the
    shaded output for the rest; returns the network and its last-50-step loss."""
    torch.manual_seed(seed)
    head, lobes, domain, amplitude, _ = LOBE_FIXTURES[kind]
    cfg = replace(
        net_config(WIDTHS),
        head=head,
        lobes=lobes,
        deadzone=LOBE_DEADZONE,
        domain=domain,
        amplitude=amplitude,
    )
    net = ReshadeNet(cfg)
    torch.nn.init.normal_(net.decoder.out.weight, std=LOBE_INIT_STD)
    n = len(LOBE_LAYOUT)
    k = n * lobes
    with torch.no_grad():
        net.decoder.out.bias[3:k:n] = LOBE_SHARPNESS_BIAS
        if head == "lobes-slide":
            net.decoder.out.bias[k : k + 3] = SLIDE_FRACTION_RAW_BIAS
        if amplitude == "photo":
            for j in range(lobes):
                net.decoder.out.bias[n * j + 4 : n * j + 7] = PHOTO_SHARE_RAW_BIAS
    net.decoder.out.requires_grad_(False)
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=1e-3)
    losses = []
    for b in training_crops(data, steps, 8, 64, seed):
        pred = net(b["image"], b["disparity"], b["camera"], b["rays"])
        loss = ((pred - b["target"]).abs() * b["mask"]).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    return net.eval(), float(np.mean(losses[-50:])) if losses else None


@torch.no_grad()
def shaded(net: ReshadeNet, lobes: torch.Tensor, base: dict, camera) -> np.ndarray:
    """What the runtime shows for `camera`: the closed form on `lobes`, clamped to [0,1]."""
    return (
        shade_lobes(
            base["image"],
            lobes,
            base["disparity"],
            base["rays"],
            torch.tensor([camera], dtype=torch.float32),
            net.cfg.deadzone,
            domain=net.cfg.domain,
            head=net.cfg.head,
        )
        .clamp(0.0, 1.0)
        .numpy()
    )


def lobe_parity_record(
    net: ReshadeNet, qnet: ReshadeNet, out: Path, height: int, width: int, kind: str = "lobes"
) -> dict:
    """PyTorch's lobes and reshaded images (fp32 network; the weights-only fake-quantised one
    for int8) and how far the closed form on onnxruntime's lobes lands from them."""
    base = parity_inputs(height, width)
    args = (base["image"], base["disparity"], base["rays"])
    with torch.no_grad():
        lobes, qlobes = net.lobes(*args), qnet.lobes(*args)
    cases = []
    refs: dict[str, list[np.ndarray]] = {"fp32": [], "int8": []}
    for cam in LOBE_CAMERAS:
        ref, qref = shaded(net, lobes, base, cam), shaded(net, qlobes, base, cam)
        refs["fp32"].append(ref)
        refs["int8"].append(qref)
        cases.append({"camera": list(cam), "reshaded": _b64(ref), "reshaded_int8": _b64(qref)})
    measured = {}
    for precision in ("fp32", "fp16", "int8"):
        stem = lobe_stem(precision, kind)
        (got,) = run_onnxruntime((out / f"{stem}.onnx").read_bytes(), base)
        worst = mean = 0.0
        for cam, ref in zip(
            LOBE_CAMERAS, refs["int8" if precision == "int8" else "fp32"], strict=True
        ):
            view = shaded(net, torch.from_numpy(got), base, cam)
            worst = max(worst, float(np.abs(view - ref).max()))
            mean = max(mean, float(np.abs(view - ref).mean()))
        measured[precision] = {
            "model": f"{stem}.json",
            "reference": "reshaded_int8" if precision == "int8" else "reshaded",
            "onnxruntime_max_abs": worst,
            "onnxruntime_mean_abs": mean,
            "tolerance": float(f"{max(2 * worst, TOLERANCE_FLOOR[precision]):.2g}"),
        }
    image = base["image"].numpy()
    intrinsics = parity_intrinsics(height, width)
    return {
        "format": "reshader-lobe-parity/1",
        "model": f"{fixture_stem(kind)}-<precision>-lobes",
        "height": height,
        "width": width,
        "head": net.cfg.head,
        "lobes": net.cfg.lobes,
        "deadzone": net.cfg.deadzone,
        "domain": net.cfg.domain,
        "amplitude": net.cfg.amplitude,
        "camera": {
            "hfov_deg": PARITY_HFOV_DEG,
            **intrinsics,
            "pixel_centres": "integer coordinates (OpenCV); cx = (W - 1)/2, cy = (H - 1)/2",
        },
        "input": {
            "generator": "closed form, float32, NCHW (x, y pixel indices; W, H the size)",
            "image": "image[c,y,x] = 0.1 + 0.1*c + 0.2*x/W + 0.5*exp(-((x - 0.4*W)^2 + "
            "(y - 0.45*H)^2) / (2*s^2)), s = 0.15*min(H, W)",
            "disparity": "disparity[y,x] = 0.25 / (1.5 + x/W + y/H)",
            "rays": "rays[:,y,x] = ((x - cx)/fx, (y - cy)/fy, 1) with the camera above",
            "image_sum": float(image.astype(np.float64).sum()),
            "disparity_sum": float(base["disparity"].numpy().astype(np.float64).sum()),
        },
        "outputs": "float32 little-endian, base64, NCHW: lobes [1,C,H,W] (the head's fields) "
        "of the PyTorch fp32 "
        "network; per camera reshaded [1,3,H,W] = clamp(shade_lobes(...), 0, 1) on those lobes "
        "(reshaded) and on the weights-only fake-quantised network's (reshaded_int8)",
        "lobes_fp32": _b64(lobes.numpy()),
        "cases": cases,
        "precisions": measured,
        "camera_dependence": {
            str(list(cam)): {
                "max_abs_change": float(np.abs(ref - image).max()),
                "mean_abs_change": float(np.abs(ref - image).mean()),
            }
            for cam, ref in zip(LOBE_CAMERAS, refs["fp32"], strict=True)
        },
        "int8_vs_fp32_max_abs": max(
            float(np.abs(a - b).max()) for a, b in zip(refs["int8"], refs["fp32"], strict=True)
        ),
    }


def fixture_stem(kind: str) -> str:
    return LOBE_FIXTURES[kind][4] or STEM


def lobe_stem(precision: str, kind: str = "lobes") -> str:
    """The graph's name with the -lobes suffix export adds (int8: weights-only, -wo)."""
    return f"{fixture_stem(kind)}-{'int8-wo' if precision == 'int8' else precision}{LOBES.suffix}"


def make_lobe_fixture(
    out: Path,
    steps: int,
    seed: int,
    examples: int,
    height: int,
    width: int,
    kind: str = "lobes",
):
    t0 = time.time()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        data = write_dataset(Path(tmp) / "synthetic", examples, 64, 64, seed=seed)
        net, loss = train_tiny_lobes(steps, seed, data, kind)
        qnet = quantize_network(copy.deepcopy(net))
        calibrate(qnet, training_crops(data, 8, 8, 64, seed + 1))
        set_input_quantization(qnet, False)  # the weights-only form the runtime ships
        qnet.eval()
        n_examples = len(ReshadeDataset(data))
    wall = round(time.time() - t0, 1)
    command = (
        f"reshader-train fixture --head {kind} --out {out} --steps {steps} --seed {seed} "
        f"--examples {examples} --height {height} --width {width}"
    )
    info = ExportInfo(
        size="fixture",
        training={
            "command": command,
            "data": f"synthetic.write_dataset({examples} examples, 64x64, seed {seed}); "
            f"crops 64, {Augment()}; last conv drawn with std {LOBE_INIT_STD}, sharpness "
            f"bias {LOBE_SHARPNESS_BIAS}"
            + (f", fraction bias {SLIDE_FRACTION_RAW_BIAS}" if kind == "lobes-slide" else "")
            + (f", share bias {PHOTO_SHARE_RAW_BIAS}" if kind == "lobes-photo" else "")
            + ", frozen",
            "feature_network": "none (masked L1 only: a test fixture)"
            if steps
            else "none (not trained: a test fixture)",
            "steps": steps,
            "wall_time_s": wall,
        },
        validation={"train_l1_last50": loss, "train_examples": n_examples},
        source=f"{command} (torch {torch.__version__})",
    )
    for precision, model in (("fp32", net), ("fp16", net), ("int8", qnet)):
        stem = lobe_stem(precision, kind).removesuffix(LOBES.suffix)
        form = "weights" if precision == "int8" else "qdq"
        if precision == "int8":
            quantization = {**SCHEME, "regions": INT8_FORMS[form], "form": form, "method": "ptq"}
            info = replace(info, validation={**info.validation, "quantization": quantization})
        export_precision(model, precision, out, stem, info, False, height, width, int8_form=form)
    record = lobe_parity_record(net, qnet, out, height, width, kind)
    tmp = out / f".{LOBE_PARITY}.tmp"
    tmp.write_text(json.dumps(record, indent=1) + "\n")
    os.replace(tmp, out / LOBE_PARITY)
    return record


def run(args: argparse.Namespace) -> int:
    if args.head != "residual":
        steps = LOBE_STEPS if args.steps is None else args.steps
        record = make_lobe_fixture(
            args.out, steps, args.seed, args.examples, args.height, args.width, args.head
        )
        print(json.dumps({k: record[k] for k in ("precisions", "camera_dependence")}, indent=1))
        return 0
    steps = STEPS if args.steps is None else args.steps
    record = make_fixture(args.out, steps, args.seed, args.examples, args.height, args.width)
    total = sum(p.stat().st_size for p in args.out.iterdir() if p.is_file())
    print(json.dumps({k: record[k] for k in ("precisions", "camera_dependence")}, indent=1))
    print(f"{args.out}: {total / 1024:.0f} KB in {len(list(args.out.iterdir()))} files")
    return 0
