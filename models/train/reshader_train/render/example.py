"""One dataset example: choose cameras, render the four images, write the folder atomically.

Layout of `<out>/<id>/` (the training toolchain reads exactly this):
  input.exr, reshaded.exr, novel.exr  RGB float32 linear HDR
  depth.exr                          1 channel float32 z-depth of the input view (inf: sky)
  mask.png                           8-bit L, 255 valid / 0 invalid
  meta.json                          cameras, novel offset, every scene parameter, timings
With several targets per example (`render --targets T`), the files
above hold the first target and targets k = 1 .. T-1 add
  reshaded-<k>.exr                   the input's samples seen from novel camera k
  mask-<k>.png                       what novel camera k sees of them
(no novel image), listed in order in meta.json's "extra_targets": [{"offset": [tx, ty, tz],
"camera": {...}, "reshaded": "reshaded-<k>.exr", "mask": "mask-<k>.png"}, ...]. A one-target
example has no such files and no "extra_targets".
"""

import json
import math
import os
import shutil
import time
from dataclasses import dataclass
from functools import partial

import numpy as np

from .cameras import Camera, look_at, sample_shell
from .procedural import GLOSSY_FAMILIES

# All three images are scaled so that the input's median luminance is this. The training
# tone mapping (exposure x3..10, clip, gamma 2.2..5) then puts the median at 0.06..0.2
# before the gamma and clips only the brightest few percent (highlights, lights).
TARGET_MEDIAN = 0.02
# A novel camera up to 0.3 away must stay in free space, so the input camera keeps this
# clearance from all geometry.
CLEARANCE = 0.35
FILES = ("input.exr", "reshaded.exr", "novel.exr", "depth.exr", "mask.png", "meta.json")
IMAGES = ("input", "reshaded", "novel")


@dataclass(frozen=True)
class RenderSettings:
    width: int
    height: int
    spp: int
    radius_min: float = 0.1
    radius_max: float = 0.3
    # Sample seeds whose (reshaded - input) differences are averaged into the ground truth;
    # 1 writes the reshaded render of the input's own seed.
    change_seeds: int = 1
    # Reshaded targets per example (novel cameras): the first is written as reshaded.exr,
    # the others as reshaded-<k>.exr.
    targets: int = 1
    # Only the input and its depth (no reshaded or novel render, no mask): examples for
    # training a depth network, at a third of the cost.
    input_only: bool = False


def example_id(seed: int, index: int) -> str:
    return f"{seed:05d}-{index:06d}"


def example_rng(seed: int, index: int, stream: int = 0) -> np.random.Generator:
    """Independent, reproducible random stream per (seed, index, purpose)."""
    return np.random.default_rng([seed, index, stream])


