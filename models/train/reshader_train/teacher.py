"""`reshader-train teacher`: a lobe head's fields fitted to every camera of each training
example, saved as per-pixel targets for `train --teacher`.

Trained through the rendered views alone, the lobe networks stay near their starting
fields (the sliding layer a uniform few per cent of the photo): a pixel's fields get a
gradient only where the camera offsets of its batch happen to move light across it. A fit
per example (see `field_fit`) finds fields that reproduce all of its cameras; a network
told those fields learns per pixel which light slides and how far, as a segmentation.

With `--source renderer` the fields are not fitted but taken from the analytic renderer
(`render.decompose`: for "lobes", each pixel's reflections of the scene's lights; for
"lobes-slide", its specular layer and the depth of the reflected image), for examples of
`render --scenes analytic`: unique, and exact where the head's model of the change is.

Writes `<out>/<example>.npy` (float16, the head's fields (C, H, W) in LobeField's layout)
and `<out>/teacher.json` (head, lobes, fit settings or the source). Resumable: examples
whose file exists are skipped; files appear whole (written under a temporary name, then
renamed). Prints, per example, what the fields gain on its own cameras.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from .data import (
    TEACHER_HEADS,
    TEACHER_JSON,
    DatasetError,
    FieldTargets,
    list_examples,
    load_example,
    make_sample,
)
from .evaluate import CHANGING_BELOW_DB
from .field_fit import add_fit_arguments, fit_fields, target_psnrs

# Measured on 6 training examples (one camera held out): at 0.01 the fraction sits on the
# highlights and the amplitudes on a few blobs, the held-out camera gains more than with
# none, and the fitted cameras nearly as much.
SPARSITY = 0.01


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, required=True, help="examples with several targets")
    p.add_argument("--out", type=Path, required=True, help="folder for the fitted fields")
    p.add_argument(
        "--head", default="lobes-slide", choices=TEACHER_HEADS, help="(default lobes-slide)"
    )
    why = (
        ": with four cameras many fields fit, and unconstrained fits are blotches of either "
        "sign that no network can predict from the photo"
    )
    add_fit_arguments(p, lobes=1, smooth=8, sparsity=SPARSITY, why=why)
    p.add_argument(
        "--source",
        default="fit",
        choices=("fit", "renderer"),
        help="fit: fields fitted to each example's cameras (the fit options apply); "
        "renderer: the analytic renderer's own (analytic examples only; --head lobes gives "
        "fields for --lobe-domain linear-clamped) (default fit)",
    )
    p.add_argument(
        "--normals",
        default="surface",
        choices=("surface", "depth"),
        help="--source renderer --head lobes: mirror each light about the surface's normal, "
        "or about the depth map's (what a head given the light's direction could do from "
        "the depth alone) (default surface)",
    )
    p.add_argument(
        "--reach",
        default="view",
        choices=("view", "surface", "visible"),
        help="--source renderer --head lobes: give a pixel a light's lobe only where the "
        "light's reflection comes near the photo's view, matched there (view), or on every "
        "glossy pixel the light reaches, as the lobe is at its peak: amplitude and "
        "sharpness then belong to the surface and the light (surface), or those only where "
        "the photo shows them (at least a tenth of the pixel's light at the photo's view: "
        "visible) (default view)",
    )
    p.add_argument(
        "--shard",
        default="0/1",
        help="I/N: fit every N-th example from the I-th, to run N processes (default 0/1)",
    )


def parse_shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard {text!r}: expected I/N, e.g. 0/2") from None
    if not 0 <= i < n:
        raise ValueError(f"--shard {text!r}: need 0 <= I < N")
    return i, n


def settings(args: argparse.Namespace) -> dict:
    if args.source == "renderer":
        domain = "linear-clamped" if args.head == "lobes" else "display"
        told = {
            "head": args.head,
            "lobes": args.lobes,
            "source": "renderer",
            "units": "hdr",
            "domain": domain,
        }
        if args.normals == "depth":
            told["normals"] = "depth"
        if args.reach != "view":
            told["reach"] = args.reach
        return told
    return {
        "head": args.head,
        "lobes": args.lobes,
        "smooth": args.smooth,
        "steps": args.steps,
        "lr": args.lr,
        "sparsity": args.sparsity,
    }


def claim_settings(out: Path, wanted: dict) -> None:
    """Writes teacher.json, or checks that the one there matches (a folder holds one head's
    fields: mixing fits would teach the network two layouts)."""
    path = out / TEACHER_JSON
    if path.exists():
        have = json.loads(path.read_text())
        if have != wanted:
            raise ValueError(f"{path} was written with {have}, not {wanted}: use another --out")
        return
    tmp = out / f".tmp-{TEACHER_JSON}-{os.getpid()}"
    tmp.write_text(json.dumps(wanted, indent=1))
    tmp.replace(path)


def fitted_gain(
    head: str, sample: dict, fields: torch.Tensor, domain: str = "display"
) -> float | None:
    """Mean gain of the fit on the example's cameras whose shading changes (an unchanged
    view's input is its truth to the last bit: there a fit can only lose), None if none."""
    psnr = target_psnrs(head, sample, fields, domain)
    gains = [ours - before for before, ours in psnr if before < CHANGING_BELOW_DB]
    return statistics.mean(gains) if gains else None


