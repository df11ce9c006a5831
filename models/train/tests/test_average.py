import torch

from reshader_train.cli import main
from reshader_train.model import ReshadeNet, net_config

TINY = "4,8,8,16,16,16"


def save(path, widths, fill, step, run_command=None):
    net = ReshadeNet(net_config(widths))
    with torch.no_grad():
        for p in net.parameters():
            p.fill_(fill)
    state = {"model": net.state_dict(), "net_config": net.cfg.to_json(), "step": step}
    if run_command:
        state["command"] = run_command
    state["optimizer"] = {"not": "kept"}
    torch.save(state, path)


def test_average_is_the_mean_of_the_weights_and_keeps_provenance(tmp_path, capsys):
    save(tmp_path / "a.pt", TINY, 1.0, 100, run_command="reshader-train train --steps 200")
    save(tmp_path / "b.pt", TINY, 2.0, 200, run_command="reshader-train train --steps 200")
    save(tmp_path / "c.pt", TINY, 6.0, 300, run_command="reshader-train train --steps 300")
    out = tmp_path / "avg" / "mean.pt"
    args = ["average", *(str(tmp_path / f"{n}.pt") for n in "abc"), "--out", str(out)]
    assert main(args) == 0
    ckpt = torch.load(out, weights_only=False)
    weights = [t for t in ckpt["model"].values() if t.is_floating_point()]
    assert weights and all(torch.allclose(t, torch.full_like(t, 3.0)) for t in weights)
    assert ckpt["step"] == 300 and "optimizer" not in ckpt
    assert [a["step"] for a in ckpt["averaged_from"]] == [100, 200, 300]
    # Each run's command once, in order: two arms of one start, then their mean.
    assert ckpt["command"].startswith(
        "reshader-train train --steps 200 ; reshader-train train --steps 300 && "
        "reshader-train average"
    )
    assert "steps 100, 200, 300" in capsys.readouterr().out
    net = ReshadeNet(net_config(TINY))
    net.load_state_dict(ckpt["model"])


def test_checkpoints_of_different_networks_are_refused(tmp_path, capsys):
    save(tmp_path / "a.pt", TINY, 1.0, 100)
    save(tmp_path / "b.pt", "4,8,8,16,16,32", 1.0, 100)
    out = tmp_path / "mean.pt"
    assert main(["average", str(tmp_path / "a.pt"), str(tmp_path / "b.pt"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "b.pt" in err and "differs" in err
    assert not out.exists()


def test_keep_checkpoints_keeps_each_step(tmp_path):
    from reshader_train.synthetic import write_dataset

    data = tmp_path / "data"
    write_dataset(data, count=2)
    run = tmp_path / "run"
    args = [
        "train", "--data", str(data), "--run-dir", str(run), "--size", TINY, "--steps", "4",
        "--batch-size", "1", "--crop", "32", "--workers", "0", "--threads", "1",
        "--loss-weights", "1,0,0", "--checkpoint-every", "2", "--keep-checkpoints",
        "--no-progress",
    ]  # fmt: skip
    assert main(args) == 0
    assert sorted(p.name for p in run.glob("checkpoint-*.pt")) == [
        "checkpoint-2.pt",
        "checkpoint-4.pt",
    ]
