"""`reshader-train evaluate`: how much reshading helps, in the layout of the paper's Table 2.

For every example of each dataset folder given, the tone-mapped input ("Input": no
reshading) and the network's output ("Ours") are compared with the tone-mapped ground-truth
reshaded image, both masked by the validity mask. Tone mapping is fixed (see tonemap.py:
exposure EVAL_EXPOSURE, gamma EVAL_GAMMA) so numbers compare across runs. PSNR and SSIM are
means over examples; the gain is the mean per-example PSNR difference. A mean of PSNRs is
dominated by images that hardly change (50-60 dB, where a residual of 1e-3 costs several
dB), so the table also gives the median gain, how many examples improved, and the pooled
PSNR (of the mean squared error over every valid pixel of the split).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .data import list_examples, load_example, make_sample
from .model import ALIGN, NetConfig, ReshadeNet
from .tonemap import EVAL_EXPOSURE, EVAL_GAMMA

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5


def masked_mse(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> float:
    """Mean squared error over valid pixels of (3,H,W) images; mask is (1,H,W)."""
    valid = mask.expand_as(pred) > 0.5
    return float(((pred - target)[valid] ** 2).mean()) if valid.any() else float("nan")


def psnr_of_mse(mse: float) -> float:
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


def masked_psnr(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> float:
    """PSNR over valid pixels of (3,H,W) images in [0,1]; mask is (1,H,W)."""
    return psnr_of_mse(masked_mse(pred, target, mask))


def _gaussian_window(channels: int) -> torch.Tensor:
    x = torch.arange(SSIM_WINDOW, dtype=torch.float32) - SSIM_WINDOW // 2
    g = torch.exp(-(x**2) / (2 * SSIM_SIGMA**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(channels, 1, SSIM_WINDOW, SSIM_WINDOW).contiguous()


def ssim_map(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM (Wang et al. 2004, Gaussian 11x11 sigma 1.5) of (C,H,W) images in [0,1]."""
    c = a.shape[0]
    win = _gaussian_window(c)
    pad = SSIM_WINDOW // 2

    def blur(x: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.pad(x[None], (pad,) * 4, mode="reflect"), win, groups=c)[0]

    c1, c2 = 0.01**2, 0.03**2
    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a**2
    var_b = blur(b * b) - mu_b**2
    cov = blur(a * b) - mu_a * mu_b
    return ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / (
        (mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2)
    )


