"""Int8 quantisation of the reshading network: fake-quantised convolutions, calibration (the
post-training baseline) and quantisation-aware fine-tuning (`reshader-train quantize`).

Only the convolutions are quantised: per-channel symmetric int8 weights and one per-tensor
asymmetric uint8 quantiser on each convolution's input. LeakyReLU, Resize, Concat, tanh, the
camera MLP and its broadcast stay in float: tract 0.23.9 cannot declutter a dequantised tensor
pushed through the camera features' Expand and has no QLinearLeakyRelu. Exported (see
export.py), each quantiser becomes QuantizeLinear -> DequantizeLinear in front of a Conv whose
weight is an int8 initialiser followed by DequantizeLinear.
"""

from __future__ import annotations

import argparse
import copy
import json
import shlex
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .data import Augment, DatasetError, ReshadeDataset, list_examples
from .model import NetConfig, ReshadeNet
from .train import atomic_write

ACT_QMIN, ACT_QMAX = 0, 255
WEIGHT_QMIN, WEIGHT_QMAX = -128, 127
# Symmetric weights use -127..127 so that zero stays exact and -128 is never produced.
WEIGHT_LEVELS = 127
# Export forms: "qdq" quantises conv inputs and weights (integer convolutions where the engine
# has them); "weights" stores int8 weights only (activations float, a quarter of the file:
# the form shipped for tract, whose integer path is slower still on x86: docs/benchmarks.md).
INT8_FORMS = {
    "qdq": "convolutions only: QDQ on conv inputs (uint8 per tensor) and weights (int8)",
    "weights": "convolution weights only (int8 per channel); activations float",
}
SCHEME = {
    "weights": "int8, per output channel, symmetric (zero point 0)",
    "activations": "uint8, per tensor, asymmetric (min/max observers)",
    "float_ops": [
        "LeakyRelu",
        "x2 upsampling (nearest by Concat+Reshape, fixed depthwise blur)",
        "Concat",
        "Expand",
        "Tanh",
        "camera MLP (Gemm)",
    ],
}
EMA_MOMENTUM = 0.01


