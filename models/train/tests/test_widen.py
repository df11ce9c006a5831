import argparse
from dataclasses import replace

import pytest
import torch

from reshader_train.export import ExportInfo, export_precision
from reshader_train.model import SIZES, ReshadeNet, net_config
from reshader_train.train import initialise
from reshader_train.widen import widen_into

NARROW = replace(net_config("4,8,8,16,16,16"), convs=(1, 1, 2, 2, 2, 2))
WIDE = replace(NARROW, widths=(6, 8, 12, 20, 24, 16))


def trained(cfg, seed=0):
    torch.manual_seed(seed)
    net = ReshadeNet(cfg).eval()
    for p in net.parameters():  # distinct values, and a visible residual
        p.data.normal_(0.0, 0.3)
    return net


def feed():
    g = torch.Generator().manual_seed(1)
    return torch.rand(1, 3, 32, 64, generator=g), torch.rand(1, 1, 32, 64, generator=g)


def test_a_widened_network_computes_the_narrow_ones_image_until_trained():
    narrow, wide = trained(NARROW), ReshadeNet(WIDE).eval()
    widen_into(wide, narrow)
    image, disparity = feed()
    cam = torch.tensor([[0.2, -0.1, 0.1]])
    with torch.no_grad():
        ref = narrow(image, disparity, cam)
        got = wide(image, disparity, cam)
    assert (ref - image).abs().max() > 0.05
    assert torch.allclose(got, ref, atol=5e-4)  # summation order only
    # The added channels are live: one of them, read by the output, changes the image.
    with torch.no_grad():
        wide.decoder.out.weight[:, 4:] = 0.5
        assert (wide(image, disparity, cam) - ref).abs().max() > 1e-2


def test_widening_refuses_a_narrower_or_different_network():
    narrow = ReshadeNet(NARROW)
    with pytest.raises(ValueError, match="narrower"):
        widen_into(narrow, ReshadeNet(WIDE))
    with pytest.raises(ValueError, match="convs"):
        widen_into(ReshadeNet(replace(WIDE, convs=(1,) * 6)), narrow)
    assert SIZES["wide"].convs == SIZES["lite"].convs
    assert all(w > n for w, n in zip(SIZES["wide"].widths, SIZES["lite"].widths, strict=True))


def test_training_starts_a_wider_network_from_an_exported_narrow_pair(tmp_path):
    narrow = trained(replace(NARROW, deadzone=0.008))
    info = ExportInfo(size="narrow", validation={})
    export_precision(narrow, "fp32", tmp_path, "n", info, True, 32, 64)
    files = [tmp_path / "n-encoder.onnx", tmp_path / "n-decoder.onnx"]
    wide = ReshadeNet(replace(WIDE, deadzone=0.008)).eval()
    args = argparse.Namespace(init_from=files, init_widen=True, init_partial=False)
    assert initialise(wide, args) > 0
    image, disparity = feed()
    cam = torch.tensor([[0.1, 0.0, 0.2]])
    with torch.no_grad():
        got, ref = wide(image, disparity, cam), narrow(image, disparity, cam)
    assert torch.allclose(got, ref, atol=5e-4)  # summation order only
