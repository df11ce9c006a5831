import argparse
import csv
import json

import pytest
import torch

from reshader_train import cli
from reshader_train.data import Augment, list_examples
from reshader_train.synthetic import write_dataset
from reshader_train.train import Compute, lr_at, train

TINY = "4,8,8,16,16,16"


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    return write_dataset(root / "train", 4, 32, 32, seed=0), write_dataset(
        root / "val", 2, 32, 32, seed=1
    )


def train_args(data, run_dir, steps, **kw):
    parser = argparse.ArgumentParser()
    from reshader_train.train import add_arguments

    add_arguments(parser)
    argv = [
        "--data",
        str(data[0]),
        "--val-data",
        str(data[1]),
        "--run-dir",
        str(run_dir),
        "--size",
        TINY,
        "--steps",
        str(steps),
        "--batch-size",
        "2",
        "--crop",
        "32",
        "--workers",
        "0",
        "--threads",
        "1",
        "--log-every",
        "1",
        "--checkpoint-every",
        "2",
        "--val-every",
        "3",
        "--no-progress",
    ]
    for k, v in kw.items():
        argv += [f"--{k.replace('_', '-')}"] + ([] if v is True else [str(v)])
    return parser.parse_args(argv)


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_lr_schedule_scales_with_run_length():
    args = argparse.Namespace(lr=1e-4, lr_final=1e-5, lr_drop=0.6, steps=100)
    assert lr_at(0, args) == 1e-4 and lr_at(59, args) == 1e-4 and lr_at(60, args) == 1e-5
    args.steps = 10
    assert lr_at(5, args) == 1e-4 and lr_at(6, args) == 1e-5


def test_train_writes_run_dir_and_resumes(data, tmp_path):
    run = tmp_path / "run"
    torch.manual_seed(0)
    net = train(train_args(data, run, 4))
    ckpt = torch.load(run / "checkpoint.pt", weights_only=False)
    assert ckpt["step"] == 4
    assert "hed-vgg16" in ckpt["feature_net"]
    config = json.loads((run / "config.json").read_text())
    assert config["net_config"]["widths"] == [4, 8, 8, 16, 16, 16]
    assert config["feature_net"] == ckpt["feature_net"]
    log = read_csv(run / "log.csv")
    assert [int(r["step"]) for r in log] == [1, 2, 3, 4]
    assert all(float(r["loss"]) > 0 for r in log)
    assert [int(r["step"]) for r in read_csv(run / "val.csv")] == [3, 4]
    trained = {k: v.clone() for k, v in net.state_dict().items()}
    assert all(torch.equal(trained[k], v) for k, v in ckpt["model"].items())

    with open(run / "log.csv", "a") as f:  # as if killed after step 4, before a checkpoint
        f.write("5,0.0001,1,1,1,1,4,1,1\n")
    net2 = train(train_args(data, run, 6))
    assert torch.load(run / "checkpoint.pt", weights_only=False)["step"] == 6
    assert [int(r["step"]) for r in read_csv(run / "log.csv")] == [1, 2, 3, 4, 5, 6]
    config = json.loads((run / "config.json").read_text())
    assert config["resumed_from_step"] == 4
    assert [h["from_step"] for h in config["history"]] == [0, 4]
    assert any(not torch.equal(trained[k], v) for k, v in net2.state_dict().items())


def test_resume_refuses_another_network(data, tmp_path):
    run = tmp_path / "run"
    train(train_args(data, run, 1))
    with pytest.raises(ValueError, match="use another --run-dir"):
        train(train_args(data, run, 2, size="4,8,8,16,16,32"))


def test_cli_reports_bad_data(tmp_path, capsys):
    code = cli.main(
        [
            "train",
            "--data",
            str(tmp_path / "none"),
            "--run-dir",
            str(tmp_path / "r"),
            "--size",
            TINY,
            "--steps",
            "1",
            "--workers",
            "0",
        ]
    )
    assert code == 2
    assert "none: dataset folder does not exist" in capsys.readouterr().err


