"""Analytic scenes: a numpy ray caster with closed-form shading (no Mitsuba, no noise).

Mitsuba's path tracer spends seconds of a CPU core on each example; this family spends a
fraction of one, so a training set of tens of thousands of examples is rebuilt in an hour
on two cores. It keeps what the reshading network has to learn, highlights and
reflections that slide across the surfaces they lie on when the camera moves, and drops
what one photo cannot tell anyway (light bouncing more than once, caustics, glass).

Scenes are spheres, boxes and cylinders on a floor, optionally before a wall. Light comes
from a sky gradient, from spherical Gaussians (SGs) standing for the sun, softboxes, strip
lights and windows, and from small emissive orbs. An SG's reflection off a glossy surface
is closed form: the GGX lobe is approximated by an SG around the mirror direction and the
product of two SGs is an SG (Wang et al. 2009, "All-frequency rendering of dynamic,
spatially-varying reflectance"). Orbs are sphere lights shaded with GGX, their size
widening the lobe (Karis 2013, "Real shading in Unreal Engine 4"). Mirror-like surfaces
trace one reflection ray and see the other objects in it.

The reshaded image shades the input camera's own surface points (the same sub-pixel
samples) as seen from the novel camera, exactly as `integrator.make_reshade` does with
Mitsuba; a point the novel camera cannot see is invalid in the mask.
"""

import math
import time

import numpy as np

from .analytic_scenes import camera_is_free, choose_camera, sample_scene
from .cameras import Camera, look_at, sample_shell
from .example import example_meta, example_rng, write_example

EPS = 1e-3
# Sub-pixel samples per axis: a fixed stratified pattern, the same for every image.
MAX_SUBSAMPLES = 3
# Mirrors (roughness below the first value) trace their reflection ray; rough surfaces
# (above the second) reflect the unoccluded environment; in between the two blend.
TRACE_ROUGHNESS = (0.08, 0.25)
UP = np.array([0.0, 1.0, 0.0])

# ---------------------------------------------------------------- ray casting


class Hits:
    """Nearest hits of a batch of rays: distance (inf: none), normal and what was hit
    (-1: nothing, 0: floor, 1: wall, 2+i: object i, -2-j: orb j)."""

    def __init__(self, n: int):
        self.t = np.full(n, np.inf, dtype=np.float32)
        self.normal = np.zeros((n, 3), dtype=np.float32)
        self.id = np.full(n, -1, dtype=np.int32)

    def take(self, t: np.ndarray, normal: np.ndarray, ident: int) -> None:
        self.take_at(np.arange(len(t)), t, normal, ident)

    def take_at(self, rows: np.ndarray, t: np.ndarray, normal: np.ndarray, ident: int) -> None:
        closer = t < self.t[rows]
        rows = rows[closer]
        self.t[rows] = t[closer]
        self.normal[rows] = normal[closer]
        self.id[rows] = ident


def _plane(o, d, point, normal):
    denom = d @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((point - o) @ normal) / denom
    t = np.where((t > 0) & (denom < 0), t, np.inf)
    return t, np.broadcast_to(normal, o.shape)


def _sphere(o, d, centre, radius):
    oc = o - centre
    b = np.einsum("ij,ij->i", oc, d)
    c = np.einsum("ij,ij->i", oc, oc) - radius**2
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0))
    t0, t1 = -b - root, -b + root
    t = np.where(t0 > 0, t0, np.where(t1 > 0, t1, np.inf))
    t = np.where(disc >= 0, t, np.inf)
    p = o + d * np.where(np.isfinite(t), t, 0)[:, None]
    return t, (p - centre) / radius


