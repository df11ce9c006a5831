"""Reading the rendered dataset and making training samples (paper section 3.5).

Layout (written by `reshader-train render`): `<root>/<id>/` with `input.exr`, `reshaded.exr`
(RGB float HDR), `depth.exr` (one channel, z-depth along the optical axis, inf on a miss),
`mask.png` (8-bit, 255 = valid) and `meta.json` with "novel_offset" [tx, ty, tz] (OpenCV
frame of the input camera, scene units) and "input_camera" (fx, fy, cx, cy in pixels). Only
folders with a meta.json are complete; `.tmp-*` folders are renders in progress.

An example may carry further reshaded targets (`render --targets T`):
`reshaded-<k>.exr` and `mask-<k>.png` for k = 1 .. T-1, listed in meta.json's
"extra_targets" as {"offset": [tx, ty, tz], "camera": {...}, "reshaded": "reshaded-<k>.exr",
"mask": "mask-<k>.png"}. The files above are always the first target, so a reader that
knows only them sees a one-target example.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from .tonemap import EVAL_EXPOSURE, EVAL_GAMMA, EXPOSURE_RANGE, GAMMA_RANGE, tonemap

DISPARITY_SCALE_RANGE = (0.5, 2.0)
DEPTH_CHANNEL_NAMES = ("Y", "Z", "depth", "R", "L")


class DatasetError(RuntimeError):
    pass


def read_exr(path: Path, channels: int) -> np.ndarray:
    """(H, W, channels) float32; RGB(A) files give R, G, B, one-channel files their channel."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            planes = {name: ch.pixels for name, ch in f.channels().items()}
    except Exception as err:
        raise DatasetError(f"{path}: cannot read EXR ({err})") from err
    if channels == 3:
        names = ["R", "G", "B"]
    elif len(planes) == 1:
        names = list(planes)
    else:
        names = [next((n for n in DEPTH_CHANNEL_NAMES if n in planes), "")]
    missing = [n for n in names if n not in planes]
    if missing:
        raise DatasetError(f"{path}: expected channels {names}, file has {sorted(planes)}")
    return np.stack([planes[n].astype(np.float32, copy=False) for n in names], axis=-1)


def read_mask(path: Path) -> np.ndarray:
    from PIL import Image

    try:
        with Image.open(path) as im:
            a = np.asarray(im.convert("L"))
    except Exception as err:
        raise DatasetError(f"{path}: cannot read mask PNG ({err})") from err
    return a >= 128


def disparity_from_depth(depth: np.ndarray) -> np.ndarray:
    """The network's disparity input d = clamp(0.25 / depth, 0, 1); misses (inf, 0, nan) -> 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        d = 0.25 / depth
    d[~np.isfinite(d) | (depth <= 0)] = 0.0
    return np.clip(d, 0.0, 1.0).astype(np.float32)


def list_examples(root: Path) -> list[Path]:
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder does not exist")
    found = sorted(
        p
        for p in root.iterdir()
        if p.is_dir() and not p.name.startswith(".tmp-") and (p / "meta.json").is_file()
    )
    if not found:
        raise DatasetError(f"{root}: no complete examples (folders with meta.json)")
    return found


def scene_name(meta: dict) -> str:
    """A short label to group evaluation results: the scene file's name or the procedural kind."""
    scene = meta.get("scene")
    if isinstance(scene, dict):
        if scene.get("file"):
            return Path(str(scene["file"])).stem
        return str(scene.get("kind", "all"))
    return str(scene) if scene else "all"


@dataclass
class Target:
    """A further reshaded target of an example: its image, mask and camera offset."""

    reshaded: np.ndarray  # (H, W, 3) HDR
    mask: np.ndarray  # (H, W) bool
    offset: np.ndarray  # (3,)


