"""Where onnxruntime spends a run of an ONNX file, per operator type.

    python bench/profile_onnxruntime.py models/depth/tiefenrausch-fp32.onnx \
        --input image=1,3,288,384 [--threads 2] [--runs 3]

The counterpart of tract's per-operator profile (`TractEngine::profile`; for the depth
network the ignored test `depth_models::profile_shipped_depth_network_in_tract`): the
session and deterministic inputs of `peer_onnxruntime.py`, the same threads, one warm-up run,
and the table of the last timed run from onnxruntime's own profiler. onnxruntime's graph
optimisations rename and fuse nodes (a convolution absorbs the clip after it, layouts
change to blocks of channels with Reorder nodes between them), so the operator types are
those of the graph it runs, not of the file.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import tempfile
import time

import onnxruntime as ort
from peer_onnxruntime import session_and_feeds


def parse_input(text: str) -> tuple[str, list[int]]:
    name, _, dims = text.partition("=")
    if not name or not dims:
        raise argparse.ArgumentTypeError(f"expected NAME=D0,D1,..., got {text!r}")
    try:
        return name, [int(d) for d in dims.split(",")]
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"bad dimension in {text!r}: {err}") from err


def profile(path: str, inputs: list[tuple[str, list[int]]], threads: int, runs: int):
    with tempfile.TemporaryDirectory() as trace_dir:
        return profile_into(trace_dir, path, inputs, threads, runs)


def profile_into(trace_dir: str, path: str, inputs, threads: int, runs: int):
    options = ort.SessionOptions()
    options.enable_profiling = True
    options.profile_file_prefix = os.path.join(trace_dir, "ort")
    session, feeds = session_and_feeds(path, inputs, threads, options)
    walls = []
    for _ in range(max(runs, 1) + 1):
        started = time.perf_counter()
        session.run(None, feeds)
        walls.append((time.perf_counter() - started) * 1e3)
    with open(session.end_profiling()) as trace:
        events = json.load(trace)
    last = max(e["ts"] for e in events if e.get("name") == "model_run")
    per_op = collections.Counter()
    for event in events:
        if (
            event.get("cat") == "Node"
            and event["name"].endswith("_kernel_time")
            and event["ts"] >= last
        ):
            per_op[event["args"]["op_name"]] += event["dur"] / 1e3
    return walls[-1], per_op


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model")
    parser.add_argument("--input", type=parse_input, action="append", required=True)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    wall, per_op = profile(args.model, args.input, args.threads, args.runs)
    total = sum(per_op.values())
    print(f"{args.model}, onnxruntime {ort.__version__}, {args.threads} threads:")
    print(f"run {wall:.1f} ms, operators {total:.1f} ms\n")
    print("| operator | ms | share |\n|---|---|---|")
    for op, ms in per_op.most_common():
        print(f"| {op} | {ms:.1f} | {100 * ms / total:.0f}% |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