def _yaw(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _box(o, d, centre, half, yaw):
    rot = _yaw(yaw)  # world from local
    lo_, ld = (o - centre) @ rot, d @ rot
    half = np.asarray(half)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / ld
        ta, tb = (-half - lo_) * inv, (half - lo_) * inv
    tmin = np.nanmax(np.minimum(ta, tb), axis=1)
    tmax = np.nanmin(np.maximum(ta, tb), axis=1)
    hit = (tmax >= np.maximum(tmin, 0)) & (tmin > 0)
    t = np.where(hit, tmin, np.inf)
    p = lo_ + ld * np.where(hit, tmin, 0)[:, None]
    rel = np.abs(p) / half
    axis = np.argmax(rel, axis=1)
    local_n = np.zeros_like(p)
    local_n[np.arange(len(p)), axis] = np.sign(p[np.arange(len(p)), axis])
    return t, local_n @ rot.T


def _cylinder(o, d, base, radius, height):
    ox, oz = o[:, 0] - base[0], o[:, 2] - base[2]
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = ox * d[:, 0] + oz * d[:, 2]
    c = ox**2 + oz**2 - radius**2
    disc = b * b - a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        t_side = (-b - np.sqrt(np.maximum(disc, 0))) / a
        y = o[:, 1] + d[:, 1] * t_side
        t_side = np.where(
            (disc >= 0) & (a > 1e-12) & (t_side > 0) & (y >= 0) & (y <= height), t_side, np.inf
        )
        t_cap = (height - o[:, 1]) / d[:, 1]
    px = ox + d[:, 0] * np.where(np.isfinite(t_cap), t_cap, 0)
    pz = oz + d[:, 2] * np.where(np.isfinite(t_cap), t_cap, 0)
    t_cap = np.where((t_cap > 0) & (d[:, 1] < 0) & (px**2 + pz**2 <= radius**2), t_cap, np.inf)
    side = t_side <= t_cap
    t = np.where(side, t_side, t_cap)
    p = o + d * np.where(np.isfinite(t), t, 0)[:, None]
    n_side = np.stack([p[:, 0] - base[0], np.zeros(len(p)), p[:, 2] - base[2]], 1) / radius
    n = np.where(side[:, None], n_side, UP)
    return t, n


def _bounds(obj: dict) -> tuple[np.ndarray, float]:
    """A sphere around an object, to skip the rays that cannot hit it."""
    c = np.asarray(obj["centre"], dtype=float)
    if obj["shape"] == "sphere":
        return c, obj["radius"]
    if obj["shape"] == "box":
        return c, float(np.linalg.norm(obj["half"]))
    half = obj["height"] / 2
    return c + [0.0, half, 0.0], math.hypot(obj["radius"], half)


def _may_hit(o, d, centre, radius) -> np.ndarray:
    oc = o - centre
    b = np.einsum("ij,ij->i", oc, d)
    c = np.einsum("ij,ij->i", oc, oc) - radius**2
    return (b * b - c >= 0) & ((b < 0) | (c < 0))


def _object_hit(obj: dict, o, d):
    c = np.asarray(obj["centre"])
    if obj["shape"] == "sphere":
        return _sphere(o, d, c, obj["radius"])
    if obj["shape"] == "box":
        return _box(o, d, c, obj["half"], obj["yaw"])
    return _cylinder(o, d, c, obj["radius"], obj["height"])


def intersect(scene: dict, o: np.ndarray, d: np.ndarray, orbs: bool = True) -> Hits:
    hits = Hits(len(o))
    hits.take(*_plane(o, d, np.zeros(3), UP), 0)
    if "wall" in scene:
        hits.take(*_plane(o, d, np.array([0, 0, scene["wall"]["z"]]), np.array([0.0, 0, 1])), 1)
    shapes = [(obj, 2 + i) for i, obj in enumerate(scene["objects"])]
    if orbs:
        shapes += [({"shape": "sphere", **orb}, -2 - j) for j, orb in enumerate(scene["orbs"])]
    for obj, ident in shapes:
        cand = np.flatnonzero(_may_hit(o, d, *_bounds(obj)))
        if len(cand):
            t, n = _object_hit(obj, o[cand], d[cand])
            hits.take_at(cand, t, n, ident)
    return hits


def visible(
    scene: dict, points: np.ndarray, normals: np.ndarray, d: np.ndarray, max_t
) -> np.ndarray:
    """1 where the segment from each point along d (up to max_t) meets no surface."""
    hits = intersect(scene, points + EPS * normals, d, orbs=False)
    return (hits.t >= np.asarray(max_t) - 2 * EPS).astype(np.float32)


# ---------------------------------------------------------------- shading


def _material(scene: dict, ident: int) -> dict:
    if ident == 0:
        return scene["floor"]
    if ident == 1:
        return scene["wall"]["material"]
    return scene["objects"][ident - 2]["material"]


def _albedo(m: dict, p: np.ndarray) -> np.ndarray:
    base = np.asarray(m["albedo"], dtype=np.float32)
    tex = m.get("texture")
    if tex is None:
        return np.broadcast_to(base, p.shape)
    s = p @ np.asarray(tex["axis"]) * tex["frequency"] + tex["phase"]
    if tex["pattern"] == "stripes":
        w = 0.5 + 0.5 * np.sin(s)
    elif tex["pattern"] == "checker":
        f = tex["frequency"] / 2
        w = (np.floor(p[:, 0] * f) + np.floor(p[:, 1] * f) + np.floor(p[:, 2] * f)) % 2
    else:  # grain: stripes bent by a slower wave
        w = 0.5 + 0.5 * np.sin(s + 2.0 * np.sin(0.23 * s + p[:, 1] * 3.0))
    other = np.asarray(tex["other"], dtype=np.float32)
    return base + (other - base) * w[:, None].astype(np.float32)


def sky_radiance(sky: dict, d: np.ndarray) -> np.ndarray:
    up = np.clip(d[:, 1], 0, 1) ** sky["power"]
    above = np.asarray(sky["horizon"]) + (np.asarray(sky["zenith"]) - sky["horizon"]) * up[:, None]
    return np.where(d[:, 1:2] >= 0, above, np.asarray(sky["ground"]))


def sky_irradiance(sky: dict, n: np.ndarray) -> np.ndarray:
    upper = 0.5 * (np.asarray(sky["horizon"]) + np.asarray(sky["zenith"]))
    w = 0.5 * (1 + n[:, 1:2])
    return math.pi * (w * upper + (1 - w) * np.asarray(sky["ground"]))


def lobe_radiance(lobes: list[dict], d: np.ndarray) -> np.ndarray:
    """The environment's SG lights seen along d (a camera looking at the sun sees it)."""
    out = np.zeros((len(d), 3))
    for g in lobes:
        out += (
            np.asarray(g["amplitude"])
            * np.exp(g["sharpness"] * (d @ np.asarray(g["axis"]) - 1))[:, None]
        )
    return out


def sg_reflection(g: dict, r: np.ndarray, lobe_sharpness: np.ndarray) -> np.ndarray:
    """Integral of SG light g against a normalised SG lobe around r (closed form)."""
    axis, lam = np.asarray(g["axis"]), g["sharpness"]
    lam_m = np.linalg.norm(lam * axis + lobe_sharpness[:, None] * r, axis=1)
    return _sg_integral(g, lam_m, lobe_sharpness)


def sg_reflection_at(g: dict, cos: np.ndarray, lobe_sharpness: np.ndarray) -> np.ndarray:
    """`sg_reflection` for unit lobe axes making cosine `cos` with the light's axis."""
    lam = g["sharpness"]
    lam_m = np.sqrt(lam**2 + lobe_sharpness**2 + 2 * lam * lobe_sharpness * cos)
    return _sg_integral(g, lam_m, lobe_sharpness)


def _sg_integral(g: dict, lam_m: np.ndarray, lobe_sharpness: np.ndarray) -> np.ndarray:
    """The closed form of `sg_reflection`, given the length of the product SG's axis."""
    lam = g["sharpness"]
    norm = lobe_sharpness / (2 * math.pi * (1 - np.exp(-2 * lobe_sharpness)))
    value = (
        norm * np.exp(lam_m - lam - lobe_sharpness) * 2 * math.pi / lam_m * (1 - np.exp(-2 * lam_m))
    )
    return value[:, None] * np.asarray(g["amplitude"])


def fresnel(f0: np.ndarray, cos: np.ndarray) -> np.ndarray:
    return f0 + (1 - f0) * ((1 - np.clip(cos, 0, 1)) ** 5)[:, None]


def ggx(n, v, light, alpha):
    h = v + light
    h /= np.linalg.norm(h, axis=1, keepdims=True) + 1e-12
    nh, nl, nv = (np.clip(np.einsum("ij,ij->i", n, x), 1e-4, 1) for x in (h, light, v))
    a2 = alpha**2
    dist = a2 / (math.pi * (nh**2 * (a2 - 1) + 1) ** 2)

    def g1(x):
        return 2 * x / (x + np.sqrt(a2 + (1 - a2) * x**2))

    return dist * g1(nl) * g1(nv) / (4 * nl * nv), np.einsum("ij,ij->i", v, h)


class Surface:
    """Per-sample surface data of hits, independent of the viewer."""

    def __init__(self, scene: dict, points, hits: Hits):
        n = len(points)
        self.points, self.normal, self.id = points, hits.normal.astype(np.float64), hits.id
        self.albedo = np.zeros((n, 3))
        self.f0 = np.zeros((n, 3))
        self.alpha = np.ones(n)
        self.emission = np.zeros((n, 3))
        for ident in np.unique(hits.id):
            sel = hits.id == ident
            if ident <= -2:
                self.emission[sel] = scene["orbs"][-2 - ident]["radiance"]
                continue
            if ident == -1:
                continue
            m = _material(scene, int(ident))
            self.albedo[sel] = _albedo(m, points[sel])
            self.f0[sel] = m["f0"]
            self.alpha[sel] = max(m["roughness"], 0.02)
        surf = hits.id >= 0
        self.surface = surf
        self.glossy = surf & (self.f0.max(1) > 0)
        # What the lights do to the diffuse term does not depend on the viewer either.
        self.diffuse = np.zeros((n, 3))
        self.light_vis: list[np.ndarray] = []
        self.orb_dirs: list[tuple] = []
        if surf.any():
            self._light(scene, surf)

    def _light(self, scene, surf):
        p, nrm = self.points[surf], self.normal[surf]
        irr = sky_irradiance(scene["sky"], nrm)
        for g in scene["lobes"]:
            axis = np.asarray(g["axis"])
            cos = np.clip(nrm @ axis, 0, 1)
            vis = visible(scene, p, nrm, np.broadcast_to(axis, p.shape), np.inf)
            self.light_vis.append(vis)
            irr = (
                irr
                + (np.asarray(g["amplitude"]) * 2 * math.pi / g["sharpness"]) * (cos * vis)[:, None]
            )
        for orb in scene["orbs"]:
            to = np.asarray(orb["centre"]) - p
            dist = np.linalg.norm(to, axis=1)
            ldir = to / dist[:, None]
            vis = visible(scene, p, nrm, ldir, dist - orb["radius"])
            intensity = np.asarray(orb["radiance"]) * math.pi * orb["radius"] ** 2
            cos = np.clip(np.einsum("ij,ij->i", nrm, ldir), 0, 1)
            self.orb_dirs.append((ldir, dist, vis, cos))
            irr = irr + intensity * (cos * vis / dist**2)[:, None]
        self.diffuse[surf] = self.albedo[surf] / math.pi * irr


def _environment(scene: dict, r, alpha, lobe_sharp, light_vis) -> np.ndarray:
    """Sky and SG lights reflected along r by lobes of roughness alpha; light_vis says, per
    SG light, whether it reaches the point at all."""
    rough = np.clip((alpha - 0.1) / 0.4, 0, 1)[:, None]
    sky = scene["sky"]
    env = (1 - rough) * sky_radiance(sky, r) + rough * sky_irradiance(sky, r) / math.pi
    for g, vis in zip(scene["lobes"], light_vis, strict=True):
        env += sg_reflection(g, r, lobe_sharp) * vis[:, None]
    return env


def _mirrored_objects(scene: dict, p, n, r, alpha, env) -> np.ndarray:
    """`env` where smooth surfaces see another surface along r instead of the sky."""
    lo, hi = TRACE_ROUGHNESS
    traced = np.clip((hi - alpha) / (hi - lo), 0, 1)
    rows = np.flatnonzero(traced > 0)
    if not len(rows):
        return env
    hits = intersect(scene, p[rows] + EPS * n[rows], r[rows], orbs=False)
    hit = hits.id >= 0
    if not hit.any():
        return env
    rows = rows[hit]
    seen = Hits(len(rows))
    seen.t, seen.normal, seen.id = hits.t[hit], hits.normal[hit], hits.id[hit]
    q = p[rows] + r[rows] * seen.t[:, None]
    w = traced[rows][:, None]
    env = env.copy()
    env[rows] = (1 - w) * env[rows] + w * Surface(scene, q, seen).diffuse
    return env


def _specular(scene: dict, s: Surface, v: np.ndarray):
    """(radiance of the specular layer, its Fresnel factor) at the glossy samples, seen
    along -v."""
    out, orbs, f = specular_parts(scene, s, v)
    for orb in orbs:
        out += orb
    return out, f


def specular_parts(scene: dict, s: Surface, v: np.ndarray):
    """The specular layer at the glossy samples seen along -v, by where its light comes
    from: (the reflected environment and objects, one term per orb, the Fresnel factor)."""
    sel = s.glossy
    p, n, alpha, f0 = s.points[sel], s.normal[sel], s.alpha[sel], s.f0[sel]
    # Rows of the glossy samples among the lit surface samples of `Surface._light`.
    rows = np.searchsorted(np.flatnonzero(s.surface), np.flatnonzero(sel))
    nv = np.clip(np.einsum("ij,ij->i", n, v), 1e-3, 1)
    r = 2 * nv[:, None] * n - v
    f = fresnel(f0, nv)
    lobe_sharp = 2 / alpha**2 / (4 * nv)
    env = _environment(scene, r, alpha, lobe_sharp, [vis[rows] for vis in s.light_vis])
    env = f * _mirrored_objects(scene, p, n, r, alpha, env)
    orbs = []
    for orb, (ldir, dist, vis, cos) in zip(scene["orbs"], s.orb_dirs, strict=True):
        d = dist[rows]
        widened = np.clip(alpha + orb["radius"] / (2 * d), 0, 1)
        spec, vh = ggx(n, v, ldir[rows], widened)
        spec = spec * (alpha / widened) ** 2
        intensity = np.asarray(orb["radiance"]) * math.pi * orb["radius"] ** 2
        e = intensity * (cos[rows] * vis[rows] / d**2)[:, None]
        orbs.append(fresnel(f0, vh) * spec[:, None] * e)
    return env, orbs, f


def shade(scene: dict, s: Surface, eye: np.ndarray) -> np.ndarray:
    """Radiance leaving each sample towards the point `eye`."""
    out = s.emission.copy()
    out[s.surface] = s.diffuse[s.surface]
    if s.glossy.any():
        v = eye - s.points[s.glossy]
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        spec, f = _specular(scene, s, v)
        # the light the specular layer reflects does not reach the diffuse base
        out[s.glossy] = s.diffuse[s.glossy] * (1 - f) + spec
    return out


def background(scene: dict, d: np.ndarray) -> np.ndarray:
    return sky_radiance(scene["sky"], d) + lobe_radiance(scene["lobes"], d)


# ---------------------------------------------------------------- cameras and images


def subsample_offsets(spp: int) -> np.ndarray:
    k = max(1, min(MAX_SUBSAMPLES, int(math.isqrt(max(spp, 1)))))
    g = (np.arange(k) + 0.5) / k - 0.5
    return np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)


