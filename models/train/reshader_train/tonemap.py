"""HDR -> LDR as the network sees it: sRGB-like values in [0,1] = clip(exposure * hdr)^(1/gamma).

Training draws exposure and gamma per example (paper section 3.5: x3..10, 2.2..5) and applies
the same pair to input and target. Evaluation uses one fixed pair so that numbers compare
across runs: exposure EVAL_EXPOSURE, gamma EVAL_GAMMA (the middle of the training ranges on a
log scale for the exposure, the sRGB-like end for the gamma).
"""

from __future__ import annotations

import numpy as np
import torch

EXPOSURE_RANGE = (3.0, 10.0)
GAMMA_RANGE = (2.2, 5.0)
EVAL_EXPOSURE = 5.5
EVAL_GAMMA = 2.2


def tonemap(hdr, exposure: float, gamma: float):
    """Works on numpy arrays and torch tensors alike."""
    if isinstance(hdr, torch.Tensor):
        return (hdr * exposure).clamp(0.0, 1.0) ** (1.0 / gamma)
    return np.clip(hdr * exposure, 0.0, 1.0) ** (1.0 / gamma)
