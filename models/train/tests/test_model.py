import math
from dataclasses import replace

import pytest
import torch

from reshader_train.model import (
    AMPLITUDE_MAX,
    LINEAR_GAMMA,
    LOBE_FLOW_MAX,
    SHARPNESS_RANGE,
    SIZES,
    SLIDE_DEPTH_INIT,
    DecoderGraph,
    EncoderGraph,
    LobeGraph,
    NetConfig,
    ReshadeNet,
    conv_flops,
    count_parameters,
    encode_disparity,
    net_config,
    shade_lobes,
    view_directions,
)

TINY = net_config("4,8,8,16,16,16")


def inputs(h=32, w=64, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, 3, h, w, generator=g), torch.rand(1, 1, h, w, generator=g)


def test_disparity_encoding_channels_and_values():
    d = torch.full((1, 1, 2, 2), 0.5)
    enc = encode_disparity(d)
    assert enc.shape == (1, 11, 2, 2)
    expected = [0.5]
    for i in range(5):
        expected += [math.sin(2**i * 0.5), math.cos(2**i * 0.5)]
    assert torch.allclose(enc[0, :, 0, 0], torch.tensor(expected))


def test_output_shape_and_alignment_check():
    net = ReshadeNet(TINY)
    image, disp = inputs()
    assert net(image, disp, torch.zeros(1, 3)).shape == (1, 3, 32, 64)
    with pytest.raises(ValueError, match="multiples of 32"):
        net(image[..., :48], disp[..., :48], torch.zeros(1, 3))


def test_starts_near_identity():
    torch.manual_seed(0)
    net = ReshadeNet(TINY).eval()
    image, disp = inputs()
    out = net(image, disp, torch.tensor([[0.2, 0.0, 0.1]]))
    assert (out - image).abs().max() < 0.02


def test_camera_changes_output_and_is_deterministic():
    torch.manual_seed(0)
    net = ReshadeNet(TINY).eval()
    torch.nn.init.normal_(net.decoder.out.weight, std=0.1)
    image, disp = inputs()
    a = net(image, disp, torch.tensor([[0.3, 0.0, 0.0]]))
    b = net(image, disp, torch.tensor([[-0.3, 0.0, 0.0]]))
    assert (a - b).abs().max() > 1e-4
    assert torch.equal(a, net(image, disp, torch.tensor([[0.3, 0.0, 0.0]])))


def test_split_graphs_match_single_network():
    torch.manual_seed(1)
    net = ReshadeNet(TINY).eval()
    torch.nn.init.normal_(net.decoder.out.weight, std=0.1)
    image, disp = inputs()
    cam = torch.tensor([[0.1, -0.2, 0.05]])
    enc_out = EncoderGraph(net)(image, disp)
    assert len(enc_out) == len(EncoderGraph.output_names)
    assert enc_out[0].shape[-2:] == (1, 2)  # bottleneck at H/32
    split = DecoderGraph(net)(image, *enc_out, cam)
    assert torch.allclose(split, net(image, disp, cam), atol=1e-6)


def test_named_sizes():
    full = count_parameters(ReshadeNet(SIZES["full"]))
    lite = count_parameters(ReshadeNet(SIZES["lite"]))
    assert 18e6 < full < 27e6
    assert lite < full / 10
    assert SIZES["full"].widths == (32, 64, 128, 256, 512, 512)


def test_flops_scale_with_pixels():
    net = ReshadeNet(TINY)
    small = conv_flops(net, 32, 32)
    big = conv_flops(net, 64, 64)
    assert small["encoder"] > 0 and small["decoder"] > 0
    assert big["encoder"] == pytest.approx(4 * small["encoder"])
    # The first encoder conv alone: 14 -> 4 channels, 3x3, over 32x32 pixels.
    assert small["encoder"] > 2 * 14 * 4 * 9 * 32 * 32


def test_config_parsing_and_json_round_trip():
    assert NetConfig.from_json(SIZES["lite"].to_json()) == SIZES["lite"]
    with pytest.raises(ValueError, match="unknown network size"):
        net_config("huge")
    with pytest.raises(ValueError):
        net_config("4,8")


def linear_net(deadzone=0.0, seed=0):
    torch.manual_seed(seed)
    cfg = NetConfig(TINY.widths, TINY.convs, TINY.camera_hidden, "camera-linear", deadzone)
    net = ReshadeNet(cfg).eval()
    torch.nn.init.normal_(net.decoder.out.weight, std=0.05)
    return net


