"""`reshader-train train`: the paper's training recipe (section 3.5), on one CPU or many GPUs.

The same command runs single-process, or under `torchrun` with DistributedDataParallel
(gloo on CPU, nccl on GPU; DistributedSampler shards the data). The run directory holds
config.json, log.csv (training losses), val.csv (held-out PSNR), and checkpoint.pt, which
a rerun of the same command resumes from.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import random
import shlex
import shutil
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader, DistributedSampler

from .data import Augment, DatasetError, ReshadeDataset, list_examples, teacher_settings
from .evaluate import masked_psnr, reshade
from .features import CHOICES, FeatureNetError
from .losses import (
    FRACTION_DISTANCES,
    LossWeights,
    ReshadeLoss,
    field_loss,
    make_loss,
    multi_target_loss,
    pixel_loss,
)
from .model import (
    HEADS,
    LOBE_AMPLITUDES,
    LOBE_DOMAINS,
    NetConfig,
    ReshadeNet,
    count_parameters,
    net_config,
)
from .onnx_weights import load_onnx_weights
from .tonemap import EVAL_EXPOSURE, EVAL_GAMMA, EXPOSURE_RANGE, GAMMA_RANGE

CHECKPOINT = "checkpoint.pt"
LOG_FIELDS = (
    "step",
    "lr",
    "loss",
    "pixel",
    "vgg",
    "style",
    "examples",
    "steps_per_s",
    "elapsed_s",
    "teacher",
)
VAL_FIELDS = ("step", "examples", "psnr_input", "psnr_ours", "gain_db")


def checked_pixel_loss(name: str) -> str:
    try:
        pixel_loss(name)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return name


def _range(text: str) -> tuple[float, float]:
    """ "LO,HI" (or one value for both) as a pair of positive floats, LO <= HI."""
    parts = text.split(",")
    try:
        lo, hi = (float(v) for v in (parts * 2 if len(parts) == 1 else parts))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected LO,HI (two numbers)") from None
    if not 0.0 < lo <= hi:
        raise argparse.ArgumentTypeError(f"{text!r}: need 0 < LO <= HI")
    return lo, hi


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--data",
        type=Path,
        nargs="+",
        required=True,
        help="training dataset folder(s); their examples are pooled, and a folder given N "
        "times is drawn N times as often (e.g. a small path-traced set beside a large "
        "analytic one)",
    )
    p.add_argument("--val-data", type=Path, help="held-out folder for the periodic PSNR check")
    p.add_argument("--run-dir", type=Path, required=True, help="config, logs and checkpoints")
    p.add_argument("--size", default="lite", help="full | lite | six comma-separated widths")
    p.add_argument(
        "--head",
        choices=HEADS,
        default="residual",
        help="output head: residual (the paper's: image + tanh(conv)), camera-linear (the "
        "last conv predicts the change per unit of camera offset, contracted with the offset), "
        "flow (camera-linear plus a predicted shift times the photo's gradient) or lobes (no "
        "camera input: per pixel --lobes spherical Gaussians whose change between the input "
        "and the novel direction is added to the photo; one network run serves every view) or "
        "lobes-flow (lobes plus the photo's gradient times a predicted shift per radian of view "
        "direction change; training experiments only, not exported) or lobes-slide (lobes plus "
        "a layer of reflected light, a fraction of the photo per pixel, that slides with the "
        "parallax of its own predicted disparity; exported and evaluated by the runtime)",
    )
    p.add_argument("--lobes", type=int, default=2, help="lobes per pixel of the lobes head")
    p.add_argument(
        "--lobe-domain",
        choices=LOBE_DOMAINS,
        default="display",
        help="where the lobe heads add their change to the photo: the display encoding "
        "(exported) or linear radiance, the photo decoded with gamma 2.2 and encoded again "
        "(training experiments only, not exported)",
    )
    p.add_argument(
        "--lobe-amplitude",
        choices=LOBE_AMPLITUDES,
        default="free",
        help="where the lobes head's amplitudes come from: free (the network gives them) or "
        "photo (with --lobe-domain linear-clamped: the network gives each lobe's share of its "
        "pixel's light at the photo's view, and the photo sets the scale)",
    )
    p.add_argument(
        "--film",
        action="store_true",
        help="the camera also gives a gain and a shift per channel at every decoder level, "
        "not only features at the bottleneck (starts at zero: with --init-from and "
        "--init-partial a network without it is continued exactly)",
    )
    p.add_argument(
        "--deadzone",
        type=float,
        default=0.0,
        help="residual magnitudes up to this become exactly 0 (output units; 0.004 is about "
        "one 8-bit level), so that views whose shading does not change stay the photo",
    )
    p.add_argument("--steps", type=int, default=20000, help="total optimiser steps")
    p.add_argument("--batch-size", type=int, default=4, help="per process")
    p.add_argument("--crop", type=int, default=128, help="random square crop (paper: 384)")
    p.add_argument(
        "--dihedral",
        action="store_true",
        help="augment with all eight symmetries of the square crop (x and y mirrors and the "
        "transpose, camera moved to match) instead of the x mirror alone: four times the "
        "geometric variety from the same renders",
    )
    p.add_argument(
        "--exposure",
        type=_range,
        default=EXPOSURE_RANGE,
        metavar="LO,HI",
        help="exposure of the tone curve each sample is shown through, log-uniform in LO,HI "
        f"(default {EXPOSURE_RANGE[0]:g},{EXPOSURE_RANGE[1]:g}, the paper's; the evaluation uses "
        f"{EVAL_EXPOSURE:g}; LO = HI: that exposure alone)",
    )
    p.add_argument(
        "--gamma",
        type=_range,
        default=GAMMA_RANGE,
        metavar="LO,HI",
        help=f"gamma of that tone curve, uniform in LO,HI (default {GAMMA_RANGE[0]:g},"
        f"{GAMMA_RANGE[1]:g}, the paper's; the evaluation and sRGB photos: about {EVAL_GAMMA:g})",
    )
    p.add_argument(
        "--targets-per-example",
        type=int,
        default=1,
        help="reshaded targets each sample is supervised with (render --targets): one network "
        "pass per photo (for the lobe heads; the camera-conditioned heads rerun only their "
        "decoder) serves N cameras, and the loss is the mean over them. An example with more "
        "targets gives N distinct ones at random; one with fewer gives all it has, and the "
        "rest of its N are padding that the loss leaves out (default 1)",
    )
    p.add_argument(
        "--teacher",
        type=Path,
        help="a folder of fields fitted per training example (`reshader-train teacher`, same "
        "--head and --lobes): the lobe head is also told those fields, pixel by pixel, "
        "instead of finding them through the rendered views alone",
    )
    p.add_argument(
        "--teacher-weight",
        type=float,
        default=1.0,
        help="weight of the fitted-field term against the loss on the views (default 1)",
    )
    p.add_argument(
        "--teacher-decay",
        type=int,
        default=0,
        metavar="STEPS",
        help="the fitted-field weight falls linearly from --teacher-weight to 0 over the "
        "first STEPS steps, so that the fields guide the start and the views decide the "
        "rest (default 0: the weight stays)",
    )
    p.add_argument(
        "--teacher-distance",
        default="l1",
        choices=FRACTION_DISTANCES,
        help="how the sliding layer's fraction is compared with the teacher's: l1 (the "
        "median's loss, which under-slides where the photo leaves doubt) or squared (the "
        "mean's, scaled to l1's size for a network that slides nothing) (default l1)",
    )
    p.add_argument(
        "--teacher-balance",
        action="store_true",
        help="lobe amplitudes in the linear-clamped domain: the teacher's lit and unlit "
        "pixels weigh equally in the fitted-field loss (default: every pixel the same, "
        "which lets the unlit majority outvote the lit pixels)",
    )
    p.add_argument(
        "--teacher-share",
        action="store_true",
        help="lobe amplitudes in the linear-clamped domain: compare each lobe with its "
        "teacher's by the share of the pixel's light it holds at the photo's view (squared), "
        "not by the log of its amplitude; where the photo leaves doubt, the network then "
        "settles on the mean share rather than the mean log, which the unlit majority drags "
        "to the floor",
    )
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--lr-final", type=float, default=1e-5)
    p.add_argument(
        "--head-lr-scale",
        type=float,
        default=1.0,
        help="the output conv learns at this multiple of the learning rate: the lobe heads' "
        "fields (sharpness, axes, amplitudes) start at a fixed point and leave it slowly",
    )
    p.add_argument(
        "--lr-drop", type=float, default=0.6, help="fraction of --steps at --lr (paper: 300k/500k)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1, help="data loader processes per rank")
    p.add_argument("--threads", type=int, default=0, help="torch threads per rank (0: default)")
    p.add_argument("--device", default="auto", help="auto | cpu | cuda")
    p.add_argument(
        "--bf16",
        action="store_true",
        help="run the network's forward pass in bfloat16 (torch.autocast): about twice the "
        "steps per second on a CPU with AMX or AVX-512 BF16 (and on recent GPUs); the "
        "weights, the optimiser, the loss and validation stay float32",
    )
    p.add_argument(
        "--channels-last",
        action="store_true",
        help="lay the network's activations out channels-last, the layout oneDNN's CPU "
        "kernels prefer (a further ~1.2x with --bf16 on one CPU thread)",
    )
    p.add_argument(
        "--loss-weights",
        default=str(LossWeights()),
        help="PIXEL,VGG,STYLE weights (default: the paper's 0.1,0.01,1; with VGG and STYLE 0 "
        "no perceptual network runs: about 5x faster steps on a CPU)",
    )
    p.add_argument(
        "--pixel-loss",
        type=checked_pixel_loss,
        default="l1",
        help="the pixel term: l1 (the paper's), l2 (mean squared error), psnr (minus the "
        "per-crop PSNR, the evaluation's measure) or rel-l2 (per crop, the squared error over "
        "how much the truth differs from the input: the evaluation's emphasis, fixed by the "
        "data); rel-l2:DB floors that change at DB instead of 45 (higher: unchanged views "
        "weigh more)",
    )
    p.add_argument("--feature-net", choices=CHOICES, default="auto")
    p.add_argument("--vgg-weights", help="torchvision VGG-19 state dict (the paper's network)")
    p.add_argument(
        "--feature-precision",
        choices=("auto", "float32", "bfloat16"),
        default="auto",
        help="perceptual network precision (auto: bfloat16 where the device runs it fast)",
    )
    p.add_argument(
        "--init-from",
        type=Path,
        nargs="+",
        help="start from the weights of exported fp32 ONNX files (e.g. a shipped model's "
        "encoder and decoder) instead of random ones; ignored when the run resumes",
    )
    p.add_argument(
        "--init-partial",
        action="store_true",
        help="with --init-from: copy only the parameters whose name and shape match (e.g. a "
        "lobes network from a residual model's encoder and decoder); the rest start afresh",
    )
    p.add_argument(
        "--init-widen",
        action="store_true",
        help="with --init-from: the files are a narrower network of the same head and depth "
        "(e.g. the shipped lite pair for --size wide); its weights are embedded so that the "
        "wider network starts out computing the same image, its added channels unused",
    )
    p.add_argument("--checkpoint-every", type=int, default=500)
    p.add_argument(
        "--keep-checkpoints",
        action="store_true",
        help="also keep each checkpoint as checkpoint-<step>.pt (for `reshader-train average`)",
    )
    p.add_argument("--log-every", type=int, default=20)
    p.add_argument("--val-every", type=int, default=1000)
    p.add_argument("--val-examples", type=int, default=16)
    p.add_argument("--limit", type=int, help="use only the first N training examples")
    p.add_argument("--no-cache", action="store_true", help="decode EXRs every time")
    p.add_argument(
        "--rescan",
        action="store_true",
        help="re-list the datasets (training: every epoch; validation: until it has "
        "--val-examples) to use examples rendered meanwhile",
    )
    p.add_argument("--no-progress", action="store_true", help="plain log lines instead of tqdm")


def lr_at(step: int, args: argparse.Namespace) -> float:
    return args.lr if step < int(args.lr_drop * args.steps) else args.lr_final


def teacher_weight_at(step: int, args: argparse.Namespace) -> float:
    if args.teacher_decay <= 0:
        return args.teacher_weight
    return args.teacher_weight * max(0.0, 1.0 - step / args.teacher_decay)


@dataclass
class Dist:
    rank: int
    world: int
    device: torch.device

    @property
    def main(self) -> bool:
        return self.rank == 0


def setup_distributed(device: str) -> Dist:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    dev = torch.device(f"cuda:{local}" if device == "cuda" else device)
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    if world > 1 and not dist.is_initialized():
        dist.init_process_group(backend="nccl" if dev.type == "cuda" else "gloo")
    return Dist(rank, world, dev)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % (2**32))
    torch.manual_seed(seed)


def atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    write(tmp)
    os.replace(tmp, path)


def append_csv(path: Path, fields: tuple[str, ...], row: dict) -> None:
    """Appends `row` (columns it lacks left blank) to a file with `fields` as its header."""
    new = not path.exists()
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        if new:
            w.writeheader()
        w.writerow({k: row.get(k, "") for k in fields})


def _write_csv(path: Path, fields, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, restval="", extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)


def truncate_csv(path: Path, step: int, fields: tuple[str, ...]) -> None:
    """Drop rows logged after `step`: a resumed run logs those steps again. The file is
    rewritten with `fields` as its header, so that a log an older version wrote with fewer
    columns takes this version's rows (its own rows blank in the new columns)."""
    if not path.exists():
        return
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if int(r["step"]) <= step]

    atomic_write(path, lambda tmp: _write_csv(tmp, fields, rows))