# Fields are stored as float16; the renderer's HDR amplitudes can exceed its range.
F16_MAX = 6.0e4


def example_fields(args: argparse.Namespace, folder: Path, ex) -> tuple[np.ndarray, float | None]:
    """The example's fields (C, H, W) as stored, and what they gain on its cameras."""
    if args.source == "renderer":
        fields = renderer_fields(folder, ex, args.head, args.lobes, args.normals, args.reach)
        told = FieldTargets(fields.transpose(1, 2, 0), args.lobes, hdr=True)
        # The sample carries the fields as the network sees them (tone mapped with it).
        sample = make_sample(
            replace(ex, teacher=told), crop=None, rng=None, aug=None, targets=ex.target_count
        )
        domain = settings(args)["domain"]
        return fields, fitted_gain(args.head, sample, sample["teacher"][None], domain)
    sample = make_sample(ex, crop=None, rng=None, aug=None, targets=ex.target_count)
    fitted = fit_fields(
        args.head,
        args.lobes,
        sample,
        args.smooth,
        args.steps,
        args.lr,
        held_out=0,
        sparsity=args.sparsity,
    )
    return fitted[0].numpy(), fitted_gain(args.head, sample, fitted)


def renderer_fields(
    folder: Path, ex, head: str, lobes: int, normals: str = "surface", reach: str = "view"
) -> np.ndarray:
    """The analytic renderer's fields (C, H, W) for example `folder` (HDR, see
    FieldTargets), its scene drawn again from the seed and index in its meta.json."""
    from .render.analytic import make_example
    from .render.decompose import decompose, light_lobes, no_lobes, visible_lobes

    meta = json.loads((folder / "meta.json").read_text())
    if meta.get("scene", {}).get("family") != "analytic":
        raise ValueError(f"{folder}: not an analytic example; --source renderer needs one")
    scene, _, cam, _, _ = make_example(meta["seed"], meta["index"], meta["width"], meta["height"])
    stored = np.asarray(meta["input_camera"]["world_from_camera"], dtype=float)[:3, 3]
    if not np.allclose(stored, cam.centre, atol=1e-6):
        raise ValueError(
            f"{folder}: its scene does not draw again from seed {meta['seed']} index "
            f"{meta['index']} (rendered with other --radius settings or another version)"
        )
    truth = decompose(scene, cam, meta["spp"])
    lit = truth["input"].mean(2) > 1e-6
    scale = float(np.median(ex.input[lit].astype(np.float32) / truth["input"][lit]))
    if head == "lobes":
        fields = light_lobes(scene, cam, lobes, normals, "view" if reach == "view" else "surface")
        if reach == "visible":
            fields = visible_lobes(fields, cam, truth["input"], lobes)
        for j in range(lobes):
            fields[..., 7 * j + 4 : 7 * j + 7] *= scale
    else:
        layer = [truth["share"], truth["rho"][..., None]]
        fields = np.concatenate([no_lobes(cam, lobes), *layer], axis=2)
    return np.ascontiguousarray(fields.transpose(2, 0, 1))


def run(args: argparse.Namespace) -> int:
    try:
        shard = parse_shard(args.shard)
    except ValueError as err:
        print(f"teacher: {err}", file=sys.stderr)
        return 2
    if args.smooth < 1 or args.steps < 1 or args.lobes < 1:
        print("teacher: --smooth, --steps and --lobes must be at least 1", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    try:
        folders = list_examples(args.data)[shard[0] :: shard[1]]
        args.out.mkdir(parents=True, exist_ok=True)
        claim_settings(args.out, settings(args))
    except (DatasetError, ValueError, OSError) as err:
        print(f"teacher: {err}", file=sys.stderr)
        return 1
    todo = [f for f in folders if not (args.out / f"{f.name}.npy").exists()]
    print(f"teacher: {len(folders) - len(todo)} of {len(folders)} already fitted", file=sys.stderr)
    started, gains = time.monotonic(), []
    for i, folder in enumerate(todo):
        try:
            ex = load_example(folder)
        except DatasetError as err:
            print(f"teacher: {err}", file=sys.stderr)
            return 1
        if ex.target_count < 2:
            print(
                f"teacher: {folder} has one target; fields need several cameras "
                "(render with --scenes analytic --targets N)",
                file=sys.stderr,
            )
            return 1
        try:
            fields, gain = example_fields(args, folder, ex)
        except ValueError as err:
            print(f"teacher: {err}", file=sys.stderr)
            return 1
        if gain is not None:
            gains.append(gain)
        tmp = args.out / f".tmp-{folder.name}-{os.getpid()}.npy"
        np.save(tmp, np.clip(fields, -F16_MAX, F16_MAX).astype(np.float16))
        tmp.replace(args.out / f"{folder.name}.npy")
        fit = "no view changes" if gain is None else f"{gain:+.2f} dB on its changing views"
        print(
            f"[{i + 1}/{len(todo)}] {folder.name}: {fit} ({time.monotonic() - started:.0f} s)",
            file=sys.stderr,
        )
    if gains:
        print(
            f"teacher: {len(todo)} examples fitted; on the {len(gains)} with changing views "
            f"the fields gain {statistics.mean(gains):+.2f} dB"
        )
    return 0
