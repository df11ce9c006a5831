"""Compare a converted depth model's disparity with the original implementation's output."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .preprocess import load_rgb, network_input


@dataclass
class Errors:
    """Disparity (exp of the network output) against the reference disparity."""

    photo: str
    size: list[int]
    max_rel: float
    mean_rel: float
    pearson: float

    def as_dict(self) -> dict:
        return asdict(self)


def disparity_errors(photo: str, log_disparity: np.ndarray, reference: np.ndarray) -> Errors:
    disparity = np.exp(np.asarray(log_disparity, np.float64)).reshape(reference.shape)
    ref = np.asarray(reference, np.float64)
    if not np.all(ref > 0):
        raise ValueError(f"{photo}: reference disparity has non-positive values")
    rel = np.abs(disparity - ref) / ref
    pearson = float(np.corrcoef(disparity.ravel(), ref.ravel())[0, 1])
    return Errors(photo, list(ref.shape), float(rel.max()), float(rel.mean()), pearson)


def reference_pairs(source: Path) -> list[tuple[Path, Path]]:
    """(photo, reference .npy) pairs shipped with the model: input/NAME.jpg, output/NAME.npy."""
    pairs = []
    for photo in sorted((source / "input").glob("*.jpg")):
        ref = source / "output" / f"{photo.stem}.npy"
        if ref.is_file():
            pairs.append((photo, ref))
    if not pairs:
        raise FileNotFoundError(f"{source}: no input/*.jpg with a matching output/*.npy")
    return pairs


def onnxruntime_outputs(model_path: Path, pairs: list[tuple[Path, Path]]) -> list[np.ndarray]:
    """Run the ONNX file with onnxruntime (CPU, 2 threads) on each reference photo."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    session = ort.InferenceSession(str(model_path), options, providers=["CPUExecutionProvider"])
    input_name = session.get_inputs()[0].name
    out = []
    for photo, ref_path in pairs:
        x = network_input(load_rgb(photo))
        reference = np.load(ref_path)
        if reference.shape != x.shape[2:]:
            raise ValueError(
                f"{ref_path}: reference is {reference.shape}, network input is {x.shape[2:]}"
            )
        (y,) = session.run(None, {input_name: x})
        out.append(y.reshape(reference.shape))
    return out


def identical_levels(log_disparity: np.ndarray, reference: np.ndarray, scale: float) -> float:
    """Fraction of pixels whose output quantisation level equals the reference's."""
    ours = np.rint(np.asarray(log_disparity, np.float64) / scale)
    ref = np.rint(np.log(np.asarray(reference, np.float64)) / scale)
    return float(np.mean(ours == ref))


def emulation_agreement(model, pairs: list[tuple[Path, Path]]) -> list[dict]:
    """How many output levels of the numpy QNNPACK emulation equal the reference's levels."""
    from .qnnpack import run_int8

    out = []
    for photo, ref_path in pairs:
        q8, q = run_int8(model, network_input(load_rgb(photo)))
        log_disparity = (q8.astype(np.float64) - q.zero_point) * q.scale
        reference = np.load(ref_path)
        out.append(
            {
                "photo": photo.name,
                "identical_output_levels": identical_levels(log_disparity, reference, q.scale),
                "max_rel": disparity_errors(photo.name, log_disparity, reference).max_rel,
            }
        )
    return out
