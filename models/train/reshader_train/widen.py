"""A trained network embedded in a wider one that starts out computing the same image.

Whether the paper's head is held back by its width can only be asked of a wider network
that already knows what the narrow one learned: one trained afresh would spend hours on
the CPU getting back to where the shipped model is. Each layer of the wide network keeps
the narrow one's weights between the old channels; the added channels get fresh weights
from the old and the added channels below them, while no old channel, and not the output,
reads an added one (their weights there are zero). The added channels therefore change
nothing until training gives them a use: the first gradient reaches their outgoing weights.
"""

from __future__ import annotations

import torch
from torch import nn

from .model import ENCODED_DISPARITY_CHANNELS, LEVELS, ReshadeNet


def _segments(wide: ReshadeNet, narrow: ReshadeNet) -> dict[str, tuple[list[int], list[int]]]:
    """For each conv of the network: the channel counts of the pieces its input is
    concatenated from, narrow and wide."""
    nw, ww = narrow.cfg.widths, wide.cfg.widths
    inputs: dict[str, tuple[list[int], list[int]]] = {}
    fixed = 3 + ENCODED_DISPARITY_CHANNELS
    for i in range(LEVELS):
        first = ([fixed], [fixed]) if i == 0 else ([nw[i - 1]], [ww[i - 1]])
        for k in range(wide.cfg.convs[i]):
            inputs[f"encoder.blocks.{i}.{2 * k}"] = first if k == 0 else ([nw[i]], [ww[i]])
    camera = wide.cfg.camera_features
    top = LEVELS - 1
    for k in range(wide.cfg.convs[top]):
        narrow_in = [nw[top], camera] if k == 0 else [nw[top]]
        wide_in = [ww[top], camera] if k == 0 else [ww[top]]
        inputs[f"decoder.bottleneck.{2 * k}"] = (narrow_in, wide_in)
    for j, i in enumerate(reversed(range(LEVELS - 1))):
        for k in range(wide.cfg.convs[i]):
            pieces = ([nw[i + 1], nw[i]], [ww[i + 1], ww[i]]) if k == 0 else ([nw[i]], [ww[i]])
            inputs[f"decoder.ups.{j}.{2 * k}"] = pieces
    inputs["decoder.out"] = ([nw[0]], [ww[0]])
    return inputs


def _old_positions(narrow_pieces: list[int], wide_pieces: list[int]) -> torch.Tensor:
    """Where each narrow input channel sits among the wide layer's input channels."""
    positions, start = [], 0
    for n, w in zip(narrow_pieces, wide_pieces, strict=True):
        positions += range(start, start + n)
        start += w
    return torch.tensor(positions)


def widen_into(wide: ReshadeNet, narrow: ReshadeNet) -> int:
    """Copies `narrow`'s weights into `wide` (same head, depth and camera MLP, every width
    at least as large) as described above; returns how many tensors were copied."""
    if narrow.cfg.film or wide.cfg.film:
        raise ValueError("widening a network with FiLM layers is not supported")
    same = ("convs", "camera_hidden", "head", "lobes", "domain", "amplitude")
    for field in same:
        if getattr(wide.cfg, field) != getattr(narrow.cfg, field):
            raise ValueError(f"cannot widen: the networks differ in {field}")
    if any(w < n for w, n in zip(wide.cfg.widths, narrow.cfg.widths, strict=True)):
        raise ValueError(f"cannot widen {narrow.cfg.widths} into narrower {wide.cfg.widths}")
    pieces = _segments(wide, narrow)
    narrow_modules = dict(narrow.named_modules())
    copied = 0
    with torch.no_grad():
        for name, module in wide.named_modules():
            source = narrow_modules.get(name)
            if isinstance(module, nn.Conv2d):
                old_in = _old_positions(*pieces[name])
                out = source.weight.shape[0]
                module.weight[:out] = 0.0
                module.weight[:out, old_in] = source.weight
                module.bias[:out] = source.bias
                copied += 2
            elif isinstance(module, nn.Linear):
                module.load_state_dict(source.state_dict())
                copied += 2
    return copied