def test_camera_linear_head_is_the_photo_at_the_input_camera():
    net = linear_net()
    image, disp = inputs()
    assert torch.equal(net(image, disp, torch.zeros(1, 3)), image)
    assert (net(image, disp, torch.tensor([[0.2, 0.0, 0.0]])) - image).abs().max() > 1e-3


def test_camera_linear_head_contracts_the_jacobian_with_the_offset():
    net = linear_net()
    image, disp = inputs()
    captured = []
    net.decoder.out.register_forward_hook(lambda _m, _i, out: captured.append(out))
    cam = torch.tensor([[0.1, -0.05, 0.2]])
    change = net(image, disp, cam) - image
    (jac,) = captured
    assert jac.shape == (1, 9, 32, 64)
    expected = sum(jac[:, 3 * k : 3 * k + 3] * float(cam[0, k]) / 0.2 for k in range(3))
    assert torch.allclose(change, torch.tanh(expected), atol=1e-6)


def test_deadzone_makes_small_residuals_exactly_zero_and_keeps_gradients():
    net = linear_net(deadzone=0.01, seed=3)
    image, disp = inputs()
    cam = torch.tensor([[0.3, 0.0, 0.0]])
    free = linear_net(deadzone=0.0, seed=3)
    change, free_change = net(image, disp, cam) - image, free(image, disp, cam) - image
    small = free_change.abs() <= 0.01
    assert small.any() and (~small).any()
    assert torch.all(change[small] == 0)
    big = ~small
    assert torch.allclose(change[big], free_change[big] - 0.01 * free_change[big].sign(), atol=1e-6)
    # Straight through: the gradient reaches the last layer even where every output is 0.
    net.train()
    out = net(image, disp, cam * 1e-3)
    assert torch.equal(out, image)
    ((out - image - 0.5) ** 2).mean().backward()
    assert net.decoder.out.weight.grad.abs().max() > 0


def test_configs_without_a_head_load_as_the_papers_network():
    old = {"widths": [4, 8, 8, 16, 16, 16], "convs": [1] * 6, "camera_hidden": [16]}
    cfg = NetConfig.from_json(old)
    assert cfg.head == "residual" and cfg.deadzone == 0.0 and cfg.out_channels == 3
    with pytest.raises(ValueError, match="unknown output head"):
        NetConfig(TINY.widths, head="sideways")
    with pytest.raises(ValueError, match="dead zone"):
        NetConfig(TINY.widths, deadzone=-0.1)


def test_image_gradient_is_central_differences_with_replicated_edges():
    from reshader_train.model import ImageGradient

    x = torch.arange(8.0)[None, None, None, :].expand(1, 3, 4, 8) * 0.1
    gx, gy = ImageGradient()(x)
    assert torch.allclose(gx[..., 1:-1], torch.full_like(gx[..., 1:-1], 0.1))
    assert torch.allclose(gx[..., 0], torch.full_like(gx[..., 0], 0.05))
    assert torch.equal(gy, torch.zeros_like(gy))


def test_flow_head_moves_a_ramp_by_the_predicted_shift():
    from reshader_train.model import FLOW_MAX_PX

    cfg = NetConfig(TINY.widths, TINY.convs, TINY.camera_hidden, "flow")
    net = ReshadeNet(cfg).eval()
    # No Jacobian term; a constant shift of 1 px along x per unit of tx / 0.2.
    torch.nn.init.zeros_(net.decoder.out.weight)
    bias = torch.zeros(15)
    bias[9] = math.atanh(1.0 / FLOW_MAX_PX)
    net.decoder.out.bias.data.copy_(bias)
    ramp = 0.2 + 0.01 * torch.arange(64.0)[None, None, None, :].expand(1, 3, 32, 64)
    disp = torch.zeros(1, 1, 32, 64)
    assert torch.equal(net(ramp, disp, torch.zeros(1, 3)), ramp)
    change = net(ramp, disp, torch.tensor([[0.1, 0.0, 0.0]])) - ramp
    # Shifting I = 0.01 x by 0.5 px to the right lowers it by 0.005 (tanh(0.005) ~ 0.005).
    inner = change[..., 1:-1]
    assert torch.allclose(inner, torch.full_like(inner, math.tanh(-0.005)), atol=1e-6)
    assert net(ramp, disp, torch.tensor([[0.0, 0.2, 0.0]])).sub(ramp).abs().max() == 0


def test_size_names_ignore_head_and_dead_zone():
    from dataclasses import replace

    from reshader_train.export import size_name

    assert size_name(replace(SIZES["lite"], deadzone=0.004, head="flow")) == "lite"
    assert size_name(TINY) == "custom"