def test_rescan_picks_up_new_examples(data, tmp_path, monkeypatch):
    import reshader_train.train as train_module

    calls = []

    def growing(root):
        calls.append(root)
        folders = list_examples(root)
        return folders[:2] if len(calls) == 1 else folders

    monkeypatch.setattr(train_module, "list_examples", growing)
    run = tmp_path / "run"
    train(train_args(data, run, 3, rescan=True))
    assert [int(r["examples"]) for r in read_csv(run / "log.csv")] == [2, 4, 4]


def test_several_data_folders_are_pooled_and_a_repeated_one_weighs_more(data, tmp_path):
    from reshader_train.train import add_arguments, setup_distributed, shared_example_list

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    argv = ["--run-dir", str(tmp_path), "--data", str(data[0]), str(data[1]), str(data[1])]
    args = parser.parse_args(argv)
    folders = shared_example_list(args, setup_distributed("cpu"))
    assert len(folders) == 4 + 2 * 2
    assert folders.count(list_examples(data[1])[0]) == 2
    pooled = train_args(data, tmp_path / "pooled", 2)
    pooled.data = [data[0], data[1]]
    train(pooled)
    assert [int(r["examples"]) for r in read_csv(tmp_path / "pooled" / "log.csv")] == [6, 6]


def test_pixel_only_training_records_its_loss(data, tmp_path):
    run = tmp_path / "pixels"
    train(train_args(data, run, 2, loss_weights="0.1,0,0", pixel_loss="l2"))
    ckpt = torch.load(run / "checkpoint.pt", weights_only=False)
    assert ckpt["feature_net"] == "none" and ckpt["loss_weights"] == "0.1,0,0"
    assert ckpt["pixel_loss"] == "l2"
    log = read_csv(run / "log.csv")
    assert all(float(r["vgg"]) == 0.0 and float(r["style"]) == 0.0 for r in log)


def test_bf16_and_channels_last_train_float32_weights_from_a_bfloat16_forward(data, tmp_path):
    compute = Compute(bf16=True, channels_last=True)
    conv = torch.nn.Conv2d(3, 4, 3)
    b = compute.batch({"image": torch.rand(1, 3, 8, 8), "camera": torch.rand(1, 3)})
    assert b["image"].is_contiguous(memory_format=torch.channels_last)
    assert b["camera"].shape == (1, 3)
    with compute.autocast(torch.device("cpu")):
        assert conv(b["image"]).dtype == torch.bfloat16
    with Compute().autocast(torch.device("cpu")):
        assert conv(b["image"]).dtype == torch.float32
    weights = {}
    for name, flags in (("fp32", {}), ("bf16", {"bf16": True, "channels_last": True})):
        train(train_args(data, tmp_path / name, 3, **flags))
        weights[name] = torch.load(tmp_path / name / "checkpoint.pt", weights_only=False)["model"]
    assert all(v.dtype == torch.float32 for v in weights["bf16"].values() if v.is_floating_point())
    # The same seed and steps: near the same weights, but not bit for bit.
    a, b = weights["fp32"]["decoder.out.weight"], weights["bf16"]["decoder.out.weight"]
    assert not torch.equal(a, b) and torch.allclose(a, b, atol=1e-2)


def test_head_and_deadzone_reach_the_checkpoint(data, tmp_path):
    run = tmp_path / "linear"
    train(train_args(data, run, 2, head="camera-linear", deadzone=0.004))
    ckpt = torch.load(run / "checkpoint.pt", weights_only=False)
    assert ckpt["net_config"]["head"] == "camera-linear"
    assert ckpt["net_config"]["deadzone"] == 0.004
    assert ckpt["model"]["decoder.out.weight"].shape[0] == 9


