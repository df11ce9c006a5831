"""Fixtures and helpers shared by the tests."""

import json

import pytest
import torch

from reshader_train.cli import main


@pytest.fixture(scope="module")
def analytic(tmp_path_factory):
    """Three analytic examples with three targets each (32x32) and their fitted fields."""
    root = tmp_path_factory.mktemp("teach")
    data = root / "analytic"
    argv = ["render", "--scenes", "analytic", "--out", str(data), "--count", "3"]
    assert main([*argv, "--size", "32x32", "--spp", "1", "--targets", "3", "--seed", "5"]) == 0
    fields = root / "fields"
    argv = ["teacher", "--data", str(data), "--out", str(fields), "--steps", "20", "--smooth", "4"]
    assert main(argv) == 0
    return data, fields


def check_untrained(cfg, data, fields, tmp_path, name: str = "net") -> tuple[list[str], dict]:
    """`teacher-check` of an untrained network of `cfg` against `fields`: its argv (the
    checkpoint third) and the JSON report."""
    from reshader_train.model import ReshadeNet

    ckpt = tmp_path / f"{name}.pt"
    torch.save({"model": ReshadeNet(cfg).state_dict(), "net_config": cfg.to_json()}, ckpt)
    out = tmp_path / f"{name}-check.json"
    argv = ["teacher-check", "--checkpoint", str(ckpt), "--data", str(data), "--teacher",
            str(fields), "--json", str(out)]  # fmt: skip
    assert main(argv) == 0
    return argv, json.loads(out.read_text())


@pytest.fixture
def act_quant_calls(monkeypatch):
    """Counts the calls of quantize.ActQuant.forward (activation fake-quantisation): a
    dict whose "n" a test may reset."""
    from reshader_train import quantize

    calls = {"n": 0}
    real = quantize.ActQuant.forward

    def counting(self, x):
        calls["n"] += 1
        return real(self, x)

    monkeypatch.setattr(quantize.ActQuant, "forward", counting)
    return calls