def _sphere_directions(n: int = 26) -> np.ndarray:
    """Roughly uniform unit directions (Fibonacci sphere)."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = math.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.cos(phi), np.sin(theta) * np.sin(phi)], -1)


def camera_is_free(scene, position) -> bool:
    """No geometry within CLEARANCE, and not enclosed by a nearby surface on all sides."""
    from .integrator import trace_distances

    t = trace_distances(scene, position, _sphere_directions())
    return bool(t.min() > CLEARANCE and np.median(t) > 0.8)


def view_hits(scene, camera: Camera, grid: int = 8) -> np.ndarray:
    """Hit distances of a coarse grid of rays across the camera's view (inf: miss)."""
    from .integrator import pixel_rays, trace_distances

    small = Camera(
        camera.world_from_camera,
        grid,
        max(2, grid * camera.height // camera.width),
        camera.fov_x_deg,
    )
    directions, _ = pixel_rays(small)
    return trace_distances(scene, camera.centre, directions)


def _outside_objects(params: dict, pos: np.ndarray) -> bool:
    """The camera stands outside every object's bounding cylinder (with a margin): a
    closed shape seen from inside (a car body, a counter) can pass `camera_is_free`."""
    from .procedural import _height, _radius

    for o in params["objects"]:
        x, y, z = o["position"]
        near = math.hypot(pos[0] - x, pos[2] - z) < _radius(o) + 0.1
        if near and pos[1] < y + _height(o) + 0.1:
            return False
    return True


def _sees_target(scene, pos: np.ndarray, target: np.ndarray, obj: dict) -> bool:
    """Nothing (a light, a counter's edge, another object) stands between the camera and
    the object it looks at."""
    from .integrator import trace_distances
    from .procedural import _radius

    to_target = target - pos
    dist = float(np.linalg.norm(to_target))
    t = float(trace_distances(scene, pos, (to_target / dist)[None])[0])
    return t >= dist - _radius(obj) - 0.05


def choose_procedural_camera(rng, scene, params: dict, width: int, height: int) -> dict:
    """Look at a random object from 1-4.5 units (0.8-2.5 for the "highlights" and "studio"
    families, so that highlights cover more pixels; the photographic families give their
    own `camera_distance`); the camera stands in free space."""
    from .procedural import PHOTO_FAMILIES, SUPPORTS, _height, _radius

    x0, x1, z0, z1, y0, y1 = params["bounds"]
    margin = CLEARANCE + 0.1
    near, far = (0.8, 2.5) if params.get("family") in GLOSSY_FAMILIES else (1.0, 4.5)
    photo = params.get("family") in PHOTO_FAMILIES
    targets = params["objects"]
    if photo:
        near, far = params["camera_distance"]
        # Look at what stands on tables and counters, not at their middles.
        targets = [o for o in targets if o["shape"] not in SUPPORTS] or targets
    for _ in range(200):
        obj = targets[int(rng.integers(len(targets)))]
        lift, closest = 0.3, near
        if photo:  # a big object is seen whole, not as a wall of one material
            lift, closest = (
                min(0.3, 0.5 * _height(obj)),
                max(near, min(0.7 * far, 2.5 * _radius(obj))),
            )
        target = np.array(obj["position"]) + [0.0, lift, 0.0] + rng.normal(0, 0.1, 3)
        dist, az = rng.uniform(closest, far), rng.uniform(0, 2 * math.pi)
        el = math.radians(rng.uniform(-5, 40))
        pos = target + dist * np.array(
            [math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)]
        )
        if not (x0 + margin < pos[0] < x1 - margin and z0 + margin < pos[2] < z1 - margin):
            continue
        if not (0.3 < pos[1] < y1 - margin) or not camera_is_free(scene, pos):
            continue
        if photo and not (_outside_objects(params, pos) and _sees_target(scene, pos, target, obj)):
            continue
        cam = {
            "position": pos.tolist(),
            "target": target.tolist(),
            "fov_x_deg": float(rng.uniform(45, 75)),
            "roll_deg": float(rng.normal(0, 3)),
        }
        hits = view_hits(scene, make_camera(cam, width, height))
        if np.isfinite(hits).mean() >= 0.3 and np.median(hits) > 0.5:
            return cam
    raise RuntimeError("no free camera position with a view found in 200 tries")


def make_camera(cam: dict, width: int, height: int) -> Camera:
    m = look_at(cam["position"], cam["target"], cam.get("up", (0.0, 1.0, 0.0)), cam["roll_deg"])
    return Camera(m, width, height, cam["fov_x_deg"])


def _write_exr(mi, path: str, image: np.ndarray) -> None:
    import drjit as dr

    channels = mi.Bitmap.PixelFormat.Y if image.shape[-1] == 1 else mi.Bitmap.PixelFormat.RGB
    bitmap = mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32), channels)
    # Mitsuba 3.9's EXR writer deadlocks when Dr.Jit's pool has a single thread
    # (--threads 1): give it two for the write.
    threads = dr.thread_count()
    if threads < 2:
        dr.set_thread_count(2)
    try:
        bitmap.write(path)
    finally:
        if threads < 2:
            dr.set_thread_count(threads)