def camera_rays(cam: Camera, offsets: np.ndarray):
    """World ray directions (S*H*W, 3) and z-cosines, samples ordered (s, y, x)."""
    ys, xs = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    dirs = []
    for du, dv in offsets:
        d = np.stack(
            [(xs + du - cam.cx) / cam.fx, (ys + dv - cam.cy) / cam.fy, np.ones_like(xs)], -1
        )
        dirs.append(d.reshape(-1, 3))
    d = np.concatenate(dirs)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d @ cam.rotation.T, d[:, 2]


def _resolve(values: np.ndarray, n_sub: int, cam: Camera) -> np.ndarray:
    return values.reshape(n_sub, cam.height, cam.width, -1).mean(0)


def _reshaded_from(scene: dict, surf: Surface, points, d, sky, eye: np.ndarray):
    """The input's samples shaded towards the camera centre `eye`, and the samples that
    camera cannot see (1: invalid)."""
    reshaded = shade(scene, surf, eye)
    reshaded[sky] = background(scene, d[sky])
    # The novel camera must see the sample: nothing in between, and its front side.
    to_eye = eye - points
    dist = np.linalg.norm(to_eye, axis=1)
    dirs = to_eye / np.maximum(dist, 1e-9)[:, None]
    facing = np.einsum("ij,ij->i", surf.normal, dirs) > 0
    seen = visible(scene, points, surf.normal, dirs, dist) > 0
    return reshaded, (~sky & ~(facing & seen)).astype(np.float32)