def load_resume(run_dir: Path, cfg: NetConfig, device: torch.device) -> dict | None:
    path = run_dir / CHECKPOINT
    if not path.exists():
        return None
    ckpt = torch.load(path, map_location=device, weights_only=False)
    if NetConfig.from_json(ckpt["net_config"]) != cfg:
        raise ValueError(
            f"{path}: was trained with network {ckpt['net_config']}, not {cfg.to_json()}; "
            "use another --run-dir or the same --size"
        )
    return ckpt


def save_checkpoint(
    run_dir: Path, net: ReshadeNet, opt, step: int, meta: dict, keep: bool = False
) -> None:
    state = {
        "model": net.state_dict(),
        "optimizer": opt.state_dict(),
        "step": step,
        "net_config": net.cfg.to_json(),
        **meta,
    }
    atomic_write(run_dir / CHECKPOINT, lambda tmp: torch.save(state, tmp))
    if keep:
        shutil.copyfile(run_dir / CHECKPOINT, run_dir / f"checkpoint-{step}.pt")


@torch.no_grad()
def validate(net: ReshadeNet, val: ReshadeDataset, count: int, device: torch.device) -> dict:
    """PSNR on each example's first target (whatever --targets-per-example), so that the
    numbers stay comparable between runs."""
    net.eval()
    pin, pout = [], []
    for i in range(min(count, len(val))):
        s = {k: v.to(device) for k, v in val[i].items()}
        ours = reshade(net, s["image"], s["disparity"], s["camera"], s["rays"])
        pin.append(masked_psnr(s["image"], s["target"], s["mask"]))
        pout.append(masked_psnr(ours, s["target"], s["mask"]))
    net.train()
    return {
        "examples": len(pin),
        "psnr_input": float(np.mean(pin)),
        "psnr_ours": float(np.mean(pout)),
        "gain_db": float(np.mean(np.subtract(pout, pin))),
    }


