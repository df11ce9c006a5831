"""The reshading network (paper section 3.4): a UNet that predicts a residual image.

Split into an encoder (image + disparity -> bottleneck and skip tensors, independent of the
view) and a decoder (those + the novel camera position -> reshaded image), so that the
runtime runs the encoder once per photo and only the decoder per view. The disparity
frequency encoding lives inside the encoder: callers feed `d = clamp(0.25 / depth, 0, 1)`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

LEVELS = 6  # full resolution plus 5 average-pool downsamplings: H and W must divide by 32
ALIGN = 2 ** (LEVELS - 1)
DISPARITY_FREQUENCIES = 5
ENCODED_DISPARITY_CHANNELS = 1 + 2 * DISPARITY_FREQUENCIES
CAMERA_FEATURES = 128  # MLP output (125) concatenated with the raw 3-vector
NEG_SLOPE = 0.1
# Output heads. "residual" is the paper's: image + tanh(conv). "camera-linear" makes the last
# conv predict a per-pixel Jacobian of the shading with respect to the camera position (3
# colours x 3 axes) and contracts it with the offset: to first order a highlight moves by an
# amount proportional to the offset, and a small network of LeakyReLU layers fed the camera
# only at the bottleneck has to build that product out of piecewise-linear pieces. The
# camera still reaches the bottleneck as in the paper, so the Jacobian may depend on it.
# "flow" adds the other half of that product: a highlight or reflection that slides by s
# pixels changes the image by about -grad(I) . s, so the last conv also predicts a shift per
# unit of offset (2 x 3 channels), which is multiplied by the photo's own gradient (fixed
# central differences). The network then has to learn smooth fields of geometry
# (how far, which way) rather than their product with the image's edges.
# Channels of the last conv per head: the residual, 3 x 3 Jacobian, and 6 shifts more.
# "lobes" takes no camera: see LobeField. Its channels are per lobe, times NetConfig.lobes;
# "lobes-flow" and "lobes-slide" add LOBE_EXTRA_CHANNELS (see LobeField).
HEAD_CHANNELS = {
    "residual": 3,
    "camera-linear": 9,
    "flow": 15,
    "lobes": 7,
    "lobes-flow": 7,
    "lobes-slide": 7,
}
LOBE_HEADS = ("lobes", "lobes-flow", "lobes-slide")
LOBE_EXTRA_CHANNELS = {"lobes": 0, "lobes-flow": 4, "lobes-slide": 4}
HEADS = tuple(HEAD_CHANNELS)


def lobe_head_channels(head: str, lobes: int) -> int:
    """Raw output channels of a lobe head with `lobes` lobes: 7 per lobe plus its extras."""
    return HEAD_CHANNELS[head] * lobes + LOBE_EXTRA_CHANNELS[head]


LOBE_DOMAINS = ("display", "linear", "linear-clamped")
# "linear-clamped" (head "lobes" only): a clipped highlight holds less light than its lobe,
# and I + S(w) - S(w0) (S = sum_j a_j G_j) would dig a dark hole where it leaves. In the
# linear domain a view is instead min(max(I - k S(w0), 0) + k S(w), 1): it never removes
# more light than the pixel has, and clips as the photo did. k = 1 where the photo clipped
# (there a lobe may be far brighter than white: where it clips, its edge, is what moves),
# else min(1, I / S(w0)), so that a lobe never holds more than its pixel; either way the
# view at the photo's camera is the photo.
CLIPPED = 1.0 - 0.5 / 255
# Where a lobe head's amplitudes come from (NetConfig.amplitude). "free": the network gives
# them. "photo" (linear-clamped only): it gives each lobe's share u of the pixel's own
# light at the photo's view, and a = u I / G(w0), so that a view changes the pixel by
# u I (exp(lambda mu . (w - w0)) - 1): the photo sets the scale, and the network learns a
# bounded share (u > 1 only matters where the photo clipped, a highlight brighter than
# white) while the axis and sharpness it learns no longer move the amplitude it must hit.
LOBE_AMPLITUDES = ("free", "photo")
# The inverse tone curve of the linear domains: the training data's display encoding is a
# gamma between 2.2 and 5 (the paper's augmentation); 2.2 is its most common value and a
# photo's sRGB curve's nearest power.
LINEAR_GAMMA = 2.2
# Below this linear value the curve's slope is cut: (x)^(1/g) has an infinite one at zero.
LINEAR_FLOOR = 1e-4
# Shifts are at most this many pixels per unit of (offset / CAMERA_SCALE).
FLOW_MAX_PX = 4.0
# Offsets are divided by this before the contraction (the middle of the paper's 0.1-0.3
# shell), so that the Jacobian channels are of the order of the change they produce.
CAMERA_SCALE = 0.2


@dataclass(frozen=True)
class NetConfig:
    """Widths per level (full resolution first) and convolutions per block."""

    widths: tuple[int, ...]
    convs: tuple[int, ...] = (2, 2, 2, 2, 2, 2)
    camera_hidden: tuple[int, ...] = (64, 128)
    head: str = "residual"
    # Residual magnitudes up to this (output units, [0,1]) become exactly 0: see Decoder.
    deadzone: float = 0.0
    # Spherical-Gaussian lobes per pixel of the "lobes" head.
    lobes: int = 2
    # Where the lobe heads add their change: see LOBE_DOMAINS.
    domain: str = "display"
    # Where the lobes' amplitudes come from: see LOBE_AMPLITUDES.
    amplitude: str = "free"
    # The camera also scales and shifts every decoder level's channels: see Decoder.
    film: bool = False

    def __post_init__(self) -> None:
        if len(self.widths) != LEVELS or len(self.convs) != LEVELS:
            raise ValueError(f"NetConfig needs {LEVELS} widths and conv counts, got {self}")
        if min(self.widths) < 1 or min(self.convs) < 1:
            raise ValueError(f"NetConfig widths and conv counts must be positive: {self}")
        if self.head not in HEADS:
            raise ValueError(f"unknown output head {self.head!r}: expected one of {HEADS}")
        if not 0.0 <= self.deadzone < 0.5:
            raise ValueError(f"dead zone {self.deadzone} must be in [0, 0.5)")
        if not 1 <= self.lobes <= 8:
            raise ValueError(f"lobes {self.lobes} must be in 1..8")
        if self.domain not in LOBE_DOMAINS:
            raise ValueError(f"unknown lobe domain {self.domain!r}: expected one of {LOBE_DOMAINS}")
        if self.domain == "linear-clamped" and self.head != "lobes":
            raise ValueError(f"lobe domain linear-clamped is for the lobes head, not {self.head}")
        if self.amplitude not in LOBE_AMPLITUDES:
            raise ValueError(
                f"unknown lobe amplitude {self.amplitude!r}: expected one of {LOBE_AMPLITUDES}"
            )
        if self.amplitude == "photo" and self.domain != "linear-clamped":
            raise ValueError("lobe amplitudes from the photo need the linear-clamped domain")
        if self.film and not self.takes_camera:
            raise ValueError(f"camera FiLM needs a head that takes the camera, not {self.head}")

    @property
    def out_channels(self) -> int:
        if self.head in LOBE_HEADS:
            return lobe_head_channels(self.head, self.lobes)
        return HEAD_CHANNELS[self.head]

    @property
    def takes_camera(self) -> bool:
        return self.head not in LOBE_HEADS

    @property
    def camera_features(self) -> int:
        """Channels the camera adds to the decoder's bottleneck input."""
        return CAMERA_FEATURES if self.takes_camera else 0

    def to_json(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_json(data: dict) -> NetConfig:
        # Checkpoints and exports from before the heads existed are "residual" without a
        # dead zone, which is what these defaults build.
        return NetConfig(
            widths=tuple(data["widths"]),
            convs=tuple(data["convs"]),
            camera_hidden=tuple(data["camera_hidden"]),
            head=data.get("head", "residual"),
            deadzone=float(data.get("deadzone", 0.0)),
            lobes=int(data.get("lobes", 2)),
            domain=data.get("domain", "display"),
            amplitude=data.get("amplitude", "free"),
            film=bool(data.get("film", False)),
        )


# `full` is the paper's network. `lite` is sized for the runtime (2 CPU cores via tract): a
# quarter of the width everywhere, and one convolution per block at the two highest
# resolutions, where the concatenations and bilinear resizes tract is slow at are largest
# (measurements in the README's Training section).
SIZES = {
    "full": NetConfig(widths=(32, 64, 128, 256, 512, 512)),
    "lite": NetConfig(widths=(8, 16, 32, 64, 128, 128), convs=(1, 1, 2, 2, 2, 2)),
    # `lite` at 1.5x the width (2.25x the FLOPs): whether width holds the lite network back
    # (`train --init-widen` starts it from a trained lite model's output).
    "wide": NetConfig(widths=(12, 24, 48, 96, 192, 192), convs=(1, 1, 2, 2, 2, 2)),
}


def net_config(size: str) -> NetConfig:
    """A named size, or explicit comma-separated widths such as "4,8,8,16,16,16"."""
    if size in SIZES:
        return SIZES[size]
    try:
        widths = tuple(int(w) for w in size.split(","))
    except ValueError:
        raise ValueError(
            f"unknown network size {size!r}: use one of {sorted(SIZES)} or 6 comma-separated widths"
        ) from None
    return NetConfig(widths=widths, convs=(1,) * LEVELS, camera_hidden=(16,))


def encode_disparity(d: torch.Tensor) -> torch.Tensor:
    """[d, sin(2^i d), cos(2^i d) for i = 0..4] along the channel axis (11 channels, no pi)."""
    parts = [d]
    for i in range(DISPARITY_FREQUENCIES):
        scaled = d * float(2**i)
        parts += [torch.sin(scaled), torch.cos(scaled)]
    return torch.cat(parts, dim=1)


def _block(cin: int, cout: int, n: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(n):
        layers += [nn.Conv2d(cin if i == 0 else cout, cout, 3, padding=1), nn.LeakyReLU(NEG_SLOPE)]
    return nn.Sequential(*layers)


class Encoder(nn.Module):
    """(image, disparity) -> (bottleneck at H/32, skips at H, H/2, ..., H/16)."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        cins = (3 + ENCODED_DISPARITY_CHANNELS,) + cfg.widths[:-1]
        self.blocks = nn.ModuleList(
            _block(cin, cout, n) for cin, cout, n in zip(cins, cfg.widths, cfg.convs, strict=True)
        )

    def forward(
        self, image: torch.Tensor, disparity: torch.Tensor
    ) -> tuple[torch.Tensor, list[torch.Tensor]]:
        h, w = image.shape[-2:]
        if h % ALIGN or w % ALIGN:
            raise ValueError(f"image is {h}x{w}; height and width must be multiples of {ALIGN}")
        x = torch.cat([image, encode_disparity(disparity)], dim=1)
        skips = []
        for i, block in enumerate(self.blocks):
            if i > 0:
                x = F.avg_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        return skips[-1], skips[:-1]


class CameraMLP(nn.Module):
    """3 -> ... -> 125, concatenated with the raw position: 128 features."""

    def __init__(self, hidden: tuple[int, ...]) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        cin = 3
        for width in hidden:
            layers += [nn.Linear(cin, width), nn.LeakyReLU(NEG_SLOPE)]
            cin = width
        layers += [nn.Linear(cin, CAMERA_FEATURES - 3), nn.LeakyReLU(NEG_SLOPE)]
        self.mlp = nn.Sequential(*layers)

    def forward(self, camera: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.mlp(camera), camera], dim=1)


class Upsample2x(nn.Module):
    """Bilinear x2 with half-pixel centres and clamped edges, exactly as F.interpolate.

    In ONNX the same values are written as nearest x2 (Concat + Reshape) followed by a
    [1,2,1]x[1,2,1]/16 depthwise blur over replicated edges, because tract runs its bilinear
    Resize 2-3x slower than that form (measured with tract 0.23.9 on the decoder's shapes);
    onnxruntime runs both about equally. The kernel is not a parameter: checkpoints do not
    change and quantisation leaves it alone (export skips Conv nodes in `/upsample.` scopes)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        k = torch.tensor([0.25, 0.5, 0.25])
        self.register_buffer(
            "blur", (k[:, None] * k[None, :]).expand(channels, 1, 3, 3).clone(), persistent=False
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not torch.onnx.is_in_onnx_export():
            return F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
        n, c, h, w = x.shape
        x = x[:, :, :, None, :, None]
        x = torch.cat([x, x], 5)
        x = torch.cat([x, x], 3).reshape(n, c, 2 * h, 2 * w)
        x = F.pad(x, (1, 1, 1, 1), mode="replicate")
        return F.conv2d(x, self.blur, groups=c)


def shrink(r: torch.Tensor, threshold: float) -> torch.Tensor:
    """Soft threshold: 0 where |r| <= threshold, r -+ threshold beyond.

    Written with two ReLUs so that every engine runs it (ONNX's Shrink is not universal).
    In training the gradient passes straight through (as if there were no threshold), so a
    residual inside the zone still learns where it should grow; the forward value, which
    the loss sees, is the thresholded one."""
    if threshold == 0.0:
        return r
    out = F.relu(r - threshold) - F.relu(-r - threshold)
    if torch.onnx.is_in_onnx_export():
        return out
    return r + (out - r).detach()


class ImageGradient(nn.Module):
    """Central differences of an RGB image along x and y, with replicated edges: a fixed
    depthwise conv (not a parameter; quantisation leaves it in float like the blur)."""

    def __init__(self) -> None:
        super().__init__()
        k = torch.zeros(2, 1, 3, 3)
        k[0, 0, 1, 0], k[0, 0, 1, 2] = -0.5, 0.5
        k[1, 0, 0, 1], k[1, 0, 2, 1] = -0.5, 0.5
        self.register_buffer("kernel", k.repeat(3, 1, 1, 1), persistent=False)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        g = F.conv2d(F.pad(image, (1, 1, 1, 1), mode="replicate"), self.kernel, groups=3)
        return g[:, 0::2], g[:, 1::2]


class Decoder(nn.Module):
    """(image, skips, bottleneck, camera) -> reshaded image = image + shrink(tanh(residual)).

    The dead zone exists because of how the evaluation (and a viewer) weighs views whose
    shading does not change: a faint residual over an unchanged view costs it many dB, and
    every network trained here without it left one (model card, 0.1.0-0.2.0). With it,
    "no change" is an interval the network can land in, not a point it has to hit.

    With the "lobes" head the decoder takes no camera and `features` is all it does: the
    view enters through the closed form of `shade_lobes`."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        w = cfg.widths
        self.head = cfg.head
        self.deadzone = cfg.deadzone
        self.camera = CameraMLP(cfg.camera_hidden) if cfg.takes_camera else None
        self.bottleneck = _block(w[-1] + cfg.camera_features, w[-1], cfg.convs[-1])
        self.ups = nn.ModuleList(
            _block(w[i + 1] + w[i], w[i], cfg.convs[i]) for i in reversed(range(LEVELS - 1))
        )
        self.upsample = nn.ModuleList(Upsample2x(w[i + 1]) for i in reversed(range(LEVELS - 1)))
        self.out = nn.Conv2d(w[0], cfg.out_channels, 3, padding=1)
        self.film = (
            nn.ModuleList(nn.Linear(CAMERA_FEATURES, 2 * w[i]) for i in reversed(range(LEVELS - 1)))
            if cfg.film
            else None
        )
        self.gradient = ImageGradient() if cfg.head == "flow" else None
        # A small last layer starts the network near the identity (reshaded = input), which
        # is the right answer for most pixels and what the no-reshading baseline scores.
        nn.init.normal_(self.out.weight, std=1e-3)
        nn.init.zeros_(self.out.bias)

    def features(
        self, skips: list[torch.Tensor], bottleneck: torch.Tensor, camera: torch.Tensor | None
    ) -> torch.Tensor:
        """The last conv's output: the residual, or the head's per-pixel quantities."""
        x = bottleneck
        features = None
        if self.camera is not None:
            features = self.camera(camera)
            # Broadcast by adding a zero plane rather than with expand(): exports as a plain
            # Add instead of Expand (which tract's int8 path rejects) plus shape arithmetic.
            cam = features[:, :, None, None] + torch.zeros_like(bottleneck[:, :1])
            x = torch.cat([bottleneck, cam], dim=1)
        x = self.bottleneck(x)
        for i, (up, block, skip) in enumerate(
            zip(self.upsample, self.ups, reversed(skips), strict=True)
        ):
            x = block(torch.cat([up(x), skip], dim=1))
            if self.film is not None:
                x = self.modulate(x, self.film[i](features))
        return self.out(x)

    @staticmethod
    def modulate(x: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        """x * (1 + gain) + shift, one gain and shift per channel from the camera.

        Why: with the camera only at the bottleneck, the full-resolution levels, where a
        highlight's edge is, can make a product of the camera and the photo's local detail
        only out of LeakyReLU pieces; a per-channel gain is that product. The layers start
        at zero, so a network initialised from one without them computes the same image."""
        c = x.shape[1]
        gain, shift = film[:, :c, None, None], film[:, c:, None, None]
        return x * (1.0 + gain) + shift

    def forward(
        self,
        image: torch.Tensor,
        skips: list[torch.Tensor],
        bottleneck: torch.Tensor,
        camera: torch.Tensor,
    ) -> torch.Tensor:
        r = self.features(skips, bottleneck, camera)
        if self.head != "residual":
            r = self.contract(image, r, camera / CAMERA_SCALE)
        return image + shrink(torch.tanh(r), self.deadzone)

    def contract(self, image: torch.Tensor, r: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Sum over camera axes k of t_k times the change per unit offset along k."""
        if self.gradient is not None:
            gx, gy = self.gradient(image)
            shift = FLOW_MAX_PX * torch.tanh(r[:, 9:15])
        change = []
        for k in range(3):
            per_unit = r[:, 3 * k : 3 * k + 3]
            if self.gradient is not None:
                per_unit = per_unit - gx * shift[:, 2 * k : 2 * k + 1]
                per_unit = per_unit - gy * shift[:, 2 * k + 1 : 2 * k + 2]
            change.append(per_unit * t[:, k, None, None, None])
        return sum(change)


# The lobe head (DESIGN.md, "The lobe head"). Per pixel and lobe j the network gives an axis
# mu_j (unit vector, input camera frame, OpenCV axes), a sharpness lambda_j and an RGB
# amplitude a_j; a view from camera centre c sees G_j = exp(lambda_j (mu_j . w - 1)) with w
# the unit direction from the pixel's 3-D point to c, and the reshaded image is
#   R = I + shrink(sum_j a_j [G_j(w_c) - G_j(w_0)], deadzone),
# so R = I exactly at the input camera and any camera is defined. The sum is taken in the
# display encoding, as the residual head's is, or (domain "linear") in linear radiance:
# R = (I^g + shrink(sum ...))^(1/g). Light adds in linear radiance, so there one specular
# amplitude serves a whole surface whatever its diffuse colour beneath, which the display
# encoding's compression would have the network vary pixel by pixel.
LOBE_LAYOUT = ("mu_x", "mu_y", "mu_z", "sharpness", "amp_r", "amp_g", "amp_b")
# Sharpness spans one (a hemisphere-wide lobe) to a mirror's: a camera offset of 0.1-0.3 at
# depth 1-5 turns w by 0.02-0.3 rad, and exp(-lambda theta^2 / 2) must resolve that.
SHARPNESS_RANGE = (1.0, 2.0e4)
SHARPNESS_INIT = 100.0
# Domain "linear-clamped" amplitudes are positive and span ten orders (a highlight clipped
# in the photo may be thousands of times brighter than white: where it clips, its edge,
# is what moves): a sigmoid in log between these bounds, starting at AMPLITUDE_INIT, below
# AMPLITUDE_SEEN, the faintest lobe a view shows past the dead zone.
LOG_AMPLITUDE_RANGE = (1.0e-6, 1.0e4)
AMPLITUDE_INIT = 1.0e-4
AMPLITUDE_SEEN = 1.0e-3
AMPLITUDE_MAX = 2.0
# Amplitude "photo": each lobe's share of its pixel's light starts here, below the dead
# zone for any pixel, and spans LOG_AMPLITUDE_RANGE as the free amplitudes do.
SHARE_INIT = 1.0e-3
# The axis is predicted as an offset from the input camera's own direction w_0, so that a
# pixel seen at its highlight's peak needs an offset of zero; offsets are at most this long.
AXIS_OFFSET_MAX = 1.0
# The disparity input is d = 0.25 / depth, so the point is X = (0.25 / d) r and
# c - X is parallel to 4 d c - r (positive factor d / 0.25): finite for the sky (d = 0).
DISPARITY_DEPTH = 0.25


def view_directions(disparity: torch.Tensor, rays: torch.Tensor, camera: torch.Tensor):
    """Unit directions from each pixel's 3-D point towards the camera centre `camera`.

    disparity (B,1,H,W), rays (B,3,H,W) = K^-1 [u, v, 1], camera (B,3)."""
    v = (disparity / DISPARITY_DEPTH) * camera[:, :, None, None] - rays
    return v / torch.sqrt((v * v).sum(1, keepdim=True) + 1e-12)


def photo_directions(rays: torch.Tensor) -> torch.Tensor:
    """w0 = normalize(-r): each pixel's direction towards the photo's own camera, whatever
    its depth (view_directions at camera 0)."""
    return view_directions(torch.zeros_like(rays[:, :1]), rays, rays.new_zeros(len(rays), 3))


def linear_light(image: torch.Tensor) -> torch.Tensor:
    """The photo's linear light through the linear domains' inverse curve, floored at
    LINEAR_FLOOR (the share of a pixel's light is defined for black pixels too)."""
    return (image.clamp(min=0.0) ** LINEAR_GAMMA).clamp(min=LINEAR_FLOOR)


class LobeField(nn.Module):
    """The decoder's raw channels -> lobes (B, 7K, H, W) in LOBE_LAYOUT order per lobe."""

    def __init__(
        self, lobes: int, head: str = "lobes", domain: str = "display", amplitude: str = "free"
    ) -> None:
        super().__init__()
        self.lobes = lobes
        self.head = head
        self.log_amplitude = domain == "linear-clamped"
        self.from_photo = amplitude == "photo"
        lo_a, hi_a = (math.log(v) for v in LOG_AMPLITUDE_RANGE)
        self.amplitude_span = (lo_a, hi_a)
        init = SHARE_INIT if self.from_photo else AMPLITUDE_INIT
        a = (math.log(init) - lo_a) / (hi_a - lo_a)
        self.amplitude_bias = math.log(a / (1 - a))
        lo, hi = (torch.log(torch.tensor(v)) for v in SHARPNESS_RANGE)
        self.register_buffer("log_sharpness", torch.stack([lo, hi]), persistent=False)
        # sigmoid(b) places the sharpness at SHARPNESS_INIT when the raw channel is 0.
        t = (torch.log(torch.tensor(SHARPNESS_INIT)) - lo) / (hi - lo)
        self.sharpness_bias = float(torch.log(t / (1 - t)))

    def forward(
        self, raw: torch.Tensor, rays: torch.Tensor, image: torch.Tensor | None = None
    ) -> torch.Tensor:
        """`image` (B,3,H,W), the photo as the network sees it: needed for amplitude
        "photo"."""
        if self.from_photo and image is None:
            raise ValueError("lobe amplitudes from the photo need the photo")
        w0 = photo_directions(rays)
        if self.from_photo:
            log_light = torch.log(linear_light(image))
        lo, hi = self.log_sharpness[0], self.log_sharpness[1]
        parts = []
        for j in range(self.lobes):
            p = raw[:, 7 * j : 7 * j + 7]
            mu = w0 + AXIS_OFFSET_MAX * torch.tanh(p[:, 0:3])
            mu = mu / torch.sqrt((mu * mu).sum(1, keepdim=True) + 1e-12)
            sharp = torch.exp(lo + (hi - lo) * torch.sigmoid(p[:, 3:4] + self.sharpness_bias))
            amp = self.amplitude(p[:, 4:7])
            if self.from_photo:
                amp = self.photo_amplitude(amp, sharp, (mu * w0).sum(1, keepdim=True), log_light)
            parts += [mu, sharp, amp]
        extra = raw[:, 7 * self.lobes :]
        if self.head == "lobes-flow":
            parts.append(LOBE_FLOW_MAX * torch.tanh(extra))
        elif self.head == "lobes-slide":
            fraction = torch.sigmoid(extra[:, 0:3] + SLIDE_FRACTION_BIAS)
            parts += [fraction, SLIDE_DEPTH_INIT + torch.tanh(extra[:, 3:4])]
        return torch.cat(parts, dim=1)

    def amplitude(self, raw: torch.Tensor) -> torch.Tensor:
        if not self.log_amplitude:
            return AMPLITUDE_MAX * torch.tanh(raw)
        lo, hi = self.amplitude_span
        return torch.exp(lo + (hi - lo) * torch.sigmoid(raw + self.amplitude_bias))

    def photo_amplitude(
        self, share: torch.Tensor, sharp: torch.Tensor, cos0: torch.Tensor, log_light: torch.Tensor
    ) -> torch.Tensor:
        """u I / G(w0) for the log of the photo's linear light `log_light`, in log so that a
        lobe far from the photo's view cannot overflow; capped at the top of
        LOG_AMPLITUDE_RANGE as the free amplitudes are."""
        log_a = torch.log(share) + log_light + sharp * (1.0 - cos0)
        return torch.exp(log_a.clamp(max=self.amplitude_span[1]))


# The "lobes-flow" head adds what a lobe cannot do alone: light that slides from one pixel
# to the next. A lobe brightens a pixel only by the amplitude predicted for that pixel,
# which for the pixels beside a highlight the network has to infer; a slide by s pixels
# changes the image by about -grad(I) . s, which the photo's own gradient supplies. The
# shift is a per-pixel 2x2 matrix (pixels per radian) times the change of the view
# direction's x and y components, so it too is zero at the input camera and one network
# run serves every view.
LOBE_FLOW_MAX = 100.0


def flow_change(
    image: torch.Tensor, flow: torch.Tensor, w: torch.Tensor, w0: torch.Tensor
) -> torch.Tensor:
    """-grad(I) . (F (w - w0)_xy) for flow (B,4,H,W) = F_xx, F_xy, F_yx, F_yy per pixel."""
    gx, gy = ImageGradient().to(image)(image)
    dx, dy = (w - w0)[:, 0:1], (w - w0)[:, 1:2]
    sx = flow[:, 0:1] * dx + flow[:, 1:2] * dy
    sy = flow[:, 2:3] * dx + flow[:, 3:4] * dy
    return -(gx * sx + gy * sy)


# The "lobes-slide" head moves light the way a reflection moves: as a layer of its own. A
# highlight or reflection is the image of a light or of another object in the surface, and
# that image lies at its own depth (behind a flat surface at the mirrored distance; close
# behind a convex one; at infinity for the sky in a flat floor), so when the camera moves it
# slides across the surface with the parallax of that depth. Per pixel the network gives the
# fraction of the photo that is such reflected light (S = I * fraction, per colour) and how
# far behind the surface its image lies, as the share rho of the surface's disparity d that
# the image lacks: the image is at disparity d (1 - rho), rho = 0 on the surface, 1 at
# infinity (a distant light in a flat floor), negative in front (a concave mirror's real
# image). A view removes S and samples it back from where the layer's parallax brings it.
# A lobe can only brighten a pixel by an amplitude predicted for that pixel, while here the
# pixels a highlight slides onto take it from the photo itself, and the network only
# predicts smooth per-surface fields. Zero at the input camera, any camera defined, and a
# view costs one bilinear sample per pixel.
# An untrained network's layer is a twentieth of the photo lying at twice the surface's
# depth: were it zero or on the surface, moving it would change nothing, and neither field
# would have a gradient to learn from. rho spans SLIDE_DEPTH_INIT -+ 1.
SLIDE_FRACTION_BIAS = -3.0
# The lobes-slide head's channels after its lobes.
SLIDE_LAYOUT = ("fraction_r", "fraction_g", "fraction_b", "rho")
SLIDE_DEPTH_INIT = 0.5
# The layer's point must stay in front of a forward-moving camera: 1 - 4 d c_z is floored.
SLIDE_MIN_DEPTH_RATIO = 0.05


def project_from(disparity: torch.Tensor, rays: torch.Tensor, camera: torch.Tensor):
    """Normalised image coordinates (x/z, y/z) of each pixel's point at `disparity` seen from
    camera centre `camera` (B,3), in that camera's frame (no rotation, as the views')."""
    q = rays - (disparity / DISPARITY_DEPTH) * camera[:, :, None, None]
    return q[:, :2] / q[:, 2:3].clamp(min=SLIDE_MIN_DEPTH_RATIO)


def slide_change(
    image: torch.Tensor,
    slide: torch.Tensor,
    disparity: torch.Tensor,
    rays: torch.Tensor,
    camera: torch.Tensor,
) -> torch.Tensor:
    """S(x - s(x)) - S(x) for slide (B,4,H,W) = fraction (3), rho (1), S = image * fraction,
    s the parallax of the layer at disparity d (1 - rho) relative to the surface, in pixels."""
    spec = image * slide[:, 0:3]
    layer = disparity * (1.0 - slide[:, 3:4])
    shift = project_from(layer, rays, camera) - project_from(disparity, rays, camera)
    _, _, h, w = image.shape
    # Pixels per unit of normalised coordinate, from the rays (pixel centres one apart).
    fx = 1.0 / (rays[:, 0, 0, 1] - rays[:, 0, 0, 0])
    fy = 1.0 / (rays[:, 1, 1, 0] - rays[:, 1, 0, 0])
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=image.dtype, device=image.device),
        torch.arange(w, dtype=image.dtype, device=image.device),
        indexing="ij",
    )
    src_x = xs - shift[:, 0] * fx[:, None, None]
    src_y = ys - shift[:, 1] * fy[:, None, None]
    grid = torch.stack([2.0 * src_x / (w - 1) - 1.0, 2.0 * src_y / (h - 1) - 1.0], dim=-1)
    moved = F.grid_sample(spec, grid, mode="bilinear", padding_mode="border", align_corners=True)
    return moved - spec


def _lobe_parts(lobes: torch.Tensor):
    """(mu, sharpness, amplitude) of each lobe of lobes (B,7K,H,W)."""
    for j in range(lobes.shape[1] // 7):
        yield (
            lobes[:, 7 * j : 7 * j + 3],
            lobes[:, 7 * j + 3 : 7 * j + 4],
            lobes[:, 7 * j + 4 : 7 * j + 7],
        )


def lobe_sum(lobes: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """sum_j a_j G_j(w) for lobes (B,7K,H,W) and unit directions w (B,3,H,W)."""
    total = torch.zeros_like(w)
    for mu, sharp, amp in _lobe_parts(lobes):
        total = total + amp * torch.exp(sharp * ((mu * w).sum(1, keepdim=True) - 1.0))
    return total


def lobe_change(lobes: torch.Tensor, w: torch.Tensor, w0: torch.Tensor) -> torch.Tensor:
    """sum_j a_j [G_j(w) - G_j(w0)] for lobes (B,7K,H,W) and unit directions (B,3,H,W)."""
    change = torch.zeros_like(w)
    for mu, sharp, amp in _lobe_parts(lobes):
        g = torch.exp(sharp * ((mu * w).sum(1, keepdim=True) - 1.0))
        g0 = torch.exp(sharp * ((mu * w0).sum(1, keepdim=True) - 1.0))
        change = change + amp * (g - g0)
    return change


def shade_lobes(
    image: torch.Tensor,
    lobes: torch.Tensor,
    disparity: torch.Tensor,
    rays: torch.Tensor,
    camera: torch.Tensor,
    deadzone: float = 0.0,
    domain: str = "display",
    head: str = "lobes",
) -> torch.Tensor:
    """The reshaded image for camera centres `camera` (B,3): what the runtime evaluates."""
    w = view_directions(disparity, rays, camera)
    w0 = view_directions(disparity, rays, torch.zeros_like(camera))
    if domain == "linear-clamped":
        linear = image.clamp(min=0.0) ** LINEAR_GAMMA
        s0, s = lobe_sum(lobes, w0), lobe_sum(lobes, w)
        clipped = image >= CLIPPED
        k = torch.where(clipped, 1.0, (linear / s0.clamp(min=1e-12)).clamp(max=1.0))
        # max(I - k S0, 0) + k S written so that it is I exactly at the photo's camera:
        # k S0 <= I where the photo did not clip.
        dug = torch.where(clipped, (s0 - linear).clamp(min=0.0), 0.0)
        moved = (linear + k * (s - s0) + dug).clamp(max=1.0)
        change = shrink(moved - linear, deadzone)
        return torch.where(
            change == 0,
            image,
            (linear + change).clamp(min=LINEAR_FLOOR) ** (1.0 / LINEAR_GAMMA),
        )
    lobe_channels = lobes.shape[1] - LOBE_EXTRA_CHANNELS[head]
    change = lobe_change(lobes[:, :lobe_channels], w, w0)
    extra = lobes[:, lobe_channels:]
    if head == "lobes-flow":
        change = change + flow_change(image, extra, w, w0)
    elif head == "lobes-slide":
        change = change + slide_change(image, extra, disparity, rays, camera)
    if domain == "display":
        return image + shrink(change, deadzone)
    # Where nothing changes the photo is returned as it is, not through the curve and back.
    change = shrink(change, deadzone)
    linear = image.clamp(min=0.0) ** LINEAR_GAMMA + change
    return torch.where(change == 0, image, linear.clamp(min=LINEAR_FLOOR) ** (1.0 / LINEAR_GAMMA))


class ReshadeNet(nn.Module):
    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = Encoder(cfg)
        self.decoder = Decoder(cfg)
        self.lobe_field = (
            LobeField(cfg.lobes, cfg.head, cfg.domain, cfg.amplitude)
            if cfg.head in LOBE_HEADS
            else None
        )
        # He initialisation for LeakyReLU keeps activations from fading over the ~20 layers
        # between the camera features and the output (PyTorch's default init shrinks them,
        # and the camera's influence with them).
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.Linear)) and m is not self.decoder.out:
                nn.init.kaiming_normal_(m.weight, a=NEG_SLOPE, nonlinearity="leaky_relu")
                nn.init.zeros_(m.bias)
        if self.decoder.film is not None:
            for layer in self.decoder.film:
                nn.init.zeros_(layer.weight)
                nn.init.zeros_(layer.bias)

    def forward(
        self,
        image: torch.Tensor,
        disparity: torch.Tensor,
        camera: torch.Tensor,
        rays: torch.Tensor | None = None,
        fields: bool = False,
    ):
        """The reshaded image. `rays` (B,3,H,W), K^-1 [u, v, 1] per pixel, is needed by the
        lobe head only (the other heads never see the geometry of the camera). With
        `fields`, a lobe head returns (image, its fields) (for `train --teacher`).

        `camera` (B,N,3), N cameras per photo, gives (B,N,3,H,W): the encoder runs once per
        photo, and so does the lobe head's decoder (only the closed form runs per camera);
        the camera-conditioned heads run their decoder once per camera."""
        many = camera.dim() == 3
        cameras = camera.unbind(1) if many else (camera,)
        if self.lobe_field is None:
            bottleneck, skips = self.encoder(image, disparity)
            out = [self.decoder(image, skips, bottleneck, c) for c in cameras]
        else:
            if rays is None:
                raise ValueError("the lobe head needs each pixel's ray (rays)")
            lobes = self.lobes(image, disparity, rays)
            out = [
                shade_lobes(
                    image,
                    lobes,
                    disparity,
                    rays,
                    c,
                    self.cfg.deadzone,
                    self.cfg.domain,
                    self.cfg.head,
                )
                for c in cameras
            ]
        views = torch.stack(out, 1) if many else out[0]
        if fields:
            if self.lobe_field is None:
                raise ValueError(f"the {self.cfg.head} head has no fields")
            return views, lobes
        return views

    def lobes(self, image: torch.Tensor, disparity: torch.Tensor, rays: torch.Tensor):
        """The lobe head's once-per-photo output (B, 7K, H, W)."""
        bottleneck, skips = self.encoder(image, disparity)
        return self.lobe_field(self.decoder.features(skips, bottleneck, None), rays, image)


# Flat-signature wrappers for ONNX export as two graphs. Tensor names for the manifest:
SKIP_NAMES = tuple(f"skip{i}" for i in range(LEVELS - 1))  # skip0 is full resolution


class EncoderGraph(nn.Module):
    """image [1,3,H,W], disparity [1,1,H,W] -> bottleneck, skip0..skip4."""

    input_names = ("image", "disparity")
    output_names = ("bottleneck",) + SKIP_NAMES

    def __init__(self, net: ReshadeNet) -> None:
        super().__init__()
        self.encoder = net.encoder

    def forward(self, image: torch.Tensor, disparity: torch.Tensor) -> tuple[torch.Tensor, ...]:
        bottleneck, skips = self.encoder(image, disparity)
        return (bottleneck, *skips)


class DecoderGraph(nn.Module):
    """image, bottleneck, skip0..skip4, camera [1,3] -> reshaded [1,3,H,W]."""

    input_names = ("image", "bottleneck") + SKIP_NAMES + ("camera",)
    output_names = ("reshaded",)

    def __init__(self, net: ReshadeNet) -> None:
        super().__init__()
        self.decoder = net.decoder

    def forward(self, image: torch.Tensor, bottleneck: torch.Tensor, *rest: torch.Tensor):
        *skips, camera = rest
        return self.decoder(image, list(skips), bottleneck, camera)


class LobeGraph(nn.Module):
    """image [1,3,H,W], disparity [1,1,H,W], rays [1,3,H,W] -> lobes [1,7K,H,W]."""

    input_names = ("image", "disparity", "rays")
    output_names = ("lobes",)

    def __init__(self, net: ReshadeNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor, disparity: torch.Tensor, rays: torch.Tensor):
        return self.net.lobes(image, disparity, rays)


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def conv_flops(net: ReshadeNet, height: int, width: int) -> dict[str, float]:
    """Multiply-adds x 2 of the convolutions (the bulk of the cost) for one view."""
    totals = {"encoder": 0.0, "decoder": 0.0}

    def hook_for(part: str):
        def hook(mod: nn.Conv2d, _inp, out: torch.Tensor) -> None:
            k = mod.kernel_size[0] * mod.kernel_size[1]
            totals[part] += 2.0 * out.numel() * mod.in_channels * k

        return hook

    handles = [
        m.register_forward_hook(hook_for(part))
        for part, sub in (("encoder", net.encoder), ("decoder", net.decoder))
        for m in sub.modules()
        if isinstance(m, nn.Conv2d)
    ]
    try:
        with torch.no_grad():
            net(
                torch.zeros(1, 3, height, width),
                torch.zeros(1, 1, height, width),
                torch.zeros(1, 3),
                torch.zeros(1, 3, height, width),
            )
    finally:
        for h in handles:
            h.remove()
    return totals
