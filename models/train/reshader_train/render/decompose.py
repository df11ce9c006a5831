"""What the lobe heads' fields truly are in an analytic photo, from the renderer itself
(`reshader-train teacher --source renderer`).

Fits of a head to an example's few cameras are not unique, and a network told them learns
where to change but too little; the renderer knows the answer, so it can say it.

`light_lobes`: the "lobes" head's fields. A spherical-Gaussian light of axis a and
sharpness l reflected by a GGX lobe (approximated as an SG of sharpness s_r around the
mirror direction r, as `analytic.sg_reflection` does) gives, seen from direction v, a
function of r . a = v . m alone, m the light's axis mirrored about the normal: near its
peak an SG in v of axis m and sharpness l s_r / (l + s_r), with the reflection's peak
value as amplitude (Fresnel and shadowing at the photo's camera). That is the head's
lobe, exactly where a highlight is.

`decompose`: the "lobes-slide" head's layer: per pixel the share of its light that the
specular layer reflects, and how far behind the surface the reflected image lies.

Where the reflected image lies: a flat mirror shows a thing at distance u along the
reflected ray at u behind the surface; a convex one of curvature k (2/R for a sphere, 1/R
across a cylinder's side) at 1/(k + 1/u), so a sphere shows the sky half its radius deep.
The layer's depth per sample is the mean of its parts' (the reflected environment and
objects, each orb), weighted by their brightness, expressed as the head's rho: the share
of the surface's disparity the image lacks, u' / (t + u') for a surface at distance t.
"""

from __future__ import annotations

import numpy as np

from ..model import SHARPNESS_RANGE
from .analytic import (
    EPS,
    TRACE_ROUGHNESS,
    Surface,
    background,
    camera_rays,
    fresnel,
    intersect,
    sg_reflection_at,
    shade,
    specular_parts,
    subsample_offsets,
)
from .cameras import Camera

# A sample whose specular layer is this dark (in HDR units) has no say in its pixel's rho.
DARK = 1e-6
# Views within this angle (radians) of the photo's own direction count: a display's cone
# and the training offsets (0.1-0.3 at 2-3 units) stay inside it. A light whose reflection
# stays below UNSEEN of its peak over that cone does not change the pixel, and its lobe is
# left out (amplitude 0: its axis and sharpness are then free).
REACH = 0.15
UNSEEN = 1e-4
# A bound on a lobe's HDR peak: far in a lobe's tail the peak its slope implies is
# astronomical and irrelevant.
MAX_AMPLITUDE = 1.0e4