def render_pair(scene: dict, input_cam: Camera, novel_cam: Camera, spp: int, extra_cams=()) -> dict:
    """input, reshaded (the input's samples seen from the novel camera), novel, depth and
    the invalid fraction per pixel; with `extra_cams`, also "extra": per further novel
    camera a dict of its reshaded image and invalid fraction (no novel image)."""
    offsets = subsample_offsets(spp)
    n_sub = len(offsets)
    d, _ = camera_rays(input_cam, offsets)
    o = np.broadcast_to(input_cam.centre, d.shape)
    hits = intersect(scene, o, d)
    points = o + d * np.where(np.isfinite(hits.t), hits.t, 0)[:, None]
    surf = Surface(scene, points, hits)
    sky = hits.id == -1
    image = shade(scene, surf, input_cam.centre)
    image[sky] = background(scene, d[sky])
    reshaded, invalid = _reshaded_from(scene, surf, points, d, sky, novel_cam.centre)
    dn, _ = camera_rays(novel_cam, offsets)
    on = np.broadcast_to(novel_cam.centre, dn.shape)
    nh = intersect(scene, on, dn)
    npoints = on + dn * np.where(np.isfinite(nh.t), nh.t, 0)[:, None]
    novel = shade(scene, Surface(scene, npoints, nh), novel_cam.centre)
    novel[nh.id == -1] = background(scene, dn[nh.id == -1])
    dc, cos = camera_rays(input_cam, np.zeros((1, 2)))
    depth = intersect(scene, np.broadcast_to(input_cam.centre, dc.shape), dc).t * cos
    out = {
        "input": _resolve(image, n_sub, input_cam).astype(np.float32),
        "reshaded": _resolve(reshaded, n_sub, input_cam).astype(np.float32),
        "novel": _resolve(novel, n_sub, novel_cam).astype(np.float32),
        "invalid": _resolve(invalid, n_sub, input_cam)[..., 0],
        "depth": depth.reshape(input_cam.height, input_cam.width).astype(np.float32),
    }
    if extra_cams:
        out["extra"] = []
        for cam in extra_cams:
            resh, inval = _reshaded_from(scene, surf, points, d, sky, cam.centre)
            out["extra"].append(
                {
                    "reshaded": _resolve(resh, n_sub, input_cam).astype(np.float32),
                    "invalid": _resolve(inval, n_sub, input_cam)[..., 0],
                }
            )
    return out


