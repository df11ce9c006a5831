import math

import h5py
import pytest
import torch

from reshader_train.features import (
    VGG19_CFG,
    FeatureNetError,
    _vgg_stack,
    hed_weights_path,
    load_feature_net,
    load_hed_vgg16,
    load_vgg19,
)
from reshader_train.losses import LossWeights, ReshadeLoss, gram


@pytest.fixture(scope="module")
def hed():
    return load_hed_vgg16()


def test_hed_features_are_deterministic_and_non_trivial(hed):
    g = torch.Generator().manual_seed(0)
    a = torch.rand(1, 3, 32, 32, generator=g)
    b = torch.rand(1, 3, 32, 32, generator=g)
    fa = hed(a)
    assert fa.shape == (1, 512, 4, 4)  # conv4_3 at 1/8
    assert torch.equal(fa, hed(a))
    assert fa.std() > 1e-3
    assert (fa - hed(b)).abs().mean() > 0.05 * fa.abs().mean()
    assert "hed-vgg16" in hed.ident and "conv4_3" in hed.ident
    assert not any(p.requires_grad for p in hed.parameters())


def test_hed_kernels_are_mapped_like_keras(hed):
    # conv1_1 at one pixel, computed by hand from the HDF5 kernel (kh, kw, in, out), must
    # equal the torch layer's output: checks the transpose and the BGR/mean convention.
    with h5py.File(hed_weights_path(), "r") as f:
        kernel = torch.from_numpy(f["block1/layers/conv2d/vars/0"][()])
        bias = torch.from_numpy(f["block1/layers/conv2d/vars/1"][()])
    rgb = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(3))
    caffe = rgb.flip(1) * 255 - torch.tensor([104.00699, 116.66877, 122.67892]).view(1, 3, 1, 1)
    patch = caffe[0, :, 3:6, 4:7].permute(1, 2, 0)  # (3, 3, in) around pixel (4, 5)
    manual = torch.einsum("hwi,hwio->o", patch, kernel) + bias
    torch_out = hed.features[0](caffe)[0, :, 4, 5]
    assert torch.allclose(manual, torch_out, atol=1e-3)


def test_vgg19_state_dict_loads_and_bad_ones_are_refused(tmp_path):
    stack = _vgg_stack(VGG19_CFG)
    state = {f"features.{k}": v for k, v in stack.state_dict().items()}
    good = tmp_path / "vgg19-test.pth"
    torch.save(state, good)
    net = load_vgg19(good)
    assert "vgg19" in net.ident and "conv4_4" in net.ident
    assert net(torch.rand(1, 3, 16, 16)).shape == (1, 512, 2, 2)
    state["features.0.weight"] = torch.zeros(64, 3, 5, 5)
    bad = tmp_path / "bad.pth"
    torch.save(state, bad)
    with pytest.raises(FeatureNetError, match="bad.pth.*features.0.weight"):
        load_vgg19(bad)
    with pytest.raises(FeatureNetError, match="not found"):
        load_vgg19(tmp_path / "missing.pth")