@dataclass
class FieldTargets:
    """A lobe head's fields fitted to an example (`reshader-train teacher`): per pixel the
    LobeField layout, `lobes` lobes first (their axes are vectors in the camera frame, which
    the flips and the transpose turn as they turn the rays), then the head's scalars.

    `hdr`: fields the renderer knows (`teacher --source renderer`), whose amplitudes are
    HDR radiance and whose sliding fraction is the linear share of the light; a sample
    puts them in its own tone mapping (`tone_mapped`)."""

    fields: np.ndarray  # (H, W, C) float16
    lobes: int
    hdr: bool = False

    def flipped(self, axis: int) -> FieldTargets:
        """Mirrored along image axis 0 (rows: y) or 1 (columns: x); that axis component of
        every lobe axis changes sign."""
        f = np.flip(self.fields, axis).copy()
        f[..., [7 * j + 1 - axis for j in range(self.lobes)]] *= -1
        return replace(self, fields=f)

    def transposed(self) -> FieldTargets:
        f = self.fields.swapaxes(0, 1).copy()
        xs, ys = ([7 * j + c for j in range(self.lobes)] for c in (0, 1))
        f[..., xs + ys] = f[..., ys + xs]
        return replace(self, fields=f)

    def window(self, win: tuple[slice, slice]) -> FieldTargets:
        return replace(self, fields=self.fields[win])

    def tone_mapped(self, hdr: np.ndarray, exposure: float, gamma: float) -> FieldTargets:
        """HDR fields as a network sees them through tonemap(exposure, gamma): amplitudes
        in its linear domain (a lobe's peak tone-mapped alone, then up by the inverse
        curve; beyond white, exposure times the peak, up to the top of
        LOG_AMPLITUDE_RANGE), the fraction as the share of the tone-mapped photo
        `hdr` (the window's input, (H,W,3)) that the sliding layer is."""
        from .model import LINEAR_GAMMA, LOG_AMPLITUDE_RANGE

        if not self.hdr:
            return self
        f = self.fields.astype(np.float32)
        for j in range(self.lobes):
            amp = f[..., 7 * j + 4 : 7 * j + 7]
            peak = np.clip(amp * exposure, 0.0, 1.0) ** (LINEAR_GAMMA / gamma)
            f[..., 7 * j + 4 : 7 * j + 7] = np.minimum(
                np.where(amp * exposure > 1.0, amp * exposure, peak), LOG_AMPLITUDE_RANGE[1]
            )
        if f.shape[-1] > 7 * self.lobes:
            share = f[..., 7 * self.lobes : 7 * self.lobes + 3]
            whole = tonemap(hdr, exposure, gamma)
            rest = tonemap((1.0 - share) * hdr, exposure, gamma)
            f[..., 7 * self.lobes : 7 * self.lobes + 3] = np.where(
                whole > 0, 1.0 - rest / np.maximum(whole, 1e-12), 0.0
            )
        return FieldTargets(f, self.lobes)