def lobe_net(lobes=2, seed=0):
    torch.manual_seed(seed)
    net = ReshadeNet(replace(TINY, head="lobes", lobes=lobes)).eval()
    torch.nn.init.normal_(net.decoder.out.weight, std=0.3)
    return net


def centred_rays(h=32, w=64, f=40.0):
    v, u = torch.meshgrid(
        torch.arange(h) - (h - 1) / 2, torch.arange(w) - (w - 1) / 2, indexing="ij"
    )
    return torch.stack([u / f, v / f, torch.ones(h, w)])[None]


def test_lobe_head_is_the_photo_at_the_input_camera_and_takes_no_camera_features():
    net = lobe_net()
    assert net.decoder.camera is None
    image, disp = inputs()
    rays = centred_rays()
    assert torch.equal(net(image, disp, torch.zeros(1, 3), rays), image)
    moved = net(image, disp, torch.tensor([[0.2, 0.0, 0.0]]), rays)
    assert (moved - image).abs().max() > 1e-3
    with pytest.raises(ValueError, match="rays"):
        net(image, disp, torch.zeros(1, 3))


def test_lobe_outputs_are_unit_axes_bounded_sharpness_and_amplitude():
    net = lobe_net(lobes=3)
    image, disp = inputs()
    with torch.no_grad():
        lobes = net.lobes(image, disp, centred_rays())
    assert lobes.shape == (1, 7 * len(range(3)), 32, 64)
    for j in range(3):
        mu, sharp, amp = (
            lobes[:, 7 * j : 7 * j + 3],
            lobes[:, 7 * j + 3],
            lobes[:, 7 * j + 4 : 7 * j + 7],
        )
        assert torch.allclose(mu.norm(dim=1), torch.ones(1, 32, 64), atol=1e-5)
        assert SHARPNESS_RANGE[0] <= float(sharp.min()) <= float(sharp.max()) <= SHARPNESS_RANGE[1]
        assert float(amp.abs().max()) <= AMPLITUDE_MAX


def test_view_directions_point_from_the_surface_to_the_camera():
    rays = centred_rays(4, 4)
    depth = torch.linspace(0.5, 6.0, 16).reshape(1, 1, 4, 4)
    disp = 0.25 / depth
    cam = torch.tensor([[0.3, -0.2, 0.1]])
    points = depth * rays
    expected = cam[:, :, None, None] - points
    expected = expected / expected.norm(dim=1, keepdim=True)
    assert torch.allclose(view_directions(disp, rays, cam), expected, atol=1e-6)
    # The sky (disparity 0) is seen along the ray from any camera.
    sky = view_directions(torch.zeros(1, 1, 4, 4), rays, cam)
    assert torch.allclose(sky, -rays / rays.norm(dim=1, keepdim=True), atol=1e-6)


def test_shade_lobes_is_the_closed_form():
    # One pixel straight ahead at depth 1, one lobe around the input camera's direction.
    image = torch.full((1, 3, 1, 1), 0.5)
    rays = torch.tensor([0.0, 0.0, 1.0]).reshape(1, 3, 1, 1)
    disp = torch.full((1, 1, 1, 1), 0.25)
    lobes = torch.tensor([0.0, 0.0, -1.0, 50.0, 0.4, 0.2, -0.2]).reshape(1, 7, 1, 1)
    cam = torch.tensor([[0.3, 0.0, 0.0]])
    cos = 1.0 / math.sqrt(1.0 + 0.3**2)  # the angle between (0.3, 0, -1) and (0, 0, -1)
    drop = math.exp(50.0 * (cos - 1.0)) - 1.0
    got = shade_lobes(image, lobes, disp, rays, cam)
    assert torch.allclose(
        got[0, :, 0, 0],
        torch.tensor([0.5 + 0.4 * drop, 0.5 + 0.2 * drop, 0.5 - 0.2 * drop]),
        atol=1e-6,
    )
    assert torch.equal(shade_lobes(image, lobes, disp, rays, cam, deadzone=1.0), image)