def _write_png(mi, path: str, image: np.ndarray) -> None:
    image = np.ascontiguousarray(image[..., None], dtype=np.uint8)
    mi.Bitmap(image, mi.Bitmap.PixelFormat.Y).write(path)


def render_views(
    mi,
    scene,
    input_cam: Camera,
    novel_cam: Camera,
    spp: int,
    seed: int,
    max_depth: int,
    timings: dict,
    change_seeds: int = 1,
    input_only: bool = False,
    extra_cams: tuple[Camera, ...] = (),
) -> dict:
    """input / reshaded / novel RGB, invalid fraction per pixel, and input depth (with
    `input_only`, the input and its depth alone). With `extra_cams`, "extra" holds one
    {"reshaded", "invalid"} per further novel camera, shaded from the same samples."""
    from .integrator import make_path, make_reshade, render_depth, render_image

    path = make_path(max_depth)
    out = {}
    t = time.perf_counter()
    out["input"] = render_image(scene, input_cam, spp, seed, path)[..., :3]
    timings["input"] = time.perf_counter() - t
    if input_only:
        t = time.perf_counter()
        out["depth"] = render_depth(scene, input_cam)
        timings["depth"] = time.perf_counter() - t
        return out
    t = time.perf_counter()
    seeds = [seed] + [(seed + k) % 2**31 for k in range(1, change_seeds)]
    inputs = [out["input"]]
    inputs += [render_image(scene, input_cam, spp, s, path)[..., :3] for s in seeds[1:]]
    reshade = make_reshade(novel_cam, input_cam, max_depth)
    out["reshaded"], out["invalid"], first = reshaded_target(
        scene, input_cam, spp, seeds, inputs, reshade
    )
    out["z_primary"], out["z_rehit"] = first[..., 4], first[..., 5]
    timings["reshaded"] = time.perf_counter() - t
    if extra_cams:
        t = time.perf_counter()
        out["extra"] = []
        for cam in extra_cams:
            reshade.set_cameras(cam.centre, input_cam.centre, input_cam.rotation[:, 2])
            image, invalid, _ = reshaded_target(scene, input_cam, spp, seeds, inputs, reshade)
            out["extra"].append({"reshaded": image, "invalid": invalid})
        timings["extra_targets"] = time.perf_counter() - t
    t = time.perf_counter()
    out["novel"] = render_image(scene, novel_cam, spp, seed, path)[..., :3]
    timings["novel"] = time.perf_counter() - t
    t = time.perf_counter()
    out["depth"] = render_depth(scene, input_cam)
    timings["depth"] = time.perf_counter() - t
    return out


def seed_pairs(scene, camera, spp, seeds, path, reshade):
    """(input RGB, reshaded RGB + AOVs) rendered with each sample seed of `seeds`."""
    from .integrator import render_image

    for sample_seed in seeds:
        sample_seed %= 2**31
        image = render_image(scene, camera, spp, sample_seed, path)[..., :3]
        yield image, render_image(scene, camera, spp, sample_seed, reshade)


def reshaded_target(scene, camera, spp, seeds, inputs, reshade):
    """The reshaded target of `reshade`'s novel camera: (RGB, invalid, the first seed's
    render with its AOVs). With one sample seed, the render itself. With several (inputs
    holds the input rendered with each), the first input plus the mean of (reshaded -
    input) over the seeds, and the union of their invalid masks.

    Input and reshaded share their samples, but their paths part wherever a glossy
    surface sends the two primary rays' bounces apart; that part of the difference is
    noise the input cannot predict. The ground truth input + mean change keeps the
    input's own noise (a network must not try to remove it) and divides the variance
    of the change by the number of seeds. Every target of an example reuses the inputs:
    a further camera costs its reshaded renders alone, with the kernels already compiled.
    """
    from .integrator import render_image

    first = render_image(scene, camera, spp, seeds[0], reshade)
    if len(seeds) == 1:
        return first[..., :3], first[..., 3], first
    total = first[..., :3] - inputs[0]
    invalid = first[..., 3].copy()
    for sample_seed, image in zip(seeds[1:], inputs[1:], strict=True):
        truth = render_image(scene, camera, spp, sample_seed, reshade)
        total += truth[..., :3] - image
        invalid = np.maximum(invalid, truth[..., 3])
    return inputs[0] + total / len(seeds), invalid, first