def teacher_settings(folder: Path) -> dict:
    """`<folder>/teacher.json`: the head and lobe count (and fit settings) of its fields."""
    path = folder / TEACHER_JSON
    try:
        settings = json.loads(path.read_text())
        head, lobes = str(settings["head"]), int(settings["lobes"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DatasetError(
            f"{path}: unreadable ({err}); fit it with `reshader-train teacher`"
        ) from err
    if head not in TEACHER_HEADS:
        raise DatasetError(f"{path}: head {head!r}, expected {TEACHER_HEADS}")
    return {**settings, "head": head, "lobes": lobes}


def load_field_targets(
    folder: Path, name: str, shape: tuple[int, int], lobes: int, hdr: bool = False
) -> FieldTargets:
    """`<folder>/<name>.npy` (C, H, W), fields of `lobes` lobes (see `teacher_settings`);
    `hdr`: the renderer's (see FieldTargets)."""
    path = folder / f"{name}.npy"
    try:
        fields = np.load(path)
    except (OSError, ValueError) as err:
        raise DatasetError(f"{path}: cannot read fitted fields ({err}); run `teacher`") from err
    if fields.ndim != 3 or fields.shape[1:] != shape:
        raise DatasetError(f"{path}: fields {fields.shape}, expected (C, {shape[0]}, {shape[1]})")
    return FieldTargets(np.ascontiguousarray(fields.transpose(1, 2, 0)), lobes, hdr)


# Heads whose fields are lobes and per-pixel scalars, so that a flip turns only the axes.
TEACHER_HEADS = ("lobes", "lobes-slide")
TEACHER_JSON = "teacher.json"


@dataclass
class Example:
    """One decoded example; HDR colours are float16 to halve the cache. `reshaded`, `mask`
    and `offset` are the first target; `extra` the others (meta.json's extra_targets)."""

    name: str
    input: np.ndarray  # (H, W, 3) HDR
    reshaded: np.ndarray  # (H, W, 3) HDR
    disparity: np.ndarray  # (H, W) network disparity, before augmentation
    mask: np.ndarray  # (H, W) bool
    offset: np.ndarray  # (3,) novel camera centre in the input camera frame
    scene: str
    intrinsics: tuple[float, float, float, float]  # fx, fy, cx, cy (pixel centres at integers)
    extra: tuple[Target, ...] = ()
    teacher: FieldTargets | None = None

    @property
    def target_count(self) -> int:
        return 1 + len(self.extra)

    def target(self, k: int) -> Target:
        """Target k (0: the first, reshaded.exr)."""
        if k == 0:
            return Target(self.reshaded, self.mask, self.offset)
        return self.extra[k - 1]


def pixel_rays(
    intrinsics: tuple[float, float, float, float], y0: int, x0: int, h: int, w: int
) -> np.ndarray:
    """(h, w, 3) K^-1 [u, v, 1] of the window whose top-left pixel is (x0, y0)."""
    fx, fy, cx, cy = intrinsics
    u = (np.arange(x0, x0 + w, dtype=np.float32) - cx) / fx
    v = (np.arange(y0, y0 + h, dtype=np.float32) - cy) / fy
    rays = np.ones((h, w, 3), dtype=np.float32)
    rays[..., 0] = u[None, :]
    rays[..., 1] = v[:, None]
    return rays


# Radiance beyond float16's range (a light seen directly, scaled to the scene's median)
# would become inf; tone mapping clips far below this anyway.
HALF_MAX = 60000.0


def to_half(image: np.ndarray) -> np.ndarray:
    return np.clip(np.nan_to_num(image, posinf=HALF_MAX), 0.0, HALF_MAX).astype(np.float16)


def _offset(value, where: str) -> np.ndarray:
    try:
        offset = np.asarray(value, dtype=np.float32)
    except (ValueError, TypeError) as err:
        raise DatasetError(f"{where} must be 3 finite numbers ({err})") from err
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise DatasetError(f"{where} must be 3 finite numbers")
    return offset


def _check_size(path: Path, arr: np.ndarray, shape: tuple[int, int]) -> None:
    if arr.shape[:2] != shape:
        raise DatasetError(f"{path}: size {arr.shape[:2]} differs from input.exr {shape}")


def _load_extra(folder: Path, meta: dict, shape: tuple[int, int]) -> tuple[Target, ...]:
    entries = meta.get("extra_targets", [])
    if not isinstance(entries, list):
        raise DatasetError(f"{folder / 'meta.json'}: extra_targets must be a list")
    out = []
    for k, entry in enumerate(entries, 1):
        where = f"{folder / 'meta.json'}: extra_targets[{k - 1}]"
        try:
            offset = _offset(entry["offset"], f"{where}.offset")
            image_name, mask_name = str(entry["reshaded"]), str(entry["mask"])
        except (KeyError, TypeError) as err:
            raise DatasetError(f"{where}: needs offset, reshaded and mask ({err})") from err
        image = read_exr(folder / image_name, 3)
        mask = read_mask(folder / mask_name)
        for name, arr in ((image_name, image), (mask_name, mask)):
            _check_size(folder / name, arr, shape)
        out.append(Target(to_half(image), mask, offset))
    return tuple(out)


def load_example(folder: Path) -> Example:
    try:
        meta = json.loads((folder / "meta.json").read_text())
        if meta.get("input_only"):
            raise DatasetError(
                f"{folder}: rendered with --input-only (a photo and its depth, for "
                "train-depth): no reshaded target to train or score a reshading network on"
            )
        raw_offset = meta["novel_offset"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DatasetError(
            f"{folder / 'meta.json'}: unreadable or no novel_offset ({err})"
        ) from err
    offset = _offset(raw_offset, f"{folder / 'meta.json'}: novel_offset")
    try:
        cam = meta["input_camera"]
        intrinsics = tuple(float(cam[k]) for k in ("fx", "fy", "cx", "cy"))
    except (KeyError, TypeError, ValueError) as err:
        raise DatasetError(
            f"{folder / 'meta.json'}: no input_camera fx, fy, cx, cy ({err})"
        ) from err
    image = read_exr(folder / "input.exr", 3)
    reshaded = read_exr(folder / "reshaded.exr", 3)
    depth = read_exr(folder / "depth.exr", 1)[..., 0]
    mask = read_mask(folder / "mask.png")
    shape = image.shape[:2]
    for name, arr in (("reshaded.exr", reshaded), ("depth.exr", depth), ("mask.png", mask)):
        _check_size(folder / name, arr, shape)
    extra = _load_extra(folder, meta, shape)
    scene = scene_name(meta)
    return Example(
        name=folder.name,
        input=to_half(image),
        reshaded=to_half(reshaded),
        disparity=disparity_from_depth(depth),
        mask=mask,
        offset=offset,
        scene=scene,
        intrinsics=intrinsics,
        extra=extra,
    )


@dataclass(frozen=True)
class Augment:
    exposure: tuple[float, float] = EXPOSURE_RANGE
    gamma: tuple[float, float] = GAMMA_RANGE
    disparity_scale: tuple[float, float] = DISPARITY_SCALE_RANGE
    flip: bool = True
    # All eight symmetries of a square crop (mirrors in x and y, and the transpose) instead
    # of the x mirror alone. A square render from a centred pinhole camera mirrored or
    # transposed is a render of the mirrored or transposed scene, so each is a valid example;
    # off by default so that earlier training commands still reproduce.
    dihedral: bool = False
    # Share of samples posed from the photo's own camera, whose truth is the photo itself:
    # no rendered pair has offset 0 (the shell starts at 0.1), yet a display's centre views
    # sit there, and a network never shown it drifts from the identity.
    still: float = 0.05


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return math.exp(rng.uniform(math.log(lo), math.log(hi)))


def _mirror_y_and_transpose(
    rng: np.random.Generator,
    planes: tuple[np.ndarray, ...],
    camera: np.ndarray,
    teacher: FieldTargets | None,
) -> tuple:
    """With the x mirror, completes the square's eight symmetries. The camera frame is
    OpenCV's (x right, y down), so mirroring rows negates ty and swapping rows with
    columns swaps tx and ty (of every row of `camera`, one per target). Non-square planes
    are never transposed (a batch of them would no longer stack)."""
    *planes, rays = planes
    if rng.random() < 0.5:
        planes = [a[::-1] for a in planes]
        rays = rays[::-1] * np.array([1.0, -1.0, 1.0], dtype=np.float32)
        camera[..., 1] = -camera[..., 1]
        teacher = teacher.flipped(0) if teacher is not None else None
    h, w = planes[0].shape[:2]
    if h == w and rng.random() < 0.5:
        planes = [a.swapaxes(0, 1) for a in planes]
        rays = rays.swapaxes(0, 1)[..., [1, 0, 2]]
        camera[..., [0, 1]] = camera[..., [1, 0]]
        teacher = teacher.transposed() if teacher is not None else None
    return (*planes, rays, camera, teacher)


def pick_targets(
    count: int, n: int | None, rng: np.random.Generator | None
) -> tuple[list[int], np.ndarray | None]:
    """Which of an example's `count` targets a sample uses, and their weights.

    n None: the first target alone (no weights), as before examples had several. Else n
    entries: with more than n targets, n distinct ones drawn at random (the first n without
    an rng); with n or fewer, all of them, then the first repeated with weight 0 up to n
    (padding, so that examples with different target counts stack into one batch). A
    draw is made only when there is a choice, so one-target data consumes the same random
    numbers as before."""
    if n is None:
        return [0], None
    if n < 1:
        raise ValueError(f"targets per example {n}: need at least 1")
    if count > n:
        picks = sorted(rng.choice(count, n, replace=False)) if rng is not None else range(n)
        return [int(k) for k in picks], np.ones(n, dtype=np.float32)
    weights = np.zeros(n, dtype=np.float32)
    weights[:count] = 1.0
    return list(range(count)) + [0] * (n - count), weights


def make_sample(
    ex: Example,
    crop: int | None,
    rng: np.random.Generator | None,
    aug: Augment | None,
    targets: int | None = None,
) -> dict[str, torch.Tensor]:
    """Crop + tone map + disparity scale. Without `aug`: fixed evaluation tone mapping, f = 1.

    Without `targets` the sample has the first target as "target" (3,H,W), "mask" (1,H,W)
    and "camera" (3,). With `targets` = N it has N of the example's targets (see
    `pick_targets`) as "targets" (N,3,H,W), "masks" (N,1,H,W), "cameras" (N,3) and
    "weights" (N,) (1 for a target, 0 for padding) instead. Every augmentation (crop,
    flips, transpose, tone mapping, disparity scale) is the same for all of them; "still"
    is drawn per target."""
    picks, weights = pick_targets(ex.target_count, targets, rng)
    chosen = [ex.target(k) for k in picks]
    h, w = ex.mask.shape
    y0 = x0 = 0
    ch, cw = h, w
    if crop is not None:
        if crop > h or crop > w:
            raise DatasetError(f"{ex.name}: crop {crop} larger than the {h}x{w} image")
        ch = cw = crop
        if rng is not None:
            y0 = int(rng.integers(0, h - crop + 1))
            x0 = int(rng.integers(0, w - crop + 1))
        else:
            y0, x0 = (h - crop) // 2, (w - crop) // 2
    win = (slice(y0, y0 + ch), slice(x0, x0 + cw))
    hdr_in = ex.input[win].astype(np.float32)
    hdr_gts = [t.reshaded[win].astype(np.float32) for t in chosen]
    disp = ex.disparity[win]
    masks = [t.mask[win] for t in chosen]
    teacher = ex.teacher
    if teacher is not None:
        teacher = teacher.window(win)
    rays = pixel_rays(ex.intrinsics, y0, x0, ch, cw)
    camera = np.stack([t.offset for t in chosen]).astype(np.float32)  # (N, 3), a copy
    n = len(chosen)
    if aug is not None and rng is not None:
        exposure = _log_uniform(rng, *aug.exposure)
        gamma = float(rng.uniform(*aug.gamma))
        f = _log_uniform(rng, *aug.disparity_scale)
        # Scaling disparity by f is scaling depth by 1/f; the camera offset scales with the
        # depth so that the picture stays the same geometry (scale covariance).
        disp = np.clip(disp * f, 0.0, 1.0)
        camera = camera / f
        if aug.flip and rng.random() < 0.5:
            # A mirrored scene seen from the mirrored camera: x flips, so does tx.
            hdr_in, disp = hdr_in[:, ::-1], disp[:, ::-1]
            hdr_gts = [a[:, ::-1] for a in hdr_gts]
            masks = [a[:, ::-1] for a in masks]
            rays = rays[:, ::-1] * np.array([-1.0, 1.0, 1.0], dtype=np.float32)
            camera[:, 0] = -camera[:, 0]
            teacher = teacher.flipped(1) if teacher is not None else None
        if aug.dihedral:
            hdr_in, disp, *planes, rays, camera, teacher = _mirror_y_and_transpose(
                rng, (hdr_in, disp, *hdr_gts, *masks, rays), camera, teacher
            )
            hdr_gts, masks = planes[:n], planes[n:]
        for k in range(n):
            if weights is not None and weights[k] == 0:
                continue  # padding: never seen by the loss
            if rng.random() < aug.still:
                hdr_gts[k], masks[k] = hdr_in, np.ones_like(masks[k])
                camera[k] = 0.0
    else:
        exposure, gamma = EVAL_EXPOSURE, EVAL_GAMMA

    def chw(a: np.ndarray) -> torch.Tensor:
        a = np.ascontiguousarray(a, dtype=np.float32)
        return torch.from_numpy(a.transpose(2, 0, 1) if a.ndim == 3 else a[None])

    sample = {
        "image": chw(tonemap(hdr_in, exposure, gamma)),
        "disparity": chw(disp),
        "rays": chw(rays),
    }
    if teacher is not None:
        sample["teacher"] = chw(teacher.tone_mapped(hdr_in, exposure, gamma).fields)
    if weights is None:
        sample["target"] = chw(tonemap(hdr_gts[0], exposure, gamma))
        sample["mask"] = chw(masks[0].astype(np.float32))
        sample["camera"] = torch.from_numpy(camera[0].astype(np.float32))
        return sample
    sample["targets"] = torch.stack([chw(tonemap(a, exposure, gamma)) for a in hdr_gts])
    sample["masks"] = torch.stack([chw(m.astype(np.float32)) for m in masks])
    sample["cameras"] = torch.from_numpy(np.ascontiguousarray(camera, dtype=np.float32))
    sample["weights"] = torch.from_numpy(weights)
    return sample


class ReshadeDataset(Dataset):
    """Training samples from a dataset folder (or a list of example folders); decoded
    examples are cached per process, by folder. `reuse` hands over another dataset's cache,
    so that a re-listed dataset (train --rescan) decodes only the new examples. `targets`:
    samples carry that many targets each (see `make_sample`); None, the first alone.
    `teacher`: a folder of fitted fields (`reshader-train teacher`), one per example, that
    samples carry as "teacher" (C,H,W), augmented with them."""

    def __init__(
        self,
        root: Path | list[Path],
        crop: int | None = None,
        augment: Augment | None = None,
        cache: bool = True,
        limit: int | None = None,
        reuse: ReshadeDataset | None = None,
        targets: int | None = None,
        teacher: Path | None = None,
    ) -> None:
        folders = list(root) if isinstance(root, list) else list_examples(Path(root))
        self.folders = folders[:limit]
        self.crop = crop
        self.augment = augment
        self.cache = cache
        self.targets = targets
        self.teacher = teacher
        told = teacher_settings(teacher) if teacher is not None else {}
        self._teacher_lobes = told.get("lobes", 0)
        self._teacher_hdr = told.get("units") == "hdr"
        self._examples: dict[Path, Example] = reuse._examples if reuse is not None else {}
        self._rng: np.random.Generator | None = None
        self._rng_pid = -1

    def __len__(self) -> int:
        return len(self.folders)

    def example(self, idx: int) -> Example:
        folder = self.folders[idx]
        ex = self._examples.get(folder)
        if ex is None:
            ex = load_example(folder)
            if self.teacher is not None:
                ex.teacher = load_field_targets(
                    self.teacher, ex.name, ex.mask.shape, self._teacher_lobes, self._teacher_hdr
                )
            if self.cache:
                self._examples[folder] = ex
        return ex

    def _generator(self) -> np.random.Generator:
        # torch gives every DataLoader worker (and every epoch's workers) its own seed.
        if self._rng is None or self._rng_pid != os.getpid():
            self._rng = np.random.default_rng(torch.initial_seed() % (2**63))
            self._rng_pid = os.getpid()
        return self._rng

    def __getitem__(self, idx: int) -> dict[str, torch.Tensor]:
        rng = self._generator() if self.augment is not None else None
        return make_sample(self.example(idx), self.crop, rng, self.augment, self.targets)