def shared_example_list(args: argparse.Namespace, d: Dist) -> list[Path]:
    """Rank 0's listing of the training examples, so that every rank shards the same list."""
    pooled = [f for root in args.data for f in list_examples(root)]
    folders = pooled[: args.limit] if d.main else []
    if d.world > 1:
        box = [folders]
        dist.broadcast_object_list(box, src=0)
        folders = box[0]
    return folders


def make_loader(
    args: argparse.Namespace, d: Dist, folders: list[Path], previous: ReshadeDataset | None = None
):
    # Loader workers fill their own caches, which die with them; only examples decoded in
    # this process (--workers 0) can be carried over to the re-listed dataset.
    reuse = previous if args.workers == 0 else None
    dataset = ReshadeDataset(
        folders,
        crop=args.crop,
        augment=Augment(exposure=args.exposure, gamma=args.gamma, dihedral=args.dihedral),
        cache=not args.no_cache,
        reuse=reuse,
        targets=args.targets_per_example,
        teacher=args.teacher,
    )
    sampler = DistributedSampler(
        dataset, num_replicas=d.world, rank=d.rank, shuffle=True, seed=args.seed, drop_last=True
    )
    if len(sampler) < args.batch_size:
        raise DatasetError(
            f"{', '.join(map(str, args.data))}: {len(dataset)} examples give "
            f"{len(sampler)} per process, fewer than --batch-size {args.batch_size}"
        )
    loader = DataLoader(
        dataset,
        batch_size=args.batch_size,
        sampler=sampler,
        drop_last=True,
        num_workers=args.workers,
        persistent_workers=args.workers > 0,
        pin_memory=d.device.type == "cuda",
    )
    return dataset, sampler, loader


