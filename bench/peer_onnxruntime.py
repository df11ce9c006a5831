"""The onnxruntime side of `reshader bench`: times ONNX files at given input shapes.

Reads a JSON request on stdin,
    {"threads": 2, "runs": 3,
     "models": [{"label": "...", "path": "x.onnx", "inputs": [["image", [1, 3, 384, 288]], ...]}]}
and prints {"onnxruntime": VERSION, "results": [{"label", "median_ms", "min_ms", "max_ms",
"runs"} or {"label", "error"}]} on stdout. Inputs are the same deterministic values in
[0, 1) the Rust side feeds tract; one untimed warm-up run precedes the timed runs.
"""

from __future__ import annotations

import json
import statistics
import sys
import time

import numpy as np
import onnxruntime as ort

DTYPES = {
    "tensor(float)": np.float32,
    "tensor(float16)": np.float16,
    "tensor(uint8)": np.uint8,
    "tensor(int8)": np.int8,
}


def deterministic(shape: list[int], dtype) -> np.ndarray:
    n = int(np.prod(shape))
    values = (np.arange(n, dtype=np.int64) * 7919 % 1000).astype(np.float32) / 1000.0
    if np.issubdtype(dtype, np.integer):
        values = values * 255.0
    return values.astype(dtype).reshape(shape)


def session_and_feeds(path: str, inputs, threads: int, options=None):
    """A CPU session of the ONNX file on `threads` threads (with `options`, if given,
    for anything else), and the deterministic inputs of the given shapes by name."""
    options = options or ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    session = ort.InferenceSession(
        path, sess_options=options, providers=["CPUExecutionProvider"]
    )
    types = {i.name: i.type for i in session.get_inputs()}
    feeds = {}
    for name, shape in inputs:
        if name not in types:
            raise ValueError(f"the graph has no input {name!r} (it has {sorted(types)})")
        dtype = DTYPES.get(types[name])
        if dtype is None:
            raise ValueError(f"input {name!r} has unsupported type {types[name]}")
        feeds[name] = deterministic(shape, dtype)
    return session, feeds


def time_model(model: dict, threads: int, runs: int) -> dict:
    session, feeds = session_and_feeds(model["path"], model["inputs"], threads)
    session.run(None, feeds)
    samples = []
    for _ in range(max(runs, 1)):
        started = time.perf_counter()
        session.run(None, feeds)
        samples.append((time.perf_counter() - started) * 1e3)
    return {
        "median_ms": statistics.median(samples),
        "min_ms": min(samples),
        "max_ms": max(samples),
        "runs": len(samples),
    }


def main() -> int:
    try:
        request = json.load(sys.stdin)
        threads, runs, models = request["threads"], request["runs"], request["models"]
    except (ValueError, KeyError, TypeError) as err:
        print(f"peer_onnxruntime: bad request on stdin: {err}", file=sys.stderr)
        return 2
    results = []
    for model in models:
        try:
            results.append({"label": model["label"], **time_model(model, threads, runs)})
        except Exception as err:  # noqa: BLE001 - one model's failure is reported, not fatal
            results.append({"label": model.get("label", "?"), "error": str(err)})
    json.dump({"onnxruntime": ort.__version__, "results": results}, sys.stdout)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
