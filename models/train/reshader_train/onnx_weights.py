"""Start training from an exported model: its ONNX initializers carry the parameter names
of the PyTorch network (`export` writes them so), which lets a run fine-tune a shipped
model when only the deployable files were kept, not the checkpoint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch


def load_onnx_weights(
    net: torch.nn.Module, files: list[Path], label: str = "--init-from", partial: bool = False
) -> int:
    """Copy every parameter of `net` from the fp32 ONNX `files`; returns how many.

    Refuses files that lack a parameter, hold it in another shape (another --size) or in
    another type (a quantised or half-precision export). With `partial`, parameters that
    are missing or shaped differently (another output head) keep their initial values
    instead, so that a new head starts from a trained model's features."""
    import onnx
    from onnx import numpy_helper

    found: dict[str, tuple[Path, np.ndarray]] = {}
    for path in files:
        try:
            graph = onnx.load(str(path)).graph
        except Exception as err:  # onnx raises DecodeError, OSError, ...
            raise ValueError(f"{label} {path}: not a readable ONNX file ({err})") from None
        for init in graph.initializer:
            found[init.name] = (path, numpy_helper.to_array(init))
    params = dict(net.named_parameters())
    if partial:
        params = {
            name: p
            for name, p in params.items()
            if name in found and found[name][1].shape == tuple(p.shape)
        }
        if not params:
            raise ValueError(f"{label} {' '.join(map(str, files))}: no parameter matches")
    missing = [name for name in params if name not in found]
    if missing:
        names = ", ".join(missing[:3]) + (", ..." if len(missing) > 3 else "")
        raise ValueError(
            f"{label} {' '.join(map(str, files))}: no weights for {len(missing)} of the "
            f"network's {len(params)} parameters ({names}); give the fp32 encoder and "
            "decoder of a model exported at the same --size"
        )
    with torch.no_grad():
        for name, param in params.items():
            path, value = found[name]
            if value.dtype != np.float32 or value.shape != tuple(param.shape):
                raise ValueError(
                    f"{label} {path}: {name} is {value.dtype} {list(value.shape)}, the "
                    f"network wants float32 {list(param.shape)} (an fp32 export of this --size)"
                )
            param.copy_(torch.from_numpy(value.copy()))
    return len(params)