# Tries per extra target at a free camera position around the example's fixed scene.
EXTRA_TARGET_TRIES = 200


def _free_offset(rng, scene: dict, input_cam: Camera, radii, tries: int):
    """A shell offset whose camera stands in free space, or None after `tries` draws."""
    for _ in range(tries):
        offset = sample_shell(rng, *radii)
        novel = input_cam.translated(offset)
        if camera_is_free(scene, novel.centre):
            return novel, offset
    return None


def make_example(seed: int, index: int, width: int, height: int, radii=(0.1, 0.3)):
    """(scene, camera dict, input camera, novel camera, offset) of example (seed, index)."""
    rng = example_rng(seed, index)
    for _ in range(20):
        scene = sample_scene(rng)
        if not scene["objects"]:
            continue
        try:
            cam = choose_camera(rng, scene)
        except RuntimeError:
            continue
        m = look_at(cam["position"], cam["target"], (0.0, 1.0, 0.0), cam["roll_deg"])
        input_cam = Camera(m, width, height, cam["fov_x_deg"])
        found = _free_offset(rng, scene, input_cam, radii, 50)
        if found is not None:
            return scene, cam, input_cam, *found
    raise RuntimeError(f"example {index}: no usable analytic scene in 20 tries")


def extra_targets(seed: int, index: int, scene: dict, input_cam: Camera, count: int, radii):
    """`count` further (novel camera, offset) pairs of example (seed, index), drawn as the
    first one is (the same shell, the same free-space check) from the example's own stream
    2: the first target stays what a one-target render writes, and target k is the same
    whatever the number of targets asked for."""
    rng = example_rng(seed, index, 2)
    out = []
    for k in range(count):
        found = _free_offset(rng, scene, input_cam, radii, EXTRA_TARGET_TRIES)
        if found is None:
            raise RuntimeError(
                f"example {index}: no free camera for target {k + 1} in {EXTRA_TARGET_TRIES} tries"
            )
        out.append(found)
    return out