def test_feature_net_choice(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    with pytest.raises(FeatureNetError, match="--vgg-weights"):
        load_feature_net("vgg19")
    assert "hed-vgg16" in load_feature_net("auto").ident
    (tmp_path / "hub/checkpoints").mkdir(parents=True)
    stack = _vgg_stack(VGG19_CFG)
    torch.save(
        {f"features.{k}": v for k, v in stack.state_dict().items()},
        tmp_path / "hub/checkpoints/vgg19-dcbb9e9d.pth",
    )
    assert "vgg19" in load_feature_net("auto").ident


def test_gram_of_known_features():
    f = torch.tensor([[[[1.0, 2.0]], [[3.0, 4.0]]]])  # (1, 2, 1, 2)
    expected = torch.tensor([[[5.0, 11.0], [11.0, 25.0]]]) / 4
    assert torch.allclose(gram(f), expected)


def test_loss_zero_on_match_masked_and_differentiable(hed):
    loss_fn = ReshadeLoss(hed)
    g = torch.Generator().manual_seed(1)
    target = torch.rand(2, 3, 32, 32, generator=g)
    mask = torch.ones(2, 1, 32, 32)
    mask[..., :, 16:] = 0
    same, parts = loss_fn(target.clone(), target, mask)
    assert float(same) == 0.0 and parts["pixel"] == 0.0
    hidden = target.clone()
    hidden[..., :, 16:] = 0.0  # differs from target only where the mask is 0
    assert float(loss_fn(hidden, target, mask)[0]) == 0.0
    pred = (target + 0.1 * torch.randn(2, 3, 32, 32, generator=g)).requires_grad_()
    total, parts = loss_fn(pred, target, mask)
    assert parts["pixel"] > 0 and parts["vgg"] > 0 and parts["style"] > 0
    total.backward()
    assert pred.grad.abs().sum() > 0
    assert pred.grad[..., :, 16:].abs().sum() == 0  # masked pixels get no gradient


def test_bfloat16_features_track_float32(hed):
    g = torch.Generator().manual_seed(2)
    target = torch.rand(1, 3, 32, 32, generator=g)
    pred = (target + 0.1 * torch.randn(1, 3, 32, 32, generator=g)).requires_grad_()
    mask = torch.ones(1, 1, 32, 32)
    _, p32 = ReshadeLoss(hed)(pred, target, mask)
    total, p16 = ReshadeLoss(hed, feature_dtype=torch.bfloat16)(pred, target, mask)
    assert p16["vgg"] == pytest.approx(p32["vgg"], rel=0.1)
    assert p16["style"] == pytest.approx(p32["style"], rel=0.1)
    total.backward()
    assert pred.grad.abs().sum() > 0


def test_loss_weights_parse_and_refuse():
    w = LossWeights.parse("0.1,0,0")
    assert (w.pixel, w.vgg, w.style) == (0.1, 0.0, 0.0) and not w.needs_features
    assert LossWeights.parse(str(LossWeights())) == LossWeights()
    for bad in ("0.1,0", "a,b,c", "0,0,0", "-1,0,0"):
        with pytest.raises(ValueError, match="--loss-weights"):
            LossWeights.parse(bad)


def test_pixel_only_loss_runs_without_a_feature_network(hed):
    with pytest.raises(ValueError, match="feature network"):
        ReshadeLoss(None, LossWeights())
    pixels = ReshadeLoss(None, LossWeights.parse("0.1,0,0"))
    g = torch.Generator().manual_seed(2)
    target = torch.rand(1, 3, 16, 16, generator=g)
    pred = (target + 0.05 * torch.randn(1, 3, 16, 16, generator=g)).requires_grad_()
    mask = torch.ones(1, 1, 16, 16)
    total, parts = pixels(pred, target, mask)
    assert parts["vgg"] == 0.0 and parts["style"] == 0.0
    assert float(total) == pytest.approx(0.1 * parts["pixel"])
    full_total, _ = ReshadeLoss(hed)(pred, target, mask)
    assert float(full_total) > float(total)


def test_l2_pixel_loss_is_the_masked_mean_squared_error():
    target = torch.zeros(1, 3, 4, 4)
    pred = torch.full((1, 3, 4, 4), 0.5)
    mask = torch.ones(1, 1, 4, 4)
    mask[..., :2, :] = 0
    loss = ReshadeLoss(None, LossWeights.parse("1,0,0"), pixel="l2")
    total, parts = loss(pred, target, mask)
    assert parts["pixel"] == pytest.approx(0.125)  # half the pixels masked: 0.25 * 0.5
    with pytest.raises(ValueError, match="pixel loss"):
        ReshadeLoss(None, LossWeights.parse("1,0,0"), pixel="l3")


def test_psnr_pixel_loss_is_minus_the_mean_per_sample_psnr():
    target = torch.zeros(2, 3, 4, 4)
    pred = torch.zeros(2, 3, 4, 4)
    pred[0] = 0.1  # 20 dB
    pred[1] = 0.01  # 40 dB
    mask = torch.ones(2, 1, 4, 4)
    _, parts = ReshadeLoss(None, LossWeights.parse("1,0,0"), pixel="psnr")(pred, target, mask)
    psnr = [10 * math.log10(1 / (mse + 1e-8)) for mse in (1e-2, 1e-4)]  # eps caps at 80 dB
    assert parts["pixel"] == pytest.approx(-sum(psnr) / 2, abs=1e-3)


def test_psnr_pixel_loss_still_rewards_images_above_50_db():
    # Unchanged images reach ~60 dB in validation; the loss must keep pushing there.
    target = torch.zeros(1, 3, 4, 4)
    mask = torch.ones(1, 1, 4, 4)
    loss = ReshadeLoss(None, LossWeights.parse("1,0,0"), pixel="psnr")
    at_50 = loss(torch.full_like(target, 10**-2.5), target, mask)[1]["pixel"]
    at_60 = loss(torch.full_like(target, 1e-3), target, mask)[1]["pixel"]
    assert at_60 < at_50 - 9.0


def test_relative_l2_weighs_each_crop_by_its_own_change():
    from reshader_train.losses import RELATIVE_FLOOR_DB, relative_l2

    image = torch.full((2, 3, 8, 8), 0.5)
    target = image.clone()
    target[0] += 0.1  # crop 0 changes by 0.1, crop 1 not at all
    wrong = torch.full_like(image, 0.01)
    floor = 10.0 ** (-RELATIVE_FLOOR_DB / 10.0)
    # The same absolute error costs far more on the crop that does not change.
    err_on_static = relative_l2(target + wrong * torch.tensor([0.0, 1.0])[:, None, None, None],
                                target, image)  # fmt: skip
    err_on_changed = relative_l2(target + wrong * torch.tensor([1.0, 0.0])[:, None, None, None],
                                 target, image)  # fmt: skip
    assert float(err_on_static) == pytest.approx(0.5 * 1e-4 / floor, rel=1e-4)
    assert float(err_on_changed) == pytest.approx(0.5 * 1e-4 / (0.01 + floor), rel=1e-4)
    assert err_on_static > 100 * err_on_changed
    assert float(relative_l2(target, target, image)) == 0.0


def test_relative_l2_needs_the_input_image():
    loss = ReshadeLoss(None, LossWeights(1, 0, 0), pixel="rel-l2")
    x = torch.rand(1, 3, 8, 8)
    mask = torch.ones(1, 1, 8, 8)
    with pytest.raises(ValueError, match="needs the input image"):
        loss(x, x, mask)
    total, parts = loss(x, x + 0.1, mask, x)
    assert parts["pixel"] == pytest.approx(0.01 / (0.01 + 10**-4.5), rel=1e-3)


def test_relative_l2_floor_is_set_by_the_loss_name():
    x = torch.rand(1, 3, 8, 8)
    mask = torch.ones(1, 1, 8, 8)
    still = x.clone()  # the truth does not change: only the floor weighs the error
    _, at45 = ReshadeLoss(None, LossWeights(1, 0, 0), pixel="rel-l2")(x + 0.01, still, mask, x)
    _, at55 = ReshadeLoss(None, LossWeights(1, 0, 0), pixel="rel-l2:55")(x + 0.01, still, mask, x)
    assert at45["pixel"] == pytest.approx(1e-4 / 10**-4.5, rel=1e-3)
    assert at55["pixel"] == pytest.approx(1e-4 / 10**-5.5, rel=1e-3)
    for bad in ("rel-l2:high", "l2:50", "l3"):
        with pytest.raises(ValueError, match="pixel loss"):
            ReshadeLoss(None, LossWeights(1, 0, 0), pixel=bad)