def masked_ssim(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> float:
    valid = mask.expand_as(pred) > 0.5
    return float(ssim_map(pred, target)[valid].mean())


def pad_to_multiple(x: torch.Tensor, multiple: int = ALIGN) -> torch.Tensor:
    """Replicate-pad (N,C,H,W) at the bottom/right to multiples of `multiple`."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    return F.pad(x, (0, pw, 0, ph), mode="replicate") if ph or pw else x


@torch.no_grad()
def reshade(
    net: ReshadeNet,
    image: torch.Tensor,
    disparity: torch.Tensor,
    camera: torch.Tensor,
    rays: torch.Tensor | None = None,
):
    """Full-image inference on (3,H,W)/(1,H,W)/(3,)/(3,H,W) tensors: pad, run, crop, clamp.
    `rays` (a sample's) is needed by the lobe head only."""
    h, w = image.shape[-2:]
    padded_rays = None if rays is None else pad_to_multiple(rays[None])
    out = net(
        pad_to_multiple(image[None]), pad_to_multiple(disparity[None]), camera[None], padded_rays
    )
    return out[0, :, :h, :w].clamp(0.0, 1.0)


@torch.no_grad()
def residual_at(
    net: ReshadeNet,
    image: torch.Tensor,
    disparity: torch.Tensor,
    camera: torch.Tensor,
    scale: float = 1.0,
    transpose: bool = False,
) -> torch.Tensor:
    """The residual head's change (output − input, unclamped) for `camera`, with the
    network run at `scale` of the image's size as `render --reshade-scale` runs it: inputs
    area-averaged down, the residual bilinear back up. `transpose` runs it on the image
    turned about its diagonal (rows for columns, the camera's x and y swapped) and turns the
    residual back: the same view if the network were symmetric under the transpose, which
    training with the eight symmetries only approximates (a runtime could then always run
    the network on the orientation tract runs fastest)."""
    if transpose:
        flipped = residual_at(
            net,
            image.transpose(-1, -2),
            disparity.transpose(-1, -2),
            camera[[1, 0, 2]],
            scale,
        )
        return flipped.transpose(-1, -2)
    h, w = image.shape[-2:]
    size = (max(1, round(h * scale)), max(1, round(w * scale)))
    img, disp = image[None], disparity[None]
    if size != (h, w):
        img = F.interpolate(img, size=size, mode="area")
        disp = F.interpolate(disp, size=size, mode="area")
    out = net(pad_to_multiple(img), pad_to_multiple(disp), camera[None], None)
    residual = out[:, :, : size[0], : size[1]] - img
    if size != (h, w):
        residual = F.interpolate(residual, size=(h, w), mode="bilinear", align_corners=False)
    return residual[0]


@torch.no_grad()
def lobe_change_at(
    net: ReshadeNet,
    image: torch.Tensor,
    disparity: torch.Tensor,
    rays: torch.Tensor,
    camera: torch.Tensor,
    scale: float,
) -> torch.Tensor:
    """A lobe head's change (view − input) for `camera` with its network and closed form at
    `scale` of the image's size, as the runtime's working size runs them: inputs
    area-averaged down, the rays bilinearly (they are affine in the pixel, so that is
    exactly the rays of the smaller image's pixel centres), the change bilinear back up."""
    h, w = image.shape[-2:]
    size = (max(1, round(h * scale)), max(1, round(w * scale)))
    img = F.interpolate(image[None], size=size, mode="area")
    disp = F.interpolate(disparity[None], size=size, mode="area")
    small_rays = F.interpolate(rays[None], size=size, mode="bilinear", align_corners=False)
    view = reshade(net, img[0], disp[0], camera, small_rays[0])
    change = F.interpolate(view[None] - img, size=(h, w), mode="bilinear", align_corners=False)
    return change[0]


@torch.no_grad()
def reshade_like_runtime(
    net: ReshadeNet,
    image: torch.Tensor,
    disparity: torch.Tensor,
    camera: torch.Tensor,
    key_spacing: float = 0.0,
    scale: float = 1.0,
    transpose: bool = False,
    rays: torch.Tensor | None = None,
) -> torch.Tensor:
    """The view at `camera` as the runtime's per-view cost options make it: the network at
    `scale` (`render --reshade-scale`) and, with `key_spacing`, the residual blended halfway
    between two key views that far apart along x (`render --key-views` at its worst: where
    a linear blend strays furthest from a residual that is not linear in the camera). The
    lobe heads (which need `rays`) have the scale only: their closed form has no key views."""
    if not net.cfg.takes_camera:
        if key_spacing > 0 or transpose:
            raise ValueError(
                f"the {net.cfg.head} head has no key views or transposed runs (its views are "
                "a closed form)"
            )
        if rays is None:
            raise ValueError(f"the {net.cfg.head} head needs each pixel's ray (rays)")
        change = lobe_change_at(net, image, disparity, rays, camera, scale)
        return (image + change).clamp(0.0, 1.0)
    if key_spacing > 0:
        step = torch.tensor([key_spacing / 2, 0.0, 0.0], dtype=camera.dtype)
        keys = [
            residual_at(net, image, disparity, camera + d * step, scale, transpose) for d in (-1, 1)
        ]
        residual = (keys[0] + keys[1]) / 2
    else:
        residual = residual_at(net, image, disparity, camera, scale, transpose)
    return (image + residual).clamp(0.0, 1.0)


def read_checkpoint(path: Path, device: torch.device | str = "cpu") -> dict:
    """A checkpoint's dictionary, refused unless it holds a model and its network config."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    ckpt = torch.load(path, map_location=device, weights_only=False)
    if "model" not in ckpt or "net_config" not in ckpt:
        raise ValueError(f"{path}: not a reshader training checkpoint (no model/net_config)")
    return ckpt


def model_from_checkpoint(ckpt: dict, device: torch.device | str = "cpu") -> ReshadeNet:
    """The float network a checkpoint read by `read_checkpoint` holds, in evaluation mode."""
    net = ReshadeNet(NetConfig.from_json(ckpt["net_config"])).to(device)
    net.load_state_dict(ckpt["model"])
    net.eval()
    return net


def load_checkpoint_model(
    path: Path, device: torch.device | str = "cpu"
) -> tuple[ReshadeNet, dict]:
    ckpt = read_checkpoint(path, device)
    return model_from_checkpoint(ckpt, device), ckpt


def load_evaluated_model(path: Path) -> tuple[ReshadeNet, dict]:
    """A float checkpoint's network, or a `quantize` checkpoint's int8 network as exported
    in the form QAT fine-tuned (weights alone for `--form weights`, the shipped int8)."""
    from .quantize import load_any_checkpoint, set_input_quantization

    net, ckpt = load_any_checkpoint(path)
    quantization = ckpt.get("quantization")
    if quantization and quantization.get("qat_form") == "weights":
        set_input_quantization(net, False)
    return net, ckpt


def lpips_metric():
    """(LPIPS callable, None) when lpips and its AlexNet weights are on disk, else (None, why)."""
    try:
        import lpips  # noqa: F401
    except ImportError:
        return None, "LPIPS: not available (no weights: the lpips package is not installed)"
    torch_home = Path(os.environ.get("TORCH_HOME", Path.home() / ".cache/torch"))
    if not list((torch_home / "hub/checkpoints").glob("alexnet-*.pth")):
        return (
            None,
            "LPIPS: not available (no weights: AlexNet backbone not in the torch hub cache)",
        )
    import lpips

    model = lpips.LPIPS(net="alex", verbose=False).eval()

    def metric(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> float:
        with torch.no_grad():
            return float(model(pred[None] * mask * 2 - 1, target[None] * mask * 2 - 1))

    return metric, None


def target_sample(ex, target: int) -> dict:
    """The evaluation sample of `ex` against its target number `target` (0: the first, as
    every example has; -1: its last), with the single-target keys."""
    if target == 0:
        return make_sample(ex, crop=None, rng=None, aug=None)
    if not -ex.target_count <= target < ex.target_count:
        raise ValueError(f"{ex.name}: has {ex.target_count} target(s), no target {target}")
    k = target % ex.target_count
    s = make_sample(ex, crop=None, rng=None, aug=None, targets=ex.target_count)
    picked = {"target": s["targets"][k], "mask": s["masks"][k], "camera": s["cameras"][k]}
    rest = {n: v for n, v in s.items() if n not in ("targets", "masks", "cameras", "weights")}
    return {**rest, **picked}


# One 8-bit level: the smallest change a display shows.
LEVEL = 1.0 / 255.0


def view_gate(image: torch.Tensor, view: torch.Tensor, fraction: float) -> torch.Tensor:
    """`view`, or the photo `image` itself where under `fraction` of the pixels differ from
    it by more than a level in any colour, as `render --reshade-gate` decides per view: a
    change that small is the network's noise on a view whose shading does not move (whole
    diffuse scenes), not a highlight. 0 keeps every view."""
    if fraction <= 0.0:
        return view
    changed = ((view - image).abs().amax(dim=0) > LEVEL).float().mean()
    return image if float(changed) < fraction else view


def evaluate_folder(
    net: ReshadeNet,
    root: Path,
    limit: int | None,
    lpips_fn=None,
    target: int = 0,
    key_spacing: float = 0.0,
    scale: float = 1.0,
    transpose: bool = False,
    change_scale: float = 1.0,
    gate: float = 0.0,
) -> list[dict]:
    rows = []
    for folder in list_examples(root)[:limit]:
        ex = load_example(folder)
        s = target_sample(ex, target)
        if key_spacing > 0 or scale != 1.0 or transpose:
            ours = reshade_like_runtime(
                net,
                s["image"],
                s["disparity"],
                s["camera"],
                key_spacing,
                scale,
                transpose,
                s["rays"],
            )
        else:
            ours = reshade(net, s["image"], s["disparity"], s["camera"], s["rays"])
        if change_scale != 1.0:
            ours = (s["image"] + change_scale * (ours - s["image"])).clamp(0.0, 1.0)
        ours = view_gate(s["image"], ours, gate)
        row = {"split": root.name, "scene": ex.scene, "example": ex.name}
        row["valid_values"] = int((s["mask"].expand_as(ours) > 0.5).sum())
        for method, img in (("input", s["image"]), ("ours", ours)):
            row[f"mse_{method}"] = masked_mse(img, s["target"], s["mask"])
            row[f"psnr_{method}"] = psnr_of_mse(row[f"mse_{method}"])
            row[f"ssim_{method}"] = masked_ssim(img, s["target"], s["mask"])
            if lpips_fn is not None:
                row[f"lpips_{method}"] = lpips_fn(img, s["target"], s["mask"])
        row["_images"] = (s["image"], ours, s["target"], s["mask"])
        rows.append(row)
    return rows


# Views whose input is below this PSNR against the truth are "changing" (the shading moves
# visibly); the rest are "static": the gain on the first and the loss on the second are
# the two numbers a reshading model is judged by.
CHANGING_BELOW_DB = 40.0


def split_by_change(rows: list[dict]) -> dict[str, list[dict]]:
    return {
        "changing": [r for r in rows if r["psnr_input"] < CHANGING_BELOW_DB],
        "static": [r for r in rows if r["psnr_input"] >= CHANGING_BELOW_DB],
    }


def gains_by_change(rows: list[dict]) -> dict[str, list[float]]:
    """Each view's PSNR gain over its input, the changing views apart from the static."""
    return {
        part: [r["psnr_ours"] - r["psnr_input"] for r in part_rows]
        for part, part_rows in split_by_change(rows).items()
    }


def summarise(rows: list[dict]) -> dict[str, dict]:
    """Per split (and per scene when a split has several; all splits together when there
    are several) mean metrics and PSNR gain."""
    groups: dict[str, list[dict]] = defaultdict(list)
    if len({r["split"] for r in rows}) > 1:  # several folders: their union first
        groups["all"] = list(rows)
    for r in rows:
        groups[r["split"]].append(r)
        groups[f"{r['split']}/{r['scene']}"].append(r)
    out = {}
    for name, rs in groups.items():
        if "/" in name and len({r["scene"] for r in groups[name.split("/")[0]]}) < 2:
            continue
        keys = [k for k in rs[0] if k.startswith(("psnr_", "ssim_", "lpips_"))]
        out[name] = {k: float(np.mean([r[k] for r in rs])) for k in keys}
        gains = [r["psnr_ours"] - r["psnr_input"] for r in rs]
        out[name]["gain_db"] = float(np.mean(gains))
        out[name]["gain_median_db"] = float(np.median(gains))
        out[name]["improved"] = int(sum(g > 0 for g in gains))
        for part, part_gains in gains_by_change(rs).items():
            out[name][f"gain_{part}_db"] = float(np.mean(part_gains)) if part_gains else None
            out[name][f"count_{part}"] = len(part_gains)
        weights = [r["valid_values"] for r in rs]
        for method in ("input", "ours"):
            pooled = np.average([r[f"mse_{method}"] for r in rs], weights=weights)
            out[name][f"pooled_psnr_{method}"] = psnr_of_mse(float(pooled))
        out[name]["count"] = len(rs)
    return out


def format_table(
    summary: dict[str, dict], lpips_note: str | None, labels: tuple[str, str] = ("Input", "Ours")
) -> str:
    lines = [
        f"Tone mapping: exposure x{EVAL_EXPOSURE}, gamma {EVAL_GAMMA}; metrics masked by validity.",
        f"{'Split / scene':<28} {'Method':<7} {'PSNR':>7} {'SSIM':>7} {'LPIPS':>7}",
    ]
    for name, m in summary.items():
        for i, (method, label_text) in enumerate(zip(("input", "ours"), labels, strict=True)):
            label = f"{name} (n={m['count']})" if i == 0 else ""
            lp = f"{m[f'lpips_{method}']:7.4f}" if f"lpips_{method}" in m else f"{'-':>7}"
            lines.append(
                f"{label:<28} {label_text:<7} {m[f'psnr_{method}']:7.2f} "
                f"{m[f'ssim_{method}']:7.4f} {lp}"
            )
        lines.append(
            f"{'':<28} gain    {m['gain_db']:+7.2f} dB (median {m['gain_median_db']:+.2f}, "
            f"{m['improved']}/{m['count']} improved; pooled PSNR "
            f"{m['pooled_psnr_input']:.2f} -> {m['pooled_psnr_ours']:.2f})"
        )
        parts = [
            f"{part} {m[f'gain_{part}_db']:+.2f} dB (n={m[f'count_{part}']})"
            for part in ("changing", "static")
            if m[f"count_{part}"]
        ]
        lines.append(
            f"{'':<28} by view: "
            + ", ".join(parts)
            + f" (input below / at or above {CHANGING_BELOW_DB:.0f} dB)"
        )
    if lpips_note:
        lines.append(lpips_note)
    return "\n".join(lines)


def write_sheet(rows: list[dict], path: Path, count: int = 6) -> None:
    """Rows of input | ours | ground truth | |ours - gt| x4 (invalid pixels tinted red)."""
    from PIL import Image

    tiles = []
    for r in rows[:count]:
        image, ours, target, mask = r["_images"]
        err = (
            ((ours - target).abs().mean(0, keepdim=True) * 4).clamp(0, 1).expand(3, -1, -1).clone()
        )
        err[0] = torch.where(mask[0] > 0.5, err[0], torch.ones_like(err[0]))
        tiles.append(torch.cat([image, ours, target, err], dim=2))
    width = max(t.shape[2] for t in tiles)
    tiles = [F.pad(t, (0, width - t.shape[2])) for t in tiles]
    sheet = torch.cat(tiles, dim=1).permute(1, 2, 0).numpy()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    Image.fromarray((sheet * 255 + 0.5).astype(np.uint8)).save(tmp, format="PNG")
    os.replace(tmp, path)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--checkpoint",
        type=Path,
        required=True,
        help="training checkpoint (.pt), or `quantize`'s: its int8 network in the form it "
        "was fine-tuned for (--form weights: int8 weights, float activations, as the int8 files)",
    )
    p.add_argument("--data", type=Path, nargs="+", required=True, help="held-out dataset folder(s)")
    p.add_argument("--limit", type=int, help="first N examples of each folder")
    p.add_argument("--sheet", type=Path, help="visual sheet PNG (input | ours | GT | error)")
    p.add_argument("--json", type=Path, help="write per-split metrics as JSON")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch default)")
    p.add_argument(
        "--target",
        type=int,
        default=0,
        help="which reshaded target of examples rendered with several to score: 0 the first "
        "(default; every example has it), -1 the last (the camera `field-fit` holds out)",
    )
    p.add_argument(
        "--key-spacing",
        type=float,
        default=0.0,
        help="score each view as `render --key-views` makes it at worst: blended halfway "
        "between two key views this far apart along x (training units; a board's cone spans "
        "0.6, so K key views are 0.6/(K-1) apart). 0 (default): the network at every view",
    )
    p.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help="run the network at this fraction of each image's size and upsample its "
        "residual (a lobe head: its network and closed form, and upsample the change), as "
        "`render --reshade-scale` does (default 1)",
    )
    p.add_argument(
        "--transpose",
        action="store_true",
        help="run the network on each image turned about its diagonal (camera x and y "
        "swapped) and turn its change back: what running it in another orientation costs",
    )
    p.add_argument(
        "--change-scale",
        type=float,
        default=1.0,
        help="multiply each view's change (view - photo) by this before scoring: whether a "
        "model that looks timid would score better bolder (default 1: as predicted)",
    )
    p.add_argument(
        "--view-gate",
        type=float,
        default=0.0,
        help="score each view as `render --reshade-gate F` makes it: the photo itself where "
        "under F of its pixels change by more than a level (default 0: every view as "
        "predicted; the runtime's default is 0.02)",
    )