def _write_exr(path: str, image: np.ndarray) -> None:
    from ..synthetic import write_exr

    names = ("R", "G", "B") if image.shape[-1] == 3 else ("Y",)
    write_exr(path, {n: image[..., k] for k, n in enumerate(names)})


def _write_mask(path: str, mask: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(mask.astype(np.uint8), mode="L").save(path)


def render_example(out_dir: str, seed: int, index: int, settings) -> dict:
    """Render and write example (seed, index); the folder appears complete or not at all.
    `settings.targets` > 1 adds that many minus one further reshaded targets."""
    start = time.perf_counter()
    radii = (settings.radius_min, settings.radius_max)
    scene, cam, input_cam, novel_cam, offset = make_example(
        seed, index, settings.width, settings.height, radii
    )
    extra = extra_targets(seed, index, scene, input_cam, settings.targets - 1, radii)
    views = render_pair(scene, input_cam, novel_cam, settings.spp, [c for c, _ in extra])
    meta = example_meta(
        views,
        seed,
        index,
        settings,
        spp=len(subsample_offsets(settings.spp)),
        change_seeds=1,
        render_seed=0,
        input_cam=input_cam,
        novel_cam=novel_cam,
        offset=offset,
        scene=scene,
        camera=cam,
        timings={"total": time.perf_counter() - start},
        extra=extra,
    )
    write_example(out_dir, views, meta, _write_exr, _write_mask)
    return meta