def brightness_scale(image: np.ndarray) -> float:
    """Factor that brings the median luminance to TARGET_MEDIAN (bounded to 1/100..100).

    Scaling every image of an example by one factor is the same as scaling every light
    in the scene, so the input/reshaded relation is untouched.
    """
    lum = image @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    return float(np.clip(TARGET_MEDIAN / max(float(np.median(lum)), 1e-8), 0.01, 100.0))


def example_meta(views: dict, seed: int, index: int, settings: RenderSettings, **kw) -> dict:
    """Scales input, reshaded and novel in `views` (in place) to the dataset's brightness
    and returns the example's meta.json. `kw`: spp, change_seeds, render_seed, input_cam,
    novel_cam, offset, scene (parameters), camera (its dict) and timings; optionally extra,
    the (novel camera, offset) pairs of the targets after the first, whose images are
    views["extra"][k - 1]["reshaded"]."""
    scale = brightness_scale(views["input"])
    for name in IMAGES:
        if name in views:
            views[name] = views[name] * scale
    for target in views.get("extra", ()):
        target["reshaded"] = target["reshaded"] * scale
    meta = {
        "id": example_id(seed, index),
        "seed": seed,
        "index": index,
        "width": settings.width,
        "height": settings.height,
        "spp": kw["spp"],
        "change_seeds": kw["change_seeds"],
        "render_seed": kw["render_seed"],
        "input_camera": kw["input_cam"].meta(),
        "novel_camera": kw["novel_cam"].meta(),
        "novel_offset": [float(v) for v in kw["offset"]],
        "scene": {
            **kw["scene"],
            "camera": kw["camera"],
            "brightness_scale": scale,
            "target_median": TARGET_MEDIAN,
        },
        "render_seconds": kw["timings"],
    }
    if "invalid" in views:
        meta["invalid_fraction"] = float((views["invalid"] > 0).mean())
    else:
        meta["input_only"] = True
    if kw.get("extra"):
        meta["extra_targets"] = [
            {
                "offset": [float(v) for v in offset],
                "camera": cam.meta(),
                "reshaded": f"reshaded-{k}.exr",
                "mask": f"mask-{k}.png",
                "invalid_fraction": float((target["invalid"] > 0).mean()),
            }
            for k, ((cam, offset), target) in enumerate(
                zip(kw["extra"], views["extra"], strict=True), 1
            )
        ]
    return meta


def write_example(out_dir: str, views: dict, meta: dict, write_exr, write_mask) -> str:
    """Write into `<out>/.tmp-<id>-<pid>` and rename: a folder named <id> is always complete,
    even when two render commands given the same seed write into one folder at once.
    write_exr(path, (H, W, C) float image) and write_mask(path, (H, W) uint8) do the files
    (Mitsuba's writers, or numpy's where Mitsuba is not loaded)."""
    ex_id = meta["id"]
    final = os.path.join(out_dir, ex_id)
    tmp = os.path.join(out_dir, f".tmp-{ex_id}-{os.getpid()}")
    clear_stale_tmp(out_dir, ex_id)
    os.makedirs(tmp)
    for name in IMAGES:
        if name in views:
            write_exr(os.path.join(tmp, f"{name}.exr"), views[name])
    write_exr(os.path.join(tmp, "depth.exr"), views["depth"][..., None])
    if "invalid" in views:
        write_mask(os.path.join(tmp, "mask.png"), np.where(views["invalid"] > 0, 0, 255))
    for entry, target in zip(meta.get("extra_targets", ()), views.get("extra", ()), strict=True):
        write_exr(os.path.join(tmp, entry["reshaded"]), target["reshaded"])
        write_mask(os.path.join(tmp, entry["mask"]), np.where(target["invalid"] > 0, 0, 255))
    with open(os.path.join(tmp, "meta.json"), "w") as f:
        json.dump(meta, f, indent=1)
    if os.path.exists(final):  # an incomplete folder from an interrupted older layout
        shutil.rmtree(final)
    os.rename(tmp, final)
    return final


