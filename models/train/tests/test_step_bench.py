import sys

from reshader_train import step_bench


def test_step_bench_times_every_compute_form(monkeypatch, capsys):
    argv = ["step_bench", "--size", "4,8,8,16,16,16", "--batch", "2", "--crop", "32",
            "--steps", "1", "--rounds", "2"]  # fmt: skip
    monkeypatch.setattr(sys, "argv", argv)
    step_bench.main()
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    assert rows[0].startswith("| form | round 1 | round 2")
    forms = [r.split(" | ")[0].removeprefix("| ") for r in rows[1:]]
    assert forms == list(step_bench.FORMS)
    assert all(float(r.split(" | ")[1]) > 0 for r in rows[1:])