class ActQuant(nn.Module):
    """Per-tensor uint8 fake quantisation with a min/max observer (running or moving average)."""

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("lo", torch.tensor(float("inf")))
        self.register_buffer("hi", torch.tensor(float("-inf")))
        self.observing = False
        self.momentum: float | None = None  # None: running min/max, else moving average

    def calibrated(self) -> bool:
        return bool(torch.isfinite(self.lo) and torch.isfinite(self.hi))

    @torch.no_grad()
    def observe(self, x: torch.Tensor) -> None:
        lo, hi = x.amin(), x.amax()
        if self.momentum is None or not self.calibrated():
            self.lo.copy_(torch.minimum(self.lo, lo))
            self.hi.copy_(torch.maximum(self.hi, hi))
        else:
            self.lo.lerp_(lo, self.momentum)
            self.hi.lerp_(hi, self.momentum)

    def qparams(self) -> tuple[torch.Tensor, torch.Tensor]:
        # The range always holds 0 so that zero padding and LeakyReLU's zero are exact.
        lo = torch.clamp(self.lo, max=0.0)
        hi = torch.clamp(self.hi, min=0.0)
        scale = torch.clamp((hi - lo) / (ACT_QMAX - ACT_QMIN), min=1e-8)
        zero = torch.clamp(torch.round(-lo / scale), ACT_QMIN, ACT_QMAX).to(torch.int32)
        return scale.reshape(1), zero.reshape(1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.observing:
            self.observe(x)
        scale, zero = self.qparams()
        return torch.fake_quantize_per_tensor_affine(x, scale, zero, ACT_QMIN, ACT_QMAX)


class QuantConv2d(nn.Module):
    """A Conv2d whose input and weights are fake-quantised (when `enabled`)."""

    def __init__(self, conv: nn.Conv2d) -> None:
        super().__init__()
        self.conv = conv
        self.act = ActQuant()
        self.enabled = True
        self.quantize_input = True  # False: weight-only (the "weights" export form)

    def weight_qparams(self) -> tuple[torch.Tensor, torch.Tensor]:
        absmax = self.conv.weight.detach().abs().amax(dim=(1, 2, 3))
        scale = torch.clamp(absmax / WEIGHT_LEVELS, min=1e-12)
        return scale, torch.zeros_like(scale, dtype=torch.int32)

    def quantized_weight(self) -> torch.Tensor:
        scale, zero = self.weight_qparams()
        return torch.fake_quantize_per_channel_affine(
            self.conv.weight, scale, zero, 0, WEIGHT_QMIN, WEIGHT_QMAX
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            if self.act.observing:
                self.act.observe(x)
            return self.conv(x)
        x = self.act(x) if self.quantize_input else x
        return self.conv._conv_forward(x, self.quantized_weight(), self.conv.bias)


def quantize_network(net: ReshadeNet) -> ReshadeNet:
    """Wraps every Conv2d of `net` (in place) in a QuantConv2d; returns `net`."""
    for module in list(net.modules()):
        for name, child in module.named_children():
            if isinstance(child, nn.Conv2d):
                setattr(module, name, QuantConv2d(child))
    return net


def quant_convs(net: nn.Module) -> list[QuantConv2d]:
    return [m for m in net.modules() if isinstance(m, QuantConv2d)]


def is_quantized(net: nn.Module) -> bool:
    return bool(quant_convs(net))


def set_mode(net: nn.Module, *, enabled: bool, observing: bool, momentum: float | None) -> None:
    for q in quant_convs(net):
        q.enabled = enabled
        q.act.observing = observing
        q.act.momentum = momentum


def set_input_quantization(net: nn.Module, on: bool) -> None:
    for q in quant_convs(net):
        q.quantize_input = on


def check_calibrated(net: nn.Module) -> None:
    missing = [i for i, q in enumerate(quant_convs(net)) if not q.act.calibrated()]
    if missing:
        raise ValueError(f"quantised convolutions {missing} have no calibrated input range")


@torch.no_grad()
def calibrate(net: ReshadeNet, batches) -> int:
    """Post-training calibration: running min/max of every conv input over `batches`
    (dicts with image, disparity, camera). Returns the number of samples seen."""
    was_training = net.training
    net.eval()
    set_mode(net, enabled=False, observing=True, momentum=None)
    seen = 0
    for b in batches:
        net(b["image"], b["disparity"], b["camera"], b["rays"])
        seen += b["image"].shape[0]
    set_mode(net, enabled=True, observing=False, momentum=None)
    net.train(was_training)
    if seen == 0:
        raise ValueError("calibration needs at least one batch")
    check_calibrated(net)
    return seen


def training_crops(
    roots: str | Path | list[Path],
    count: int,
    batch_size: int,
    crop: int,
    seed: int,
    augment: Augment | None = None,
) -> Iterator[dict[str, torch.Tensor]]:
    """`count` batches of augmented training crops from a dataset folder, or the pooled
    examples of several, reproducible by seed."""
    if isinstance(roots, (str, Path)):
        roots = [roots]
    pooled = [f for root in roots for f in list_examples(root)]
    dataset = ReshadeDataset(pooled, crop=crop, augment=augment or Augment())
    torch.manual_seed(seed)  # the dataset seeds its augmentation generator from torch
    order = np.random.default_rng(seed).permutation(max(len(dataset), count * batch_size))
    for i in range(count):
        idx = order[i * batch_size : (i + 1) * batch_size] % len(dataset)
        samples = [dataset[int(j)] for j in idx]
        yield {k: torch.stack([s[k] for s in samples]) for k in samples[0]}


def build_quantized(cfg: NetConfig, state: dict) -> ReshadeNet:
    net = quantize_network(ReshadeNet(cfg))
    net.load_state_dict(state)
    set_mode(net, enabled=True, observing=False, momentum=None)
    check_calibrated(net)
    return net.eval()


def load_any_checkpoint(path: Path) -> tuple[ReshadeNet, dict]:
    """A float training checkpoint or a quantised one written by `quantize` (evaluation mode)."""
    from .evaluate import model_from_checkpoint, read_checkpoint

    ckpt = read_checkpoint(path)
    if "quantization" not in ckpt:
        return model_from_checkpoint(ckpt), ckpt
    try:
        net = build_quantized(NetConfig.from_json(ckpt["net_config"]), ckpt["model"])
    except (KeyError, RuntimeError) as err:
        raise ValueError(f"{path}: unreadable quantised checkpoint ({err})") from err
    return net, ckpt


def command_line(command: str, args: argparse.Namespace, positional: tuple[str, ...] = ()) -> str:
    """The `reshader-train` command line equivalent to parsed `args` (for provenance)."""
    parts = ["reshader-train", command, *(str(getattr(args, p)) for p in positional)]
    for key, value in vars(args).items():
        if key.startswith("_") or key == "command" or key in positional:
            continue
        if value is None or value is False:
            continue
        flag = f"--{key.replace('_', '-')}"
        if value is True:
            parts.append(flag)
        elif isinstance(value, (list, tuple)):
            parts += [flag, *map(str, value)]
        else:
            parts += [flag, str(value)]
    return shlex.join(parts)


# --- `reshader-train quantize`: quantisation-aware fine-tuning --------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("checkpoint", type=Path, help="fp32 training checkpoint (.pt)")
    p.add_argument(
        "--data",
        type=Path,
        nargs="+",
        required=True,
        help="training dataset folder(s), their examples pooled (the families a model was "
        "trained on: the crops should look like what it will see)",
    )
    p.add_argument(
        "--val-data",
        type=Path,
        nargs="+",
        help="held-out folder(s): PSNR and SSIM of the input, fp32, fp16, PTQ and QAT",
    )
    p.add_argument("--out", type=Path, required=True, help="quantised checkpoint to write (.pt)")
    p.add_argument("--steps", type=int, default=2000, help="fine-tuning steps")
    p.add_argument("--lr", type=float, default=1e-5)
    p.add_argument("--batch-size", type=int, default=4)
    p.add_argument("--crop", type=int, default=128)
    p.add_argument("--calib-batches", type=int, default=16, help="batches for the PTQ start")
    p.add_argument(
        "--freeze-observers",
        type=float,
        default=0.5,
        help="fraction of --steps after which activation ranges stop moving",
    )
    p.add_argument(
        "--form",
        choices=("qdq", "weights"),
        default="qdq",
        help="what the fine-tuning quantises: qdq (conv inputs and weights, for engines with "
        "int8 convolutions) or weights (int8 weights, float activations: the form shipped "
        "for tract); export with the same --int8-form",
    )
    p.add_argument(
        "--target",
        choices=("fp32", "truth"),
        default="fp32",
        help="what the quantised network learns to match: fp32 (the float checkpoint's own "
        "output on each crop: distillation, which keeps what the float network learned and "
        "only undoes what quantisation changed) or truth (the rendered reshaded image, as "
        "training does; from a mean of checkpoints even lr 2e-6 loses held-out PSNR)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    p.add_argument("--val-examples", type=int, default=16, help="first N views of each folder")
    p.add_argument(
        "--loss-weights",
        help="PIXEL,VGG,STYLE as for train (default: the weights the checkpoint was trained with)",
    )
    p.add_argument("--feature-net", default="auto", help="as for train (auto|vgg19|hed-vgg16)")
    p.add_argument("--vgg-weights", help="torchvision VGG-19 state dict")
    p.add_argument("--feature-precision", choices=("auto", "float32", "bfloat16"), default="auto")
    p.add_argument("--log-every", type=int, default=50)


def held_out_samples(roots: list[Path], count: int) -> list[dict[str, torch.Tensor]]:
    """The first `count` views of each folder, decoded once for every precision's scores."""
    samples = []
    for root in roots:
        val = ReshadeDataset(root, crop=None, augment=None)
        samples += [val[i] for i in range(min(count, len(val)))]
    return samples


@torch.no_grad()
def held_out_scores(
    net: ReshadeNet, samples: list[dict[str, torch.Tensor]], half: bool = False
) -> dict[str, float]:
    """Mean PSNR and SSIM (masked, evaluation tone mapping) of the input and of `net` on the
    held-out `samples`; `half` runs the network in fp16, as the fp16 export."""
    from .evaluate import masked_psnr, masked_ssim, reshade

    net.eval()
    model = copy.deepcopy(net).half() if half else net
    scores: dict[str, list[float]] = {"psnr_input": [], "psnr": [], "ssim_input": [], "ssim": []}
    for s in samples:
        inputs = (s["image"], s["disparity"], s["camera"], s["rays"])
        ours = reshade(model, *(t.half() if half else t for t in inputs)).float()
        scores["psnr_input"].append(masked_psnr(s["image"], s["target"], s["mask"]))
        scores["psnr"].append(masked_psnr(ours, s["target"], s["mask"]))
        scores["ssim_input"].append(masked_ssim(s["image"], s["target"], s["mask"]))
        scores["ssim"].append(masked_ssim(ours, s["target"], s["mask"]))
    return {**{k: float(np.mean(v)) for k, v in scores.items()}, "count": len(samples)}


def int8_scores(
    net: ReshadeNet, samples: list[dict[str, torch.Tensor]], method: str
) -> dict[str, dict]:
    """Held-out scores of both exported int8 forms: `qdq` (conv inputs and weights
    quantised, as trained) and `weights` (int8 weights, float activations; the form
    shipped for tract)."""
    weights_only = copy.deepcopy(net)
    set_input_quantization(weights_only, False)
    return {
        f"int8_{method}": held_out_scores(net, samples),
        f"int8_{method}_weights": held_out_scores(weights_only, samples),
    }


def augment_of(ckpt: dict) -> Augment:
    """The augmentation the checkpoint was trained with, so that QAT sees the same crops
    through the same tone curves (checkpoints from before `--exposure` and `--gamma`
    existed were trained with the defaults)."""
    args = ckpt.get("args", {})
    default = Augment()
    return Augment(
        exposure=tuple(args.get("exposure", default.exposure)),
        gamma=tuple(args.get("gamma", default.gamma)),
        dihedral=bool(args.get("dihedral", False)),
    )


def qat_target(float_net: ReshadeNet, batch: dict[str, torch.Tensor], target: str) -> torch.Tensor:
    if target == "truth":
        return batch["target"]
    with torch.no_grad():
        return float_net(batch["image"], batch["disparity"], batch["camera"], batch["rays"])


def qat(args: argparse.Namespace) -> dict:
    from .evaluate import load_checkpoint_model
    from .losses import LossWeights, make_loss

    if args.threads > 0:
        torch.set_num_threads(args.threads)
    t0 = time.time()
    float_net, base = load_checkpoint_model(args.checkpoint)
    net = quantize_network(copy.deepcopy(float_net))
    calibrate(
        net, training_crops(args.data, args.calib_batches, args.batch_size, args.crop, args.seed)
    )
    validation: dict[str, dict] = {}
    held_out = held_out_samples(args.val_data or [], args.val_examples)
    if held_out:
        validation["fp32"] = held_out_scores(float_net, held_out)
        validation["fp16"] = held_out_scores(float_net, held_out, True)
        validation.update(int8_scores(net, held_out, "ptq"))

    weights = LossWeights.parse(args.loss_weights or base.get("loss_weights") or str(LossWeights()))
    criterion = make_loss(
        weights,
        args.feature_net,
        args.vgg_weights,
        args.feature_precision,
        torch.device("cpu"),
        base.get("pixel_loss", "l1"),
    )
    if base.get("feature_net") and base["feature_net"] != criterion.ident:
        print(
            f"warning: {args.checkpoint} was trained with {base['feature_net']}; fine-tuning "
            f"with {criterion.ident}",
            file=sys.stderr,
        )
    # Calibration above still records the activation ranges, so that either form exports.
    set_input_quantization(net, args.form == "qdq")
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    freeze_at = int(args.freeze_observers * args.steps)
    crops = training_crops(
        args.data, args.steps, args.batch_size, args.crop, args.seed + 1, augment_of(base)
    )
    net.train()
    for step, b in enumerate(crops):
        observing = step < freeze_at
        set_mode(net, enabled=True, observing=observing, momentum=EMA_MOMENTUM)
        pred = net(b["image"], b["disparity"], b["camera"], b["rays"])
        loss, parts = criterion(pred, qat_target(float_net, b, args.target), b["mask"], b["image"])
        if not torch.isfinite(loss):
            raise FloatingPointError(f"QAT loss is {float(loss)} at step {step}: {parts}")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if (step + 1) % args.log_every == 0 or step + 1 == args.steps:
            print(f"qat step {step + 1}/{args.steps} loss {parts['loss']:.4f}", file=sys.stderr)
    set_mode(net, enabled=True, observing=False, momentum=None)
    set_input_quantization(net, True)
    net.eval()
    if held_out:
        validation.update(int8_scores(net, held_out, "qat"))
    return {
        "model": net.state_dict(),
        "net_config": net.cfg.to_json(),
        "quantization": {
            **SCHEME,
            "method": "qat",
            "qat_form": args.form,
            "qat_target": args.target,
            "calibration_batches": args.calib_batches,
        },
        "step": int(base.get("step", 0)) + args.steps,
        "feature_net": criterion.ident,
        "loss_weights": str(weights),
        "pixel_loss": criterion.pixel,
        "args": base.get("args", {}),
        "base_checkpoint": str(args.checkpoint.resolve()),
        # Set when the base was rebuilt by `import` (it has no run folder to read them from).
        "base_command": base.get("command"),
        "base_wall_time_s": base.get("wall_time_s"),
        "base_step": base.get("step"),
        "qat_command": command_line("quantize", args, ("checkpoint",)),
        "qat_steps": args.steps,
        "qat_wall_time_s": round(time.time() - t0, 1),
        "qat_data": " ".join(str(d.resolve()) for d in args.data),
        "validation": validation,
    }


def run(args: argparse.Namespace) -> int:
    from .features import FeatureNetError

    try:
        state = qat(args)
    except (DatasetError, FeatureNetError, FileNotFoundError, ValueError) as err:
        print(f"quantize: {err}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, lambda tmp: torch.save(state, tmp))
    print(json.dumps(state["validation"], indent=2))
    print(f"quantised checkpoint: {args.out}")
    return 0