def _reduce_mean(parts: dict[str, float], d: Dist) -> dict[str, float]:
    if d.world == 1:
        return parts
    keys = sorted(parts)
    t = torch.tensor([parts[k] for k in keys], dtype=torch.float64, device=d.device)
    dist.all_reduce(t)
    return {k: float(v) / d.world for k, v in zip(keys, t.tolist(), strict=True)}


class RunLog:
    """Rank 0's record of a run: log.csv, val.csv, the progress bar (or plain lines)."""

    def __init__(self, args: argparse.Namespace, d: Dist, step: int) -> None:
        self.args, self.d = args, d
        self.t0 = self.t_last = time.time()
        self.step_last = step
        self.progress = None
        if d.main and not args.no_progress:
            from tqdm import tqdm

            self.progress = tqdm(total=args.steps, initial=step, dynamic_ncols=True, smoothing=0.05)

    def step(self, step: int, parts: dict[str, float], lr: float, examples: int) -> None:
        if step % self.args.log_every == 0 or step == self.args.steps:
            parts = _reduce_mean(parts, self.d)
            if self.d.main:
                self._write(step, parts, lr, examples)
        if self.progress is not None:
            self.progress.update(1)
            self.progress.set_postfix(loss=f"{parts['loss']:.4f}", lr=f"{lr:.0e}")

    def _write(self, step: int, parts: dict[str, float], lr: float, examples: int) -> None:
        now = time.time()
        rate = (step - self.step_last) / max(now - self.t_last, 1e-9)
        self.t_last, self.step_last = now, step
        row = {**parts, "step": step, "lr": lr, "examples": examples}
        row.update(steps_per_s=round(rate, 4), elapsed_s=round(now - self.t0, 1))
        append_csv(self.args.run_dir / "log.csv", LOG_FIELDS, row)
        if self.progress is None:
            print(
                f"step {step}/{self.args.steps} loss {parts['loss']:.4f} ({rate:.2f} steps/s)",
                file=sys.stderr,
            )

    def validation(self, step: int, v: dict) -> None:
        append_csv(self.args.run_dir / "val.csv", VAL_FIELDS, {**v, "step": step})
        message = (
            f"step {step}: val PSNR input {v['psnr_input']:.2f} ours "
            f"{v['psnr_ours']:.2f} ({v['gain_db']:+.2f} dB)"
        )
        if self.progress is not None:
            self.progress.write(message)
        else:
            print(message, file=sys.stderr)

    def close(self) -> None:
        if self.progress is not None:
            self.progress.close()


