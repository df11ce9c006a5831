"""`reshader-train train-depth`: the depth network fine-tuned on rendered photos.

Starts from the shipped fp32 graph (`--base`), learns its convolutions' weights with the
scale-and-shift-invariant loss of `loss.py` on random crops, and keeps a checkpoint every
`--checkpoint-every` steps (`RUN/step-NNNNNN.pt`, and `RUN/last.pt` to resume from: a run
stopped at any moment continues where its last checkpoint was, with the same command).
`--anchor` pulls the weights towards the shipped ones (L2, per weight), so that what the
network knew about real photos is not traded away for the renders' look; `--decals`
paints patterns into the crops at their depth (data.py); `--keep-photos` keeps the base
network's coarse shapes on photos without depth (keep.py). Validation:
the aligned error on `--val` at the evaluation's tone mapping, whole images.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ..data import DatasetError
from ..train import atomic_write
from .data import Cache, evaluation_image, example_folders, training_crop
from .graph import DepthGraph, GraphError
from .keep import keep_loss, load_photos, photo_crop
from .loss import depth_loss

LAST = "last.pt"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--data",
        type=Path,
        nargs="+",
        required=True,
        help="example folders (or folders of family folders) with input.exr and depth.exr",
    )
    p.add_argument(
        "--val",
        type=Path,
        required=True,
        help="validation examples (chooses checkpoints; never the held-out sets)",
    )
    p.add_argument("--out", type=Path, required=True, help="run folder (checkpoints, log.jsonl)")
    p.add_argument(
        "--base",
        type=Path,
        default=Path("models/depth/tiefenrausch-fp32.onnx"),
        help="the fp32 graph to start from",
    )
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument(
        "--lr",
        type=float,
        default=2e-5,
        help="Adam learning rate (constant, the last 30%% at a third)",
    )
    p.add_argument("--batch", type=int, default=4)
    p.add_argument(
        "--crop", default="192x256", help="HEIGHTxWIDTH of the training crops, multiples of 32"
    )
    p.add_argument(
        "--grad-weight", type=float, default=0.5, help="weight of the gradient-matching term"
    )
    p.add_argument(
        "--anchor",
        type=float,
        default=0.0,
        help="L2 pull towards the base weights, per weight (0: none)",
    )
    p.add_argument(
        "--decals",
        type=float,
        default=0.0,
        help="share of crops with dark or bright shapes painted on them at their depth "
        "(data.py): teaches that a pattern is not a shape (0: none)",
    )
    p.add_argument(
        "--keep-photos",
        type=Path,
        nargs="+",
        default=None,
        help="photos (files or folders of .jpg/.png) without depth on which the tuned "
        "network keeps the base network's coarse shapes (keep.py)",
    )
    p.add_argument(
        "--keep-weight", type=float, default=1.0, help="weight of the --keep-photos term"
    )
    p.add_argument("--keep-batch", type=int, default=2, help="--keep-photos crops per step")
    p.add_argument("--checkpoint-every", type=int, default=250)
    p.add_argument("--val-every", type=int, default=500)
    p.add_argument(
        "--rescan",
        type=int,
        default=250,
        help="look for newly rendered examples every N steps (0: never)",
    )
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    p.add_argument("--seed", type=int, default=0)


def _crop(text: str) -> tuple[int, int]:
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--crop {text!r}: expected HEIGHTxWIDTH, e.g. 192x256") from None
    if h <= 0 or w <= 0 or h % 32 or w % 32:
        raise ValueError(f"--crop {text!r}: both sides must be positive multiples of 32")
    return h, w


def validate(net: DepthGraph, folders: list[Path], cache: Cache) -> dict:
    totals = {"data": 0.0, "grad": 0.0}
    with torch.no_grad():
        for folder in folders:
            rgb, disparity = evaluation_image(cache.get(folder))
            _, parts = depth_loss(
                net(torch.from_numpy(rgb)[None]), torch.from_numpy(disparity)[None]
            )
            for k in totals:
                totals[k] += parts[k] / len(folders)
    return totals


def _save(path: Path, state: dict) -> None:
    atomic_write(path, lambda tmp: torch.save(state, tmp))


def _truncate_log(path: Path, step: int) -> None:
    """Drops the records of steps after the checkpoint resumed from: they are run again."""
    if path.is_file():
        kept = [r for r in path.read_text().splitlines() if json.loads(r)["step"] <= step]
        atomic_write(path, lambda tmp: Path(tmp).write_text("".join(r + "\n" for r in kept)))


def _by_name(saved: dict, saved_names: list[str], names: list[str]) -> dict:
    """An optimizer state saved with its parameters in one order, for another order.

    Adam keeps its moments by parameter index; the order of the graph's weights has
    changed between versions of this module, and a run resumed across such a change would
    otherwise fail on the first step with mismatched shapes (or, worse, not fail)."""
    index = {name: i for i, name in enumerate(saved_names)}
    if sorted(index) != sorted(names):
        raise ValueError("the checkpoint's weights are not this graph's")
    moments = saved["state"]
    (group,) = saved["param_groups"]
    return {
        "state": {i: moments[index[n]] for i, n in enumerate(names) if index[n] in moments},
        "param_groups": [{**group, "params": list(range(len(names)))}],
    }


def _keep_term(net, reference, photos, crop, batch: int, rng, parts: dict) -> torch.Tensor:
    """keep.py's term on a batch of the photos' crops; its value goes into `parts`."""
    x = torch.from_numpy(
        np.stack([photo_crop(photos[i], crop, rng) for i in rng.integers(0, len(photos), batch)])
    ).contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        target = reference(x)
    term = keep_loss(net(x), target)
    parts["keep"] = float(term.detach())
    return term


def train(args) -> None:
    crop = _crop(args.crop)
    torch.set_num_threads(args.threads or os.cpu_count() or 1)
    net = DepthGraph.load(args.base).to(memory_format=torch.channels_last)
    base = {k: v.detach().clone() for k, v in net.weights.items()}
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    folders = example_folders(args.data)
    val = example_folders([args.val])
    keep = load_photos(args.keep_photos, crop) if args.keep_photos else []
    reference = DepthGraph.load(args.base).eval() if keep else None
    args.out.mkdir(parents=True, exist_ok=True)
    step, wall = 0, 0.0
    if (args.out / LAST).is_file():
        state = torch.load(args.out / LAST, weights_only=False)
        net.weights.load_state_dict(state["weights"])
        opt.load_state_dict(_by_name(state["optimizer"], list(state["weights"]), list(net.weights)))
        step, wall = state["step"], state["wall_time_s"]
        _truncate_log(args.out / "log.jsonl", step)
        print(f"train-depth: resuming {args.out} at step {step}", flush=True)
    rng = np.random.default_rng([args.seed, step])
    cache = Cache()
    command = shlex.join(["reshader-train", "train-depth", *sys.argv[2:]])
    print(
        f"train-depth: {len(folders)} training examples, {len(val)} validation, "
        f"{len(keep)} photos to keep, crops {crop[0]}x{crop[1]}",
        flush=True,
    )
    log = (args.out / "log.jsonl").open("a")
    if step == 0:
        log.write(json.dumps({"step": 0, "val": validate(net, val, cache)}) + "\n")
        log.flush()
    net.train()
    start = time.perf_counter() - wall
    while step < args.steps:
        if args.rescan and step % args.rescan == 0 and step:
            folders = example_folders(args.data)
        lr = args.lr / 3 if step >= 0.7 * args.steps else args.lr
        for group in opt.param_groups:
            group["lr"] = lr
        batch = [
            training_crop(cache.get(folders[i]), crop, rng, args.decals)
            for i in rng.integers(0, len(folders), args.batch)
        ]
        rgb = torch.from_numpy(np.stack([b[0] for b in batch])).contiguous(
            memory_format=torch.channels_last
        )
        target = torch.from_numpy(np.stack([b[1] for b in batch]))
        loss, parts = depth_loss(net(rgb), target, args.grad_weight)
        if keep:
            loss = loss + args.keep_weight * _keep_term(
                net, reference, keep, crop, args.keep_batch, rng, parts
            )
        if args.anchor:
            loss = loss + args.anchor * sum(
                ((w - base[k]) ** 2).sum() for k, w in net.weights.items()
            )
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        record = {
            "step": step,
            "loss": float(loss.detach()),
            **parts,
            "lr": lr,
            "examples": len(folders),
        }
        if step % args.val_every == 0 or step == args.steps:
            record["val"] = validate(net, val, cache)
        log.write(json.dumps(record) + "\n")
        log.flush()
        if step % args.checkpoint_every == 0 or step == args.steps:
            state = {
                "weights": net.weights.state_dict(),
                "optimizer": opt.state_dict(),
                "step": step,
                "wall_time_s": time.perf_counter() - start,
                "base": str(args.base),
                "command": command,
                "examples": len(folders),
            }
            _save(
                args.out / f"step-{step:06d}.pt",
                {k: v for k, v in state.items() if k != "optimizer"},
            )
            _save(args.out / LAST, state)
            print(
                f"step {step}: loss {float(loss.detach()):.4f} "
                + (f"val {record['val']}" if "val" in record else ""),
                flush=True,
            )


def run(args) -> int:
    try:
        train(args)
    except (DatasetError, GraphError, ValueError) as err:
        print(f"reshader-train train-depth: {err}", file=sys.stderr)
        return 2
    return 0
