"""Milliseconds per training step of the lite network in each compute form of `train`
(float32 or `--bf16`, NCHW or `--channels-last`), the forms alternated in rounds so that a
busy machine slows them alike.

    python -m reshader_train.step_bench [--threads 1] [--batch 8] [--crop 128] [--rounds 2]

The numbers behind `train --bf16` (README, "Running train"). The loss is a plain squared
error against random targets: what is timed is the network's forward and backward pass and
the optimiser, as in a pixel-loss step.
"""

from __future__ import annotations

import argparse
import time

import torch

from .model import ReshadeNet, net_config
from .train import Compute

FORMS = {
    "float32, NCHW": Compute(),
    "bfloat16, NCHW": Compute(bf16=True),
    "float32, channels-last": Compute(channels_last=True),
    "bfloat16, channels-last": Compute(bf16=True, channels_last=True),
}


def stepper(compute: Compute, batch: dict, size: str):
    """A function running one training step of a fresh `size` network in `compute`'s form."""
    torch.manual_seed(0)
    net = ReshadeNet(net_config(size))
    if compute.channels_last:
        net = net.to(memory_format=torch.channels_last)
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    b = compute.batch(batch)
    device = torch.device("cpu")

    def step() -> None:
        with compute.autocast(device):
            out = net(b["image"], b["disparity"], b["camera"], None)
        loss = ((out.float() - b["target"]) ** 2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    return step


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--crop", type=int, default=128)
    p.add_argument("--steps", type=int, default=8, help="timed steps per form and round")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--size", default="lite")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    n, c = args.batch, args.crop
    batch = {
        "image": torch.rand(n, 3, c, c),
        "disparity": torch.rand(n, 1, c, c),
        "camera": 0.3 * torch.rand(n, 3),
        "target": torch.rand(n, 3, c, c),
    }
    steps = {name: stepper(compute, batch, args.size) for name, compute in FORMS.items()}
    print(f"{args.size}, batch {n} of {c}x{c}, {args.threads} thread(s), ms per step by round")
    print("| form | " + " | ".join(f"round {r + 1}" for r in range(args.rounds)) + " |")
    print("|---|" + "---|" * args.rounds)
    times: dict[str, list[float]] = {name: [] for name in FORMS}
    for _ in range(args.rounds):
        for name, step in steps.items():
            step()  # warm-up: the first step of a form builds its kernels
            t0 = time.perf_counter()
            for _ in range(args.steps):
                step()
            times[name].append(1e3 * (time.perf_counter() - t0) / args.steps)
    for name, ms in times.items():
        print(f"| {name} | " + " | ".join(f"{t:.0f}" for t in ms) + " |", flush=True)


if __name__ == "__main__":
    main()