def make_criterion(args: argparse.Namespace, d: Dist) -> ReshadeLoss:
    weights = LossWeights.parse(args.loss_weights)
    return make_loss(
        weights,
        args.feature_net,
        args.vgg_weights,
        args.feature_precision,
        d.device,
        args.pixel_loss,
    )


def restore(run_dir: Path, net: ReshadeNet, opt, feature_ident: str, d: Dist) -> int:
    """Loads checkpoint.pt when there is one; returns the step to continue from."""
    ckpt = load_resume(run_dir, net.cfg, d.device)
    if ckpt is None:
        return 0
    net.load_state_dict(ckpt["model"])
    opt.load_state_dict(ckpt["optimizer"])
    if ckpt.get("feature_net") != feature_ident and d.main:
        print(
            f"warning: resuming a run trained with {ckpt.get('feature_net')} using {feature_ident}",
            file=sys.stderr,
        )
    return int(ckpt["step"])


def write_config(args: argparse.Namespace, d: Dist, net: ReshadeNet, meta: dict, step: int):
    """config.json: this invocation's settings, plus every earlier invocation's command."""
    path = args.run_dir / "config.json"
    history = json.loads(path.read_text()).get("history", []) if path.exists() else []
    command = " ".join(shlex.quote(a) for a in sys.argv)
    history.append(
        {"command": command, "from_step": step, "started": time.strftime("%FT%TZ", time.gmtime())}
    )
    config = {
        **meta,
        "command": command,
        "net_config": net.cfg.to_json(),
        "parameters": count_parameters(net),
        "resumed_from_step": step,
        "torch": torch.__version__,
        "device": str(d.device),
        "global_batch": args.batch_size * d.world,
        "history": history,
    }
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(config, indent=2)))


