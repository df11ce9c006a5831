"""recipes/release ships a checkpoint: run against a stand-in reshader-train (each
subcommand writes what the real one writes, in miniature) it must put exactly the
encoder/decoder pairs and the examples into OUT, and leave OUT as it was when a step fails."""

import hashlib
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
RECIPE = ROOT / "models/train/recipes/release"

STAND_IN = r"""
import json, os, sys
from pathlib import Path

cmd, args = sys.argv[1], sys.argv[2:]
with open(os.environ["FAKE_LOG"], "a") as log:
    log.write(" ".join([cmd, *args]) + "\n")
if os.environ.get("FAKE_FAIL") == cmd:
    sys.exit(f"reshader-train {cmd}: failed on purpose")

def opt(name):
    return args[args.index(name) + 1]

if cmd == "evaluate":
    rows = [{"split": f, "scene": "s", "psnr_input": p, "psnr_ours": p + 0.5}
            for f in ("highlights", "products", "rooms", "studio", "diffuse")
            for p in (30.0, 45.0)]
    splits = {f: {"gain_db": 0.5, "psnr_input": 37.5, "psnr_ours": 38.0}
              for f in ("highlights", "products", "rooms", "studio", "diffuse")}
    Path(opt("--json")).write_text(json.dumps({"examples": rows, "splits": splits}))
elif cmd == "quantize":
    Path(opt("--out")).write_text("qat")
elif cmd == "export":
    out = Path(opt("--out"))
    precisions = args[args.index("--precision") + 1:]
    precisions = precisions[: next((i for i, a in enumerate(precisions) if a.startswith("-")),
                                   len(precisions))]
    for p in precisions:
        name = "int8-wo" if p == "int8" else p
        for part in ("", "-encoder", "-decoder"):
            for ext in ("onnx", "json"):
                (out / f"reshade-lite-{name}{part}.{ext}").write_text(opt("--version"))
elif cmd == "examples":
    out = Path(opt("--out"))
    out.mkdir(parents=True)
    (out / "examples.json").write_text("{}")
"""


def fake_venv(tmp_path: Path) -> Path:
    """A venv that scripts/python-env takes as up to date, with the stand-in inside."""
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    # The interpreter running these tests, with its packages (score-heldout needs them).
    python = venv / "bin/python"
    python.write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n')
    tool = venv / "bin/reshader-train"
    tool.write_text(f"#!{sys.executable}\n{STAND_IN}")
    for script in (python, tool):
        script.chmod(script.stat().st_mode | stat.S_IXUSR)
    parts = [ROOT / "models/train/pyproject.toml", ROOT / "scripts/python-env"]
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in parts)).hexdigest()[:16]
    (venv / ".reshader-stamp").write_text(digest + "\n")
    return venv


def run_release(tmp_path: Path, **env) -> subprocess.CompletedProcess:
    out = tmp_path / "shipped"
    environ = {
        **os.environ,
        "RESHADER_VENV": str(fake_venv(tmp_path)),
        "FAKE_LOG": str(tmp_path / "calls.log"),
        "OUT": str(out),
        **env,
    }
    ckpt = tmp_path / "runs/average.pt"
    ckpt.parent.mkdir()
    ckpt.write_text("weights")
    argv = ["bash", str(RECIPE), str(ckpt), "9.9.9", str(tmp_path / "data")]
    return subprocess.run(argv, env=environ, capture_output=True, text=True)


@pytest.fixture
def shipped(tmp_path: Path) -> Path:
    out = tmp_path / "shipped"
    (out / "examples").mkdir(parents=True)
    (out / "examples/old-example").write_text("old")
    (out / "reshade-lite-fp32-encoder.onnx").write_text("0.4.0")
    (out / "README.md").write_text("card")
    return out


def test_release_ships_the_pairs_and_examples_only(tmp_path, shipped):
    done = run_release(tmp_path)
    assert done.returncode == 0, done.stderr
    names = {p.name for p in shipped.iterdir()}
    pairs = {
        f"reshade-lite-{p}-{part}.{ext}"
        for p in ("fp32", "fp16", "int8-wo")
        for part in ("encoder", "decoder")
        for ext in ("onnx", "json")
    }
    assert names == pairs | {"examples", "README.md"}
    assert (shipped / "reshade-lite-fp32-encoder.onnx").read_text() == "9.9.9"
    assert sorted(os.listdir(shipped / "examples")) == ["examples.json"]
    assert "| changing views |" in done.stdout  # score-heldout's row for the card
    calls = (tmp_path / "calls.log").read_text().splitlines()
    assert [c.split()[0] for c in calls] == ["evaluate", "quantize", "export", "export", "examples"]
    assert "--form weights --target fp32" in calls[1]
    assert "--int8-form weights" in calls[3] and "average-qat.pt" in calls[3]
    assert json.loads((tmp_path / "runs/average-heldout.json").read_text())["examples"]


def test_a_failed_step_leaves_the_shipped_model_as_it_was(tmp_path, shipped):
    before = {p: p.read_bytes() for p in shipped.rglob("*") if p.is_file()}
    done = run_release(tmp_path, FAKE_FAIL="examples")
    assert done.returncode != 0
    assert "failed on purpose" in done.stderr
    after = {p: p.read_bytes() for p in shipped.rglob("*") if p.is_file()}
    assert after == before
    assert not [p for p in shipped.iterdir() if p.name.startswith(".release")]
