"""The shipped fp32 depth graph as a PyTorch module, its weights trainable.

The graph is Conv, Clip, Add, Resize (nearest, x2) and Identity in a chain of named
blobs. Its clips are the activation ranges the int8 network was trained with: they stay
fixed (buffers), only the convolutions' weights and biases learn, so that the tuned
weights write back into the same graph (`export.py`) and the runtime loads it as it
loads the shipped file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import torch
import torch.nn.functional as F
from onnx import numpy_helper

OPS = ("Conv", "Clip", "Add", "Resize", "Identity")


class GraphError(ValueError):
    """The ONNX file is not a graph this module can run."""


def _attrs(node) -> dict:
    return {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}


def weight_key(name: str) -> str:
    """An initializer's name as a ParameterDict key, which may not contain dots."""
    return name.replace(".", "_")


def learned_names(model: onnx.ModelProto) -> list[str]:
    """The initializers that learn: every convolution's weights and bias, in graph order."""
    return [name for node in model.graph.node if node.op_type == "Conv" for name in node.input[1:]]


class DepthGraph(torch.nn.Module):
    def __init__(self, model: onnx.ModelProto):
        super().__init__()
        graph = model.graph
        self.input_name = graph.input[0].name
        self.output_name = graph.output[0].name
        for node in graph.node:
            if node.op_type not in OPS:
                raise GraphError(f"unsupported op {node.op_type} ({node.name or node.output[0]})")
        consts = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
        self.weights = torch.nn.ParameterDict(
            {
                weight_key(name): torch.nn.Parameter(
                    torch.from_numpy(np.array(consts[name], dtype=np.float32))
                )
                for name in learned_names(model)
            }
        )
        self.fixed: dict[str, torch.Tensor] = {}
        self.steps = []
        for node in graph.node:
            if node.op_type == "Clip":
                lo, hi = (float(consts[n]) for n in node.input[1:3])
                self.fixed[node.output[0]] = torch.tensor([lo, hi])
            elif node.op_type == "Resize":
                scales = consts[node.input[2]]
                if not np.allclose(scales, [1, 1, 2, 2]):
                    raise GraphError(f"Resize {node.output[0]}: scales {scales}, expected x2")
            self.steps.append((node.op_type, list(node.input), node.output[0], _attrs(node)))

    @classmethod
    def load(cls, path: Path) -> DepthGraph:
        from google.protobuf.message import DecodeError

        try:
            model = onnx.load(str(path))
        except (OSError, DecodeError) as err:
            raise GraphError(f"{path}: not a readable ONNX file ({err})") from err
        try:
            return cls(model)
        except GraphError as err:
            raise GraphError(f"{path}: {err}") from err

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """image: [N, 3, H, W] RGB in [0, 1] -> log disparity [N, 1, H, W]."""
        blobs = {self.input_name: image}
        for op, inputs, output, attrs in self.steps:
            x = blobs[inputs[0]]
            if op == "Conv":
                w = self.weights[weight_key(inputs[1])]
                b = self.weights[weight_key(inputs[2])] if len(inputs) > 2 else None
                pads = attrs.get("pads", [0, 0, 0, 0])
                if pads[0] != pads[2] or pads[1] != pads[3]:
                    x = F.pad(x, (pads[1], pads[3], pads[0], pads[2]))
                    pads = [0, 0, 0, 0]
                blobs[output] = F.conv2d(
                    x,
                    w,
                    b,
                    stride=attrs.get("strides", [1, 1]),
                    padding=(pads[0], pads[1]),
                    dilation=attrs.get("dilations", [1, 1]),
                    groups=attrs.get("group", 1),
                )
            elif op == "Clip":
                lo, hi = self.fixed[output].tolist()
                blobs[output] = x.clamp(lo, hi)
            elif op == "Add":
                blobs[output] = x + blobs[inputs[1]]
            elif op == "Resize":
                blobs[output] = F.interpolate(x, scale_factor=2.0, mode="nearest")
            else:
                blobs[output] = x
        return blobs[self.output_name]