def test_rescan_decodes_each_example_once(data, tmp_path, monkeypatch):
    import reshader_train.data as data_module
    import reshader_train.train as train_module

    calls, decoded = [], []
    real_load = data_module.load_example

    def growing(root):
        calls.append(root)
        folders = list_examples(root)
        return folders[:2] if len(calls) == 1 else folders

    def counting(folder):
        decoded.append(folder)
        return real_load(folder)

    monkeypatch.setattr(train_module, "list_examples", growing)
    monkeypatch.setattr(data_module, "load_example", counting)
    args = train_args(data, tmp_path / "run", 4, rescan=True, loss_weights="1,0,0")
    train(args)
    decoded = [f for f in decoded if f.parent == data[0]]
    assert len(decoded) == len(set(decoded)) == 4


def test_dihedral_reaches_the_loader_and_quantize(data, tmp_path, monkeypatch):
    import reshader_train.train as train_module
    from reshader_train.quantize import augment_of

    made = []
    real = train_module.Augment
    monkeypatch.setattr(train_module, "Augment", lambda **kw: made.append(kw) or real(**kw))
    run = tmp_path / "dihedral"
    train(train_args(data, run, 2, dihedral=True, gamma="2.2,3"))
    assert made and all(kw["dihedral"] and kw["gamma"] == (2.2, 3.0) for kw in made)
    ckpt = torch.load(run / "checkpoint.pt", weights_only=False)
    assert augment_of(ckpt).dihedral
    assert augment_of(ckpt).gamma == (2.2, 3.0)
    assert augment_of(ckpt).exposure == Augment().exposure
    assert not augment_of({"args": {}}).dihedral


def test_lobe_head_trains_validates_and_reaches_the_checkpoint(data, tmp_path):
    run = tmp_path / "lobes"
    train(train_args(data, run, 3, head="lobes", lobes=3, loss_weights="1,0,0"))
    ckpt = torch.load(run / "checkpoint.pt", weights_only=False)
    assert ckpt["net_config"]["head"] == "lobes"
    assert ckpt["net_config"]["lobes"] == 3
    assert ckpt["model"]["decoder.out.weight"].shape[0] == 21
    assert not any(k.startswith("decoder.camera.") for k in ckpt["model"])
    (row,) = read_csv(run / "val.csv")
    assert float(row["psnr_ours"]) > 0


def test_head_lr_scale_moves_the_output_conv_faster_and_resumes(data, tmp_path, monkeypatch):
    from reshader_train import train as train_module

    seen = []
    step = train_module.train_step

    def spy(model, criterion, opt, *rest):
        seen.append([(len(g["params"]), g["lr"]) for g in opt.param_groups])
        return step(model, criterion, opt, *rest)

    monkeypatch.setattr(train_module, "train_step", spy)
    run = tmp_path / "slide"
    args = dict(head="lobes-slide", loss_weights="1,0,0", lr=1e-4, lr_drop=1, head_lr_scale=10)
    train(train_args(data, run, 2, **args))
    train(train_args(data, run, 3, **args))  # resumed with its two groups
    assert len(seen) == 3
    (rest, rest_lr), (head, head_lr) = seen[-1]
    assert head == 2 and rest > 2 and rest_lr == pytest.approx(1e-4)
    assert head_lr == pytest.approx(1e-3)


@pytest.fixture(scope="module")
def three_targets(tmp_path_factory):
    """Three analytic examples with three targets each (32x32)."""
    out = tmp_path_factory.mktemp("multi") / "analytic"
    argv = ["render", "--scenes", "analytic", "--out", str(out), "--count", "3"]
    assert cli.main([*argv, "--size", "32x32", "--spp", "1", "--targets", "3"]) == 0
    return out


@pytest.mark.parametrize("head", ["lobes", "residual"])
def test_several_targets_per_example_train_on_mixed_data(data, three_targets, tmp_path, head):
    run = tmp_path / head
    args = train_args(data, run, 3, head=head, targets_per_example=2, loss_weights="1,0,0")
    args.data = [three_targets, data[0]]  # three targets each, and one
    train(args)
    log = read_csv(run / "log.csv")
    assert len(log) == 3 and all(float(r["loss"]) > 0 for r in log)
    config = json.loads((run / "config.json").read_text())
    assert config["args"]["targets_per_example"] == 2
    (row,) = read_csv(run / "val.csv")
    assert float(row["psnr_ours"]) > 0