def test_linear_domain_adds_the_change_to_the_decoded_photo():
    image = torch.tensor([0.2, 0.5, 0.9]).reshape(1, 3, 1, 1)
    rays = torch.tensor([0.0, 0.0, 1.0]).reshape(1, 3, 1, 1)
    disp = torch.full((1, 1, 1, 1), 0.25)
    lobes = torch.tensor([0.0, 0.0, -1.0, 50.0, -0.3, -0.3, -0.3]).reshape(1, 7, 1, 1)
    cam = torch.tensor([[0.3, 0.0, 0.0]])
    display = shade_lobes(image, lobes, disp, rays, cam)
    linear = shade_lobes(image, lobes, disp, rays, cam, domain="linear")
    change = display - image
    want = (image**LINEAR_GAMMA + change).clamp(min=1e-4) ** (1 / LINEAR_GAMMA)
    assert torch.allclose(linear, want, atol=1e-6)
    # The same linear brightening moves a dark pixel more than a bright one in display units.
    moved = (linear - image).abs()[0, :, 0, 0]
    assert moved[0] > moved[1] > moved[2] > 0
    # Nothing changes at the input camera, and a change inside the dead zone is nothing.
    assert torch.equal(
        shade_lobes(image, lobes, disp, rays, torch.zeros(1, 3), domain="linear"), image
    )
    assert torch.equal(shade_lobes(image, lobes, disp, rays, cam, 1.0, "linear"), image)


def test_linear_domain_network_is_the_photo_at_the_input_camera_and_round_trips():
    cfg = replace(TINY, head="lobes", domain="linear")
    assert NetConfig.from_json(cfg.to_json()).domain == "linear"
    assert (
        NetConfig.from_json({k: v for k, v in TINY.to_json().items() if k != "domain"}).domain
        == "display"
    )
    torch.manual_seed(0)
    net = ReshadeNet(cfg).eval()
    torch.nn.init.normal_(net.decoder.out.weight, std=0.3)
    image, disp = inputs()
    rays = centred_rays()
    assert torch.equal(net(image, disp, torch.zeros(1, 3), rays), image)
    assert (net(image, disp, torch.tensor([[0.2, 0.0, 0.0]]), rays) - image).abs().max() > 1e-3
    with pytest.raises(ValueError, match="lobe domain"):
        replace(TINY, domain="log")


def test_lobe_graph_is_the_networks_lobes():
    net = lobe_net()
    image, disp = inputs()
    rays = centred_rays()
    assert LobeGraph.input_names == ("image", "disparity", "rays")
    assert torch.equal(LobeGraph(net)(image, disp, rays), net.lobes(image, disp, rays))
    assert NetConfig.from_json(replace(TINY, head="lobes", lobes=3).to_json()).lobes == 3


def test_lobes_flow_slides_a_ramp_by_the_shift_and_is_the_photo_at_the_input_camera():
    net = ReshadeNet(replace(TINY, head="lobes-flow", lobes=1))
    assert net.decoder.out.out_channels == 7 + 4
    image = torch.linspace(0, 1, 64).expand(1, 3, 32, 64).clone()  # a ramp along x
    disp = torch.full((1, 1, 32, 64), 0.125)
    rays = centred_rays()
    lobes = torch.zeros(1, 11, 32, 64)
    lobes[:, 2] = -1.0
    lobes[:, 3] = 1.0  # a wide lobe with no amplitude: the flow term alone
    lobes[:, 7] = 50.0  # F_xx: 50 pixels per radian of x direction change
    cam = torch.tensor([[0.2, 0.0, 0.0]])
    w = view_directions(disp, rays, cam)
    w0 = view_directions(disp, rays, torch.zeros(1, 3))
    got = shade_lobes(image, lobes, disp, rays, cam, head="lobes-flow")
    slope = 1.0 / 63  # per pixel
    expected = image - slope * 50.0 * (w - w0)[:, 0:1]
    inner = (slice(None), slice(None), slice(1, -1), slice(1, -1))
    assert torch.allclose(got[inner], expected[inner], atol=1e-5)
    still = shade_lobes(image, lobes, disp, rays, torch.zeros(1, 3), head="lobes-flow")
    assert torch.equal(still, image)
    with torch.no_grad():
        out = net.lobes(*inputs(), rays)
    assert out.shape[1] == 11 and float(out[:, 7:].abs().max()) <= LOBE_FLOW_MAX


def slide_scene(rho: float):
    """A one-pixel-wide highlight column at x = 20 on a flat grey surface (disparity 0.125),
    all of it reflected light, its image at disparity 0.125 (1 - rho); no lobe amplitude."""
    image = torch.full((1, 3, 32, 64), 0.2)
    image[..., 20] = 0.9
    disp = torch.full((1, 1, 32, 64), 0.125)
    lobes = torch.zeros(1, 11, 32, 64)
    lobes[:, 2] = -1.0
    lobes[:, 3] = 1.0
    lobes[:, 7:10, :, 20] = 1.0 - 0.2 / 0.9  # only what lies above the surface's grey
    lobes[:, 10] = rho
    return image, disp, lobes


