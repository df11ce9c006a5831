"""Exports the naive configuration of `reshader bench`: the paper-size ("full") reshading
network, randomly initialised (timing does not depend on the weights), as one fp32 graph
with its manifest, using the training toolchain's exporter.

    python bench/export_naive.py --out ~/.cache/reshader/bench

The output is a cache: large, untrained, never committed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from reshader_train.export import ExportError, ExportInfo, export_precision
from reshader_train.model import ReshadeNet, net_config

SIZE = "full"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--stem", default="reshade-full-naive-fp32")
    p.add_argument("--seed", type=int, default=0)
    # Only the parity check runs at this size; the graph keeps symbolic H and W.
    p.add_argument("--height", type=int, default=64)
    p.add_argument("--width", type=int, default=64)
    args = p.parse_args(argv)
    torch.manual_seed(args.seed)
    net = ReshadeNet(net_config(SIZE)).eval()
    info = ExportInfo(
        size=SIZE,
        validation={"note": "randomly initialised: for timing only"},
        source=f"bench/export_naive.py --seed {args.seed} (torch {torch.__version__})",
    )
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        paths = export_precision(
            net, "fp32", args.out, args.stem, info, False, args.height, args.width
        )
    except ExportError as err:
        print(f"export_naive: {err}", file=sys.stderr)
        return 2
    for path in paths:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
