"""Parameters, convolution FLOPs and PyTorch CPU time of candidate network sizes.

    python -m reshader_train.sizes_bench [--threads 1] [--height 384] [--width 640]

The numbers behind the choice of the `lite` size (README, Training section). PyTorch is a
stand-in for the runtime's engine here; the runtime's own benchmark measures tract.
"""

from __future__ import annotations

import argparse
import time

import torch

from .model import SIZES, NetConfig, ReshadeNet, conv_flops, count_parameters

CANDIDATES = {
    "full": SIZES["full"],
    "half": NetConfig(widths=(16, 32, 64, 128, 256, 256)),
    "12-24, 1 conv top": NetConfig(widths=(12, 24, 48, 96, 192, 192), convs=(1, 1, 2, 2, 2, 2)),
    "lite": SIZES["lite"],
    "8-16, 1 conv all": NetConfig(widths=(8, 16, 32, 64, 128, 128), convs=(1,) * 6),
}


def measure(cfg: NetConfig, height: int, width: int, repeats: int) -> dict[str, float]:
    net = ReshadeNet(cfg).eval()
    flops = conv_flops(net, height, width)
    image, disp = torch.rand(1, 3, height, width), torch.rand(1, 1, height, width)
    camera = torch.tensor([[0.1, 0.0, 0.1]])
    enc_ms, dec_ms = [], []
    with torch.no_grad():
        net(image, disp, camera)  # warm-up
        for _ in range(repeats):
            t0 = time.perf_counter()
            bottleneck, skips = net.encoder(image, disp)
            t1 = time.perf_counter()
            net.decoder(image, skips, bottleneck, camera)
            t2 = time.perf_counter()
            enc_ms.append(1e3 * (t1 - t0))
            dec_ms.append(1e3 * (t2 - t1))
    return {
        "params_m": count_parameters(net) / 1e6,
        "enc_gflop": flops["encoder"] / 1e9,
        "dec_gflop": flops["decoder"] / 1e9,
        "enc_ms": min(enc_ms),
        "dec_ms": min(dec_ms),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--height", type=int, default=384)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    print(f"{args.height}x{args.width}, {args.threads} thread(s), best of {args.repeats}")
    print("| size | widths | convs | params | enc GFLOP | dec GFLOP | enc ms | dec ms |")
    print("|---|---|---|---|---|---|---|---|")
    for name, cfg in CANDIDATES.items():
        m = measure(cfg, args.height, args.width, args.repeats)
        print(
            f"| {name} | {'-'.join(map(str, cfg.widths))} | {','.join(map(str, cfg.convs))} | "
            f"{m['params_m']:.2f} M | {m['enc_gflop']:.2f} | {m['dec_gflop']:.2f} | "
            f"{m['enc_ms']:.0f} | {m['dec_ms']:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