def test_lobes_slide_moves_a_highlight_by_its_layers_parallax():
    net = ReshadeNet(replace(TINY, head="lobes-slide", lobes=1))
    assert net.decoder.out.out_channels == 7 + 4
    rays = centred_rays()
    fx = 1.0 / float(rays[0, 0, 0, 1] - rays[0, 0, 0, 0])
    # A light mirrored at infinity (rho = 1) in the surface at depth 2: a camera c to the
    # right moves it by f c / 2 pixels to the right relative to the surface.
    image, disp, lobes = slide_scene(1.0)
    cam_x = 3.0 * 2.0 / fx  # the offset that moves it by exactly 3 pixels
    got = shade_lobes(
        image, lobes, disp, rays, torch.tensor([[cam_x, 0.0, 0.0]]), head="lobes-slide"
    )
    row = got[0, 0, 16]
    assert torch.allclose(row[23], torch.tensor(0.9), atol=1e-4)
    assert torch.allclose(row[20], torch.tensor(0.2), atol=1e-4)
    assert torch.allclose(row[:19], torch.tensor(0.2)) and torch.allclose(
        row[25:], torch.tensor(0.2)
    )
    still = shade_lobes(image, lobes, disp, rays, torch.zeros(1, 3), 0.004, head="lobes-slide")
    assert torch.equal(still, image)
    # No offset between the layer and the surface: it stays where it is for any camera.
    image, disp, lobes = slide_scene(0.0)
    fixed = shade_lobes(
        image, lobes, disp, rays, torch.tensor([[0.3, 0.1, 0.2]]), 0.004, head="lobes-slide"
    )
    assert torch.equal(fixed, image)
    with torch.no_grad():
        out = net.lobes(*inputs(), rays)
    assert out.shape[1] == 11 and float(out[:, 7:10].min()) >= 0 and float(out[:, 7:10].max()) <= 1
    assert SLIDE_DEPTH_INIT - 1 <= float(out[:, 10].min()) <= float(out[:, 10].max()) <= 1.5


def test_several_cameras_run_the_encoder_once_and_the_lobe_decoder_once():
    from reshader_train.model import NetConfig, ReshadeNet, net_config

    image, disparity = torch.rand(2, 3, 32, 32), torch.rand(2, 1, 32, 32)
    rays, cameras = torch.randn(2, 3, 32, 32), torch.randn(2, 4, 3) * 0.2
    for head, decoder_runs in (("lobes", 1), ("residual", 4), ("camera-linear", 4)):
        net = ReshadeNet(NetConfig(**{**net_config("4,8,8,16,16,16").to_json(), "head": head}))
        calls = {"encoder": 0, "decoder": 0}

        def count(name, calls=calls):
            return lambda *_: calls.__setitem__(name, calls[name] + 1)

        net.encoder.register_forward_hook(count("encoder"))
        net.decoder.out.register_forward_hook(count("decoder"))
        out = net(image, disparity, cameras, rays)
        assert out.shape == (2, 4, 3, 32, 32)
        assert calls == {"encoder": 1, "decoder": decoder_runs}
        for k in range(4):
            one = net(image, disparity, cameras[:, k], rays)
            assert torch.allclose(out[:, k], one, atol=1e-6)


def test_film_starts_as_the_network_without_it_and_then_follows_the_camera():
    torch.manual_seed(0)
    plain = ReshadeNet(TINY).eval()
    torch.nn.init.normal_(plain.decoder.out.weight, std=0.3)
    film = ReshadeNet(replace(TINY, film=True)).eval()
    missing = film.load_state_dict(plain.state_dict(), strict=False).missing_keys
    assert missing and all(k.startswith("decoder.film.") for k in missing)
    image, disparity = inputs()
    cam = torch.tensor([[0.2, -0.1, 0.05]])
    with torch.no_grad():
        assert torch.equal(film(image, disparity, cam), plain(image, disparity, cam))
        for layer in film.decoder.film:
            torch.nn.init.normal_(layer.weight, std=0.5)
        moved = film(image, disparity, cam) - plain(image, disparity, cam)
        other = film(image, disparity, -cam) - plain(image, disparity, -cam)
    assert moved.abs().max() > 1e-3 and not torch.allclose(moved, other)
    assert NetConfig.from_json(film.cfg.to_json()).film
    assert not NetConfig.from_json({k: v for k, v in TINY.to_json().items() if k != "film"}).film
    with pytest.raises(ValueError, match="FiLM needs a head that takes the camera"):
        replace(TINY, head="lobes", film=True)