def run(args: argparse.Namespace) -> int:
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    try:
        net, ckpt = load_evaluated_model(args.checkpoint)
    except (FileNotFoundError, ValueError) as err:
        print(f"evaluate: {err}", file=sys.stderr)
        return 2
    lpips_fn, lpips_note = lpips_metric()
    rows = []
    try:
        for root in args.data:
            rows += evaluate_folder(
                net,
                root,
                args.limit,
                lpips_fn,
                args.target,
                args.key_spacing,
                args.scale,
                args.transpose,
                args.change_scale,
                args.view_gate,
            )
    except ValueError as err:
        print(f"evaluate: {err}", file=sys.stderr)
        return 2
    summary = summarise(rows)
    step, feats = ckpt.get("step"), ckpt.get("feature_net")
    print(f"checkpoint {args.checkpoint} (step {step}, feature net {feats})")
    print(format_table(summary, lpips_note))
    if args.json:
        report = {
            "checkpoint": str(args.checkpoint),
            "step": ckpt.get("step"),
            "feature_net": ckpt.get("feature_net"),
            "exposure": EVAL_EXPOSURE,
            "gamma": EVAL_GAMMA,
            "key_spacing": args.key_spacing,
            "scale": args.scale,
            "transpose": args.transpose,
            "change_scale": args.change_scale,
            "view_gate": args.view_gate,
            "lpips": lpips_note or "available",
            "splits": summary,
            "examples": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows],
        }
        tmp = args.json.with_name(f".{args.json.name}.tmp")
        tmp.write_text(json.dumps(report, indent=2))
        os.replace(tmp, args.json)
    if args.sheet:
        write_sheet(rows, args.sheet)
        print(f"sheet: {args.sheet}")
    return 0
