"""Exports randomly initialised reshading networks for `reshader bench`, using the
training toolchain's exporter (timing does not depend on the weights):

- the naive configuration, the paper-size (`full`) network as one fp32 graph:
      python bench/export_untrained.py --size full --out ~/.cache/reshader/bench
- a stand-in for the shipped model before a trained one exists, with the shipped
  architecture (`lite`) as an encoder/decoder pair:
      python bench/export_untrained.py --size lite --split --out ~/.cache/reshader/bench

The output is a cache: large, untrained, never committed; every manifest says so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from reshader_train.export import ExportError, ExportInfo, export_precision
from reshader_train.model import ReshadeNet, net_config


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--size", default="full", help="network size name (full, lite, ...)")
    p.add_argument("--stem", help="file name stem [default: reshade-SIZE-untrained-PRECISION]")
    p.add_argument("--precision", nargs="+", default=["fp32"], choices=["fp32", "fp16"])
    p.add_argument("--split", action="store_true", help="also write the encoder/decoder pair")
    p.add_argument("--seed", type=int, default=0)
    # Only the parity check runs at this size; the graph keeps symbolic H and W.
    p.add_argument("--height", type=int, default=64)
    p.add_argument("--width", type=int, default=64)
    args = p.parse_args(argv)
    torch.manual_seed(args.seed)
    net = ReshadeNet(net_config(args.size)).eval()
    info = ExportInfo(
        size=args.size,
        validation={"note": "randomly initialised (untrained): for timing only"},
        source=f"bench/export_untrained.py --size {args.size} --seed {args.seed} "
        f"(torch {torch.__version__})",
    )
    args.out.mkdir(parents=True, exist_ok=True)
    for precision in args.precision:
        stem = args.stem or f"reshade-{args.size}-untrained-{precision}"
        try:
            paths = export_precision(
                net, precision, args.out, stem, info, args.split, args.height, args.width
            )
        except ExportError as err:
            print(f"export_untrained: {err}", file=sys.stderr)
            return 2
        for path in paths:
            print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