def initialise(net: ReshadeNet, args: argparse.Namespace) -> int:
    """Weights from --init-from's ONNX files, as they are or (--init-widen) embedded."""
    if not args.init_widen:
        return load_onnx_weights(net, args.init_from, partial=args.init_partial)
    from .from_onnx import exported_network
    from .widen import widen_into

    narrow, _ = exported_network(args.init_from, "--init-from", net.cfg.deadzone)
    return widen_into(net, narrow)


def param_groups(net: ReshadeNet, head_lr_scale: float) -> list[dict]:
    """One group, or (with a head learning-rate scale) the output conv in a second group
    that carries its scale; a checkpoint resumes with the grouping it was saved with."""
    if head_lr_scale == 1.0:
        return [{"params": list(net.parameters())}]
    head = {id(p) for p in net.decoder.out.parameters()}
    rest = [p for p in net.parameters() if id(p) not in head]
    return [
        {"params": rest},
        {"params": list(net.decoder.out.parameters()), "lr_scale": head_lr_scale},
    ]


def check_teacher(folder: Path, cfg: NetConfig) -> None:
    """The fitted fields must be the trained head's, lobe for lobe."""
    fitted = teacher_settings(folder)
    head, lobes = fitted["head"], fitted["lobes"]
    if (head, lobes) != (cfg.head, cfg.lobes):
        raise ValueError(
            f"{folder}: fields of --head {head} --lobes {lobes}, but this run trains --head "
            f"{cfg.head} --lobes {cfg.lobes}"
        )
    domain = fitted.get("domain", "display")
    if domain != cfg.domain:
        raise ValueError(
            f"{folder}: fields for --lobe-domain {domain}, but this run trains {cfg.domain}"
        )