def clear_stale_tmp(out_dir: str, ex_id: str) -> None:
    """Remove the unfinished folders of `ex_id` left by render commands that are gone (and
    this process's own); a live one's is its to finish."""
    prefix = f".tmp-{ex_id}"
    for name in os.listdir(out_dir):
        if name != prefix and not name.startswith(prefix + "-"):
            continue
        owner = name[len(prefix) + 1 :]  # "" for the layout without a process id
        if owner.isdigit() and int(owner) != os.getpid() and pid_alive(int(owner)):
            continue
        shutil.rmtree(os.path.join(out_dir, name), ignore_errors=True)


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # it exists, owned by another user
    return True


def is_complete(out_dir: str, ex_id: str) -> bool:
    return os.path.isfile(os.path.join(out_dir, ex_id, "meta.json"))


@dataclass
class ExampleSetup:
    """Everything example (seed, index) draws before rendering: scene, cameras, sample seed."""

    params: dict
    scene: object
    cam: dict
    input_cam: Camera
    novel_cam: Camera
    offset: np.ndarray
    render_seed: int
    # (novel camera, offset) of the targets after the first (settings.targets - 1).
    extra: list[tuple[Camera, np.ndarray]]


def setup_example(mi, source, seed: int, index: int, settings: RenderSettings) -> ExampleSetup:
    rng = example_rng(seed, index)
    params, scene, cam = source.make(mi, rng, settings.width, settings.height, index)
    input_cam = make_camera(cam, settings.width, settings.height)
    offset = sample_shell(rng, settings.radius_min, settings.radius_max)
    render_seed = int(example_rng(seed, index, 1).integers(2**31))
    # From a stream of their own, like the analytic scenes' further targets: the first
    # target is what a one-target render writes, and target k the same whatever the number
    # asked for. The input camera's clearance keeps every offset in free space.
    shell = example_rng(seed, index, 2)
    extra = []
    for _ in range(settings.targets - 1):
        extra_offset = sample_shell(shell, settings.radius_min, settings.radius_max)
        extra.append((input_cam.translated(extra_offset), extra_offset))
    return ExampleSetup(
        params, scene, cam, input_cam, input_cam.translated(offset), offset, render_seed, extra
    )


def render_example(mi, source, out_dir: str, seed: int, index: int, settings: RenderSettings):
    """Render and write example (seed, index) of `source`; returns its meta dict."""
    timings: dict = {}
    start = time.perf_counter()
    ex = setup_example(mi, source, seed, index, settings)
    timings["scene"] = time.perf_counter() - start
    views = render_views(
        mi,
        ex.scene,
        ex.input_cam,
        ex.novel_cam,
        settings.spp,
        ex.render_seed,
        ex.params["max_depth"],
        timings,
        settings.change_seeds,
        settings.input_only,
        tuple(c for c, _ in ex.extra),
    )
    timings["total"] = time.perf_counter() - start
    meta = example_meta(
        views,
        seed,
        index,
        settings,
        spp=settings.spp,
        change_seeds=settings.change_seeds,
        render_seed=ex.render_seed,
        input_cam=ex.input_cam,
        novel_cam=ex.novel_cam,
        offset=ex.offset,
        scene=ex.params,
        camera=ex.cam,
        timings=timings,
        extra=ex.extra,
    )
    write_example(out_dir, views, meta, partial(_write_exr, mi), partial(_write_png, mi))
    return meta
