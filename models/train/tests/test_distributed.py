"""Two-process DistributedDataParallel training on the CPU (gloo), as torchrun would run it."""

import socket

import torch
import torch.multiprocessing as mp

from reshader_train.synthetic import write_dataset
from reshader_train.train import add_arguments, train


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def worker(rank: int, world: int, port: int, data: str, run_dir: str, out: str) -> None:
    import argparse
    import os

    os.environ.update(
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
        WORLD_SIZE=str(world),
        RANK=str(rank),
        LOCAL_RANK=str(rank),
    )
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(
        [
            "--data",
            data,
            "--run-dir",
            run_dir,
            "--size",
            "4,8,8,16,16,16",
            "--steps",
            "3",
            "--batch-size",
            "1",
            "--crop",
            "32",
            "--workers",
            "0",
            "--threads",
            "1",
            "--log-every",
            "1",
            "--no-progress",
            "--device",
            "cpu",
        ]
    )
    net = train(args)  # seeds each rank differently: DDP must keep the weights in sync
    torch.save(net.state_dict(), f"{out}/rank{rank}.pt")
    torch.distributed.destroy_process_group()


def test_two_process_gloo_training(tmp_path):
    data = write_dataset(tmp_path / "train", 4, 32, 32, seed=0)
    run = tmp_path / "run"
    mp.spawn(worker, args=(2, free_port(), str(data), str(run), str(tmp_path)), nprocs=2, join=True)
    s0 = torch.load(tmp_path / "rank0.pt")
    s1 = torch.load(tmp_path / "rank1.pt")
    assert all(torch.equal(s0[k], s1[k]) for k in s0)
    ckpt = torch.load(run / "checkpoint.pt", weights_only=False)
    assert ckpt["step"] == 3 and ckpt["world_size"] == 2
    assert all(torch.equal(ckpt["model"][k], s0[k]) for k in s0)
    lines = (run / "log.csv").read_text().splitlines()
    assert len(lines) == 4  # header + one averaged row per step, written by rank 0 only