class Compute(NamedTuple):
    """How a step computes the network: `--bf16` and `--channels-last`."""

    bf16: bool = False
    channels_last: bool = False

    def batch(self, b: dict) -> dict:
        """The batch's images in the layout the network was put in."""
        if not self.channels_last:
            return b
        fmt = torch.channels_last
        return {k: v.contiguous(memory_format=fmt) if v.dim() == 4 else v for k, v in b.items()}

    def autocast(self, device: torch.device):
        return torch.autocast(device.type, dtype=torch.bfloat16, enabled=self.bf16)


class Teaching(NamedTuple):
    """How a step tells the network its teacher's fields (`field_loss`'s options)."""

    lobes: int
    weight: float
    fraction: str
    log_amplitude: bool
    balance: bool = False
    share: bool = False


def train_step(
    model,
    criterion: ReshadeLoss,
    opt,
    batch: dict,
    lr: float,
    d: Dist,
    step: int,
    teach: Teaching | None = None,
    compute: Compute | None = None,
):
    """One optimiser step. `teach`: batches carry fitted fields ("teacher"), and the
    fields' distance from them (`field_loss`) is added at its weight. `compute`: the
    forward pass's precision and layout; the losses are taken in float32."""
    for group in opt.param_groups:
        group["lr"] = lr * group.get("lr_scale", 1.0)
    compute = compute or Compute()
    b = compute.batch({k: v.to(d.device, non_blocking=True) for k, v in batch.items()})
    many = "targets" in b  # (B, N, ...): N cameras per photo, one encoder pass
    camera = b["cameras"] if many else b["camera"]
    with compute.autocast(d.device):
        pred = model(b["image"], b["disparity"], camera, b["rays"], fields=teach is not None)
    if teach is not None:
        pred, fields = pred
        fields = fields.float()
    pred = pred.float()
    if many:
        loss, parts = multi_target_loss(
            criterion, pred, b["targets"], b["masks"], b["weights"], b["image"]
        )
    else:
        loss, parts = criterion(pred, b["target"], b["mask"], b["image"])
    if teach is not None:
        photo = (b["image"], b["rays"]) if teach.share else None
        taught = field_loss(
            fields,
            b["teacher"],
            teach.lobes,
            teach.fraction,
            teach.log_amplitude,
            teach.balance,
            photo,
        )
        loss = loss + teach.weight * taught
        parts = {**parts, "loss": float(loss.detach()), "teacher": float(taught.detach())}
    if not torch.isfinite(loss):
        raise FloatingPointError(f"loss is {float(loss)} at step {step}: {parts}")
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return parts


def _json_value(value):
    """An argument as JSON can hold it: paths (also in lists, e.g. --init-from) as text."""
    if isinstance(value, list):
        return [_json_value(v) for v in value]
    return str(value) if isinstance(value, Path) else value