def test_the_loss_over_n_targets_is_the_mean_of_the_per_target_losses(data, three_targets):
    from torch.utils.data import DataLoader

    from reshader_train.data import Augment, ReshadeDataset
    from reshader_train.losses import LossWeights, ReshadeLoss, multi_target_loss
    from reshader_train.model import NetConfig, ReshadeNet, net_config

    folders = list_examples(three_targets) + list_examples(data[0])[:1]
    ds = ReshadeDataset(folders, crop=32, augment=Augment(), targets=2)
    torch.manual_seed(0)
    batch = next(iter(DataLoader(ds, batch_size=4)))
    assert batch["targets"].shape == (4, 2, 3, 32, 32)
    assert batch["weights"].tolist() == [[1, 1], [1, 1], [1, 1], [1, 0]]
    for head in ("lobes", "residual"):
        cfg: NetConfig = net_config(TINY)
        net = ReshadeNet(NetConfig(**{**cfg.to_json(), "head": head}))
        torch.nn.init.normal_(net.decoder.out.weight, std=0.1)  # a prediction that differs
        b = batch
        with torch.no_grad():
            pred = net(b["image"], b["disparity"], b["cameras"], b["rays"])
        for pixel in ("l1", "rel-l2"):
            criterion = ReshadeLoss(None, LossWeights(1, 0, 0), pixel=pixel)
            loss, _ = multi_target_loss(
                criterion, pred, b["targets"], b["masks"], b["weights"], b["image"]
            )
            per_target = []
            for i in range(4):
                for k in range(2):
                    if b["weights"][i, k] == 0:
                        continue
                    with torch.no_grad():
                        one = net(b["image"][i : i + 1], b["disparity"][i : i + 1],
                                  b["cameras"][i : i + 1, k], b["rays"][i : i + 1])  # fmt: skip
                    # batch of one vs four: the convolutions may sum in another order
                    assert torch.allclose(one[0], pred[i, k], atol=1e-5)
                    t, m = b["targets"][i : i + 1, k], b["masks"][i : i + 1, k]
                    per_target.append(criterion(one, t, m, b["image"][i : i + 1])[0])
            assert len(per_target) == 7
            assert float(loss) == pytest.approx(float(torch.stack(per_target).mean()), rel=1e-5)


def test_a_log_from_before_a_new_column_is_rewritten_with_it(tmp_path):
    from reshader_train.train import LOG_FIELDS, append_csv, truncate_csv

    path = tmp_path / "log.csv"
    old = LOG_FIELDS[:-1]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=old)
        w.writeheader()
        w.writerow({k: 1 for k in old})
    truncate_csv(path, 1, LOG_FIELDS)  # what a resumed run does first
    append_csv(path, LOG_FIELDS, {k: 2 for k in LOG_FIELDS})
    first, second = read_csv(path)
    assert first[LOG_FIELDS[-1]] == "" and first["loss"] == "1"
    assert second[LOG_FIELDS[-1]] == "2"


def test_tone_curve_ranges_reach_the_samples(data, tmp_path):
    from reshader_train.train import make_loader, setup_distributed

    args = train_args(data, tmp_path / "run", 1, exposure="5.5", gamma="2.2,2.4")
    assert args.exposure == (5.5, 5.5) and args.gamma == (2.2, 2.4)
    dataset = make_loader(args, setup_distributed("cpu"), list_examples(data[0]))[0]
    assert dataset.augment.exposure == (5.5, 5.5) and dataset.augment.gamma == (2.2, 2.4)
    for bad in ("10,3", "a,b", "1,2,3", "0,2"):
        with pytest.raises(SystemExit):
            train_args(data, tmp_path / "run", 1, gamma=bad)