def curvature(scene: dict, ident: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Mean curvature (2/R sphere, 1/R a cylinder's side, 0 flat) of each hit surface."""
    k = np.zeros(len(ident))
    for i, obj in enumerate(scene["objects"]):
        sel = ident == 2 + i
        if obj["shape"] == "sphere":
            k[sel] = 2.0 / obj["radius"]
        elif obj["shape"] == "cylinder":
            side = sel & (np.abs(normal[:, 1]) < 0.5)
            k[side] = 1.0 / obj["radius"]
    return k


def image_rho(t: np.ndarray, k: np.ndarray, u: np.ndarray) -> np.ndarray:
    """rho of a reflected image of a thing at distance u off a surface of curvature k at
    distance t from the camera (u = inf: a distant thing)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        behind = 1.0 / (k + 1.0 / u)
        return np.where(np.isfinite(behind), behind / (t + behind), 1.0)


def _sample_rho(scene: dict, surf: Surface, t: np.ndarray, eye: np.ndarray):
    """(specular radiance, rho, the radiance's brightness that weighs rho) of the glossy
    samples of `surf`, seen from `eye`."""
    sel = surf.glossy
    p, n = surf.points[sel], surf.normal[sel]
    v = eye - p
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    env, orbs, _ = specular_parts(scene, surf, v)
    nv = np.clip(np.einsum("ij,ij->i", n, v), 1e-3, 1)
    r = 2 * nv[:, None] * n - v
    k = curvature(scene, surf.id[sel], n)
    ts = t[sel]
    parts = [(env, intersect(scene, p + EPS * n, r, orbs=False).t.astype(np.float64))]
    rows = np.searchsorted(np.flatnonzero(surf.surface), np.flatnonzero(sel))
    parts += [(o, dist[rows]) for o, (_, dist, _, _) in zip(orbs, surf.orb_dirs, strict=True)]
    weight = sum(part.mean(1) for part, _ in parts)
    rho = sum(part.mean(1) * image_rho(ts, k, u) for part, u in parts)
    spec = sum(part for part, _ in parts)
    return spec, np.where(weight > DARK, rho / np.maximum(weight, DARK), 0.0), weight


def _lobes_of_lights(
    scene: dict,
    surf: Surface,
    eye: np.ndarray,
    rotation: np.ndarray,
    mirror: np.ndarray,
    whole: bool = False,
):
    """Per SG light, (axis in the camera frame, sharpness, HDR amplitude, its value at the
    best view within REACH) at the glossy samples of `surf`, seen from `eye`; the axis is
    the light mirrored about `mirror` (a unit normal per sample of `surf`). `whole`: each
    lobe as it is at its peak (sharpness and amplitude there, whatever the view), on
    every glossy sample the light reaches: a property of the surface and the light, not
    of where the photo's camera stands."""
    sel = surf.glossy
    p, n, alpha, f0 = surf.points[sel], surf.normal[sel], surf.alpha[sel], surf.f0[sel]
    about = mirror[sel]
    rows = np.searchsorted(np.flatnonzero(surf.surface), np.flatnonzero(sel))
    v = eye - p
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    nv = np.clip(np.einsum("ij,ij->i", n, v), 1e-3, 1)
    f = fresnel(f0, nv)
    reflect_sharp = 2 / alpha**2 / (4 * nv)
    # A smooth surface whose reflected ray meets an object shows that object instead of
    # the lights (analytic._mirrored_objects): there the lobe is the part left over.
    r = 2 * nv[:, None] * n - v
    lo, hi = TRACE_ROUGHNESS
    blocked = np.clip((hi - alpha) / (hi - lo), 0, 1) * (
        intersect(scene, p + EPS * n, r, orbs=False).id >= 0
    )
    out = []
    for g, vis in zip(scene["lobes"], surf.light_vis, strict=True):
        axis = np.asarray(g["axis"], dtype=np.float64)
        m = 2 * (about @ axis)[:, None] * about - axis
        c0 = np.clip(np.einsum("ij,ij->i", v, m), -1, 1)
        at = np.ones_like(c0) if whole else c0
        lam = g["sharpness"]
        # The reflection as a function of c = v . m, matched in value and log-slope at the
        # photo's own view: what moves a highlight's edge (where a bright one clips) is
        # the slope there, which an SG matched at the peak gets wrong in its tails.
        mixed = np.sqrt(lam**2 + reflect_sharp**2 + 2 * lam * reflect_sharp * at)
        tail = 2 * np.exp(-2 * mixed) / (1 - np.exp(-2 * mixed))
        sharp = np.clip(lam * reflect_sharp / mixed * (1 - 1 / mixed + tail), *SHARPNESS_RANGE)
        value = sg_reflection_at(g, at, reflect_sharp)
        log_amp = np.log(np.maximum(value, 1e-30)) + (sharp * (1 - at))[:, None]
        amp = f * np.exp(np.minimum(log_amp, np.log(MAX_AMPLITUDE)))
        amp = amp * (vis[rows] * (1 - blocked))[:, None]
        nearest = np.cos(np.maximum(np.arccos(c0) - REACH, 0.0))
        seen = np.exp(sharp * (nearest - 1))
        if not whole:
            amp = np.where((seen >= UNSEEN)[:, None], amp, 0.0)
        out.append((m @ rotation, sharp, amp, amp.mean(1) * seen))
    return out


def depth_normals(points: np.ndarray, height: int, width: int, towards: np.ndarray):
    """Unit normals (H*W, 3) of a grid of 3-D points (H*W, 3) from the cross product of
    central differences (one-sided at the border), turned to face `towards`: what a depth
    map alone tells of the surfaces, wrong across its edges."""
    g = points.reshape(height, width, 3)
    dx = np.gradient(g, axis=1) if width > 1 else np.zeros_like(g)
    dy = np.gradient(g, axis=0) if height > 1 else np.zeros_like(g)
    n = np.cross(dx, dy).reshape(-1, 3)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return np.where((np.einsum("ij,ij->i", n, towards - points) < 0)[:, None], -n, n)


def light_lobes(
    scene: dict, cam: Camera, count: int, normals: str = "surface", reach: str = "view"
) -> np.ndarray:
    """(H, W, 7 count) "lobes" head fields at the pixel centres, LobeField's layout per
    lobe (axis in the camera frame, sharpness, HDR amplitude), the `count` lights whose
    reflection is brightest within REACH first. Pixels with fewer get zero lobes.
    `normals` "depth": each light is mirrored about the depth map's normal instead of the
    surface's (`depth_normals`): the axes a head that mirrors a known light about the
    depth map would get. `reach` "surface": every glossy pixel keeps its lights' lobes as
    they are at their peaks (`_lobes_of_lights`' `whole`), not only where a light's
    reflection comes within REACH of the photo's view."""
    d, _ = camera_rays(cam, np.zeros((1, 2)))
    o = np.broadcast_to(cam.centre, d.shape)
    hits = intersect(scene, o, d)
    t = np.where(np.isfinite(hits.t), hits.t, 0).astype(np.float64)
    surf = Surface(scene, o + d * t[:, None], hits)
    fields = no_lobes(cam, count).reshape(len(d), count, 7)
    mirror = surf.normal
    if normals == "depth":
        points = np.where(np.isfinite(hits.t)[:, None], surf.points, o + d * 1e6)
        mirror = depth_normals(points, cam.height, cam.width, cam.centre)
    lights = []
    if surf.glossy.any():
        lights = _lobes_of_lights(
            scene, surf, cam.centre, cam.rotation, mirror, whole=reach == "surface"
        )
    if lights:
        rank = np.argsort(-np.stack([seen for *_, seen in lights]), axis=0, kind="stable")
        rows = np.flatnonzero(surf.glossy)
        for k in range(min(count, len(lights))):
            for j, (mu, sharp, amp, _) in enumerate(lights):
                pick = rank[k] == j
                fields[rows[pick], k] = np.concatenate(
                    [mu[pick], sharp[pick, None], amp[pick]], axis=1
                )
    return fields.reshape(cam.height, cam.width, 7 * count)


# `--reach visible`: a lobe counts as seen in the photo where its value at the photo's view
# is at least this share of the pixel's light.
VISIBLE_SHARE = 0.1


def visible_lobes(fields: np.ndarray, cam: Camera, photo: np.ndarray, count: int) -> np.ndarray:
    """`fields` (H, W, 7 count, lobes at their peaks) with the amplitude of every lobe
    that the photo does not show set to 0: a lobe is kept where its value at the photo's
    view is at least VISIBLE_SHARE of the pixel's light in `photo` (H, W, 3, the same
    HDR units). What a head that reads its amplitudes off the photo's highlights could
    know."""
    out = fields.copy()
    w0 = no_lobes(cam, 1)[..., 0:3]
    light = photo.mean(2)
    for j in range(count):
        lobe = out[..., 7 * j : 7 * j + 7]
        g0 = np.exp(lobe[..., 3] * (np.einsum("hwc,hwc->hw", lobe[..., 0:3], w0) - 1))
        shown = lobe[..., 4:7].mean(2) * g0 >= VISIBLE_SHARE * light
        lobe[..., 4:7] *= shown[..., None]
    return out


def no_lobes(cam: Camera, count: int) -> np.ndarray:
    """(H, W, 7 count) lobes of amplitude 0, pointing back to the camera (w0) with
    sharpness 1: the fields of a pixel nothing shines on."""
    d, _ = camera_rays(cam, np.zeros((1, 2)))
    fields = np.zeros((len(d), count, 7), np.float32)
    fields[:, :, 0:3] = -(d @ cam.rotation)[:, None, :]
    fields[:, :, 3] = 1.0
    return fields.reshape(cam.height, cam.width, 7 * count)


def decompose(scene: dict, cam: Camera, spp: int) -> dict[str, np.ndarray]:
    """ "input" (H,W,3): the photo as rendered (before the dataset's brightness scale);
    "share" (H,W,3): the specular layer's share of each pixel's light (linear), and
    "rho" (H,W): its image's depth as the lobes-slide head's rho (0 where it has none)."""
    offsets = subsample_offsets(spp)
    d, _ = camera_rays(cam, offsets)
    o = np.broadcast_to(cam.centre, d.shape)
    hits = intersect(scene, o, d)
    t = np.where(np.isfinite(hits.t), hits.t, 0).astype(np.float64)
    points = o + d * t[:, None]
    surf = Surface(scene, points, hits)
    total = shade(scene, surf, cam.centre)
    n = len(d)
    spec, rho_w, weight = (np.zeros((n, 3)), np.zeros(n), np.zeros(n))
    if surf.glossy.any():
        s, r, w = _sample_rho(scene, surf, t, cam.centre)
        spec[surf.glossy], rho_w[surf.glossy], weight[surf.glossy] = s, r * w, w
    sky = hits.id == -1
    total[sky] = background(scene, d[sky])

    def resolve(a: np.ndarray) -> np.ndarray:
        return a.reshape(len(offsets), cam.height, cam.width, -1).mean(0)

    spec_px, total_px = resolve(spec), resolve(total)
    w_px = resolve(weight[:, None])[..., 0]
    share = np.where(total_px > DARK, spec_px / np.maximum(total_px, DARK), 0.0)
    rho = np.where(w_px > DARK, resolve(rho_w[:, None])[..., 0] / np.maximum(w_px, DARK), 0.0)
    return {
        "input": total_px.astype(np.float32),
        "share": np.clip(share, 0, 1).astype(np.float32),
        "rho": rho.astype(np.float32),
    }