def train(args: argparse.Namespace) -> ReshadeNet:
    """Runs (or resumes) training and returns the trained network (unwrapped)."""
    d = setup_distributed(args.device)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    seed_everything(args.seed + d.rank)
    if d.main:
        args.run_dir.mkdir(parents=True, exist_ok=True)
    criterion = make_criterion(args, d)
    if args.targets_per_example < 1:
        raise ValueError(f"--targets-per-example {args.targets_per_example}: need at least 1")
    dataset, sampler, loader = make_loader(args, d, shared_example_list(args, d))
    val = ReshadeDataset(args.val_data) if args.val_data and d.main else None

    cfg = replace(
        net_config(args.size),
        head=args.head,
        deadzone=args.deadzone,
        lobes=args.lobes,
        domain=args.lobe_domain,
        amplitude=args.lobe_amplitude,
        film=args.film,
    )
    if args.teacher:
        check_teacher(args.teacher, cfg)
    if args.teacher_share and not (args.teacher and cfg.domain == "linear-clamped"):
        raise ValueError("--teacher-share needs --teacher and --lobe-domain linear-clamped")
    net = ReshadeNet(cfg).to(d.device)
    opt = torch.optim.Adam(param_groups(net, args.head_lr_scale), lr=args.lr)
    step = restore(args.run_dir, net, opt, criterion.ident, d)
    if step == 0 and args.init_from:
        count = initialise(net, args)
        if d.main:
            total = len(list(net.parameters()))
            print(
                f"initialised {count} of {total} parameters from {len(args.init_from)} ONNX file(s)"
            )
    compute = Compute(args.bf16, args.channels_last)
    if compute.channels_last:
        net = net.to(memory_format=torch.channels_last)
    model = net
    if d.world > 1:
        ids = [d.device.index] if d.device.type == "cuda" else None
        model = DistributedDataParallel(net, device_ids=ids)
    args_json = {k: _json_value(v) for k, v in vars(args).items()}
    meta = {
        "feature_net": criterion.ident,
        "feature_precision": str(criterion.feature_dtype).removeprefix("torch."),
        "loss_weights": str(criterion.weights),
        "pixel_loss": criterion.pixel,
        "args": {k: v for k, v in args_json.items() if not k.startswith("_")},
        "world_size": d.world,
        "train_examples": len(dataset),
    }
    if d.main:
        for name, fields in (("log.csv", LOG_FIELDS), ("val.csv", VAL_FIELDS)):
            truncate_csv(args.run_dir / name, step, fields)
        write_config(args, d, net, meta, step)
        print(
            f"training {args.size} ({count_parameters(net) / 1e6:.2f} M parameters) on "
            f"{len(dataset)} examples, {d.world} process(es) on {d.device}, perceptual "
            f"features: {meta['feature_net']}; steps {step} -> {args.steps}",
            file=sys.stderr,
        )

    log = RunLog(args, d, step)
    net.train()
    epoch = first_epoch = step // max(1, len(loader))
    while step < args.steps:
        if args.rescan and epoch > first_epoch:
            folders = shared_example_list(args, d)
            if len(folders) > len(dataset):
                dataset, sampler, loader = make_loader(args, d, folders, dataset)
                meta["train_examples"] = len(dataset)
        sampler.set_epoch(epoch)
        for batch in loader:
            if step >= args.steps:
                break
            lr = lr_at(step, args)
            teach = (
                Teaching(
                    args.lobes,
                    teacher_weight_at(step, args),
                    args.teacher_distance,
                    cfg.domain == "linear-clamped",
                    args.teacher_balance,
                    args.teacher_share,
                )
                if args.teacher
                else None
            )
            parts = train_step(model, criterion, opt, batch, lr, d, step, teach, compute)
            step += 1
            log.step(step, parts, lr, len(dataset))
            if d.main and (step % args.checkpoint_every == 0 or step == args.steps):
                save_checkpoint(args.run_dir, net, opt, step, meta, args.keep_checkpoints)
            if val is not None and (step % args.val_every == 0 or step == args.steps):
                if args.rescan and len(val) < args.val_examples:
                    val = ReshadeDataset(args.val_data)
                log.validation(step, validate(net, val, args.val_examples, d.device))
        epoch += 1
    log.close()
    if d.world > 1:
        dist.barrier()
    return net


def run(args: argparse.Namespace) -> int:
    try:
        train(args)
    except (DatasetError, FeatureNetError, ValueError) as err:
        print(f"train: {err}", file=sys.stderr)
        return 2
    finally:
        if dist.is_initialized():
            dist.destroy_process_group()
    return 0
