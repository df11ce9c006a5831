"""`reshader-train import`: a checkpoint rebuilt from an exported fp32 encoder/decoder pair.

Only the deployable ONNX files of a shipped model are kept, not its checkpoint. Importing
them gives `evaluate`, `quantize`, `export` and `examples` something to work on, and lets
an export-time part of the network (the dead zone) change without retraining the weights.
The source manifests' provenance (training command, data, steps) is carried over, with
this command appended, so that a re-export still says how its weights were trained.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from dataclasses import replace
from pathlib import Path

import torch

from .model import HEADS, LEVELS, SIZES, NetConfig, ReshadeNet, net_config
from .onnx_weights import load_onnx_weights
from .train import atomic_write


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("onnx", type=Path, nargs="+", help="fp32 encoder and decoder (or one graph)")
    p.add_argument("--out", type=Path, required=True, help="checkpoint to write (.pt)")
    p.add_argument(
        "--deadzone",
        type=float,
        help="residual magnitudes up to this become exactly 0 (default: the source's)",
    )


def source_manifest(path: Path) -> dict:
    manifest = path.with_suffix(".json")
    try:
        return json.loads(manifest.read_text())
    except (OSError, ValueError) as err:
        raise ValueError(
            f"{manifest}: the manifest beside {path.name} is unreadable ({err})"
        ) from None


def config_from(manifest: dict, where: Path) -> NetConfig:
    arch = manifest.get("architecture") or {}
    if "size" not in arch or "widths" not in arch:
        raise ValueError(f"{where}: manifest has no architecture size and widths")
    if arch["size"] in SIZES:
        cfg = SIZES[arch["size"]]
    else:
        widths = ",".join(map(str, arch["widths"]))
        cfg = replace(net_config(widths), convs=tuple(arch.get("convs", (1,) * LEVELS)))
    head = arch.get("head", "residual")
    if head not in HEADS:
        raise ValueError(f"{where}: unknown output head {head!r}")
    return replace(
        cfg,
        head=head,
        deadzone=float(arch.get("deadzone", 0.0)),
        film=bool(arch.get("film", False)),
    )


def loss_options(command: str) -> dict[str, str]:
    """`--loss-weights` and `--pixel-loss` as the source's training command gave them, so that
    `quantize` fine-tunes with the loss the weights were trained with."""
    try:
        tokens = shlex.split(command)
    except ValueError:
        return {}
    found = {}
    for key, option in (("loss_weights", "--loss-weights"), ("pixel_loss", "--pixel-loss")):
        if option in tokens[:-1]:
            found[key] = tokens[tokens.index(option) + 1]
    return found


def exported_network(
    files: list[Path], label: str, deadzone: float | None = None
) -> tuple[ReshadeNet, list[dict]]:
    """The network an exported fp32 pair (or single graph) holds, as its manifests describe
    it (with another dead zone if given), and those manifests."""
    manifests = [source_manifest(f) for f in files]
    cfg = config_from(manifests[0], files[0].with_suffix(".json"))
    if deadzone is not None:
        cfg = replace(cfg, deadzone=deadzone)
    net = ReshadeNet(cfg)
    load_onnx_weights(net, files, label=label)
    return net, manifests


def build(files: list[Path], deadzone: float | None, argv_line: str) -> dict:
    net, manifests = exported_network(files, "import", deadzone)
    cfg = net.cfg
    training = manifests[0].get("training") or {}
    source_command = training.get("command", "unknown")
    return {
        "model": net.state_dict(),
        "net_config": cfg.to_json(),
        "step": int(training.get("steps") or 0),
        "feature_net": training.get("feature_network", "unknown"),
        "args": {"data": training.get("data", "unknown")},
        "command": f"{source_command} && {argv_line}",
        **loss_options(source_command),
        "wall_time_s": training.get("wall_time_s"),
        "imported_from": [
            {"file": str(f), "sha256": m.get("sha256"), "version": m.get("version")}
            for f, m in zip(files, manifests, strict=True)
        ],
    }


def run(args: argparse.Namespace) -> int:
    line = "reshader-train import " + " ".join(shlex.quote(str(f)) for f in args.onnx)
    line += f" --out {shlex.quote(str(args.out))}"
    if args.deadzone is not None:
        line += f" --deadzone {args.deadzone:g}"
    try:
        state = build(args.onnx, args.deadzone, line)
    except ValueError as err:
        print(f"import: {err}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, lambda tmp: torch.save(state, tmp))
    cfg = state["net_config"]
    print(f"checkpoint {args.out}: {cfg['head']} head, dead zone {cfg['deadzone']:g}")
    return 0
