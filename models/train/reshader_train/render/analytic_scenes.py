"""The analytic family's scenes (`analytic.py` renders them): every random choice of a
scene as a JSON-able dict kept in meta.json, and a free camera that looks at it.

Spheres, boxes turned about the vertical and capped cylinders stand on an infinite floor
(y = 0), half of them before a back wall; 0-3 small emissive orbs hang above them. Lights
are a sky gradient and spherical Gaussians (SGs): the sun, softboxes and windows, and
strip lights as rows of small lobes.
"""

import colorsys
import math

import numpy as np

FAMILY = "analytic"
# A fifth of the scenes have no specular term at all: their reshaded image equals the
# input exactly, which teaches the network to leave diffuse surfaces alone.
DIFFUSE_SCENE_P = 0.2
# Offsets of secondary rays from the surface, against self-intersection.
CLEARANCE = 0.35

MATERIALS = (
    ("matte", 0.22),
    ("plastic", 0.2),
    ("varnish", 0.18),
    ("metal", 0.2),
    ("ceramic", 0.1),
    ("paint", 0.1),
)
METALS = {  # F0 of polished metals, linear RGB (chrome, copper, gold, steel, aluminium)
    "chrome": (0.55, 0.56, 0.55),
    "copper": (0.95, 0.64, 0.54),
    "gold": (1.0, 0.78, 0.34),
    "steel": (0.56, 0.57, 0.58),
    "aluminium": (0.91, 0.92, 0.92),
}


def _colour(rng, sat=(0.0, 0.85), val=(0.15, 0.9)) -> list[float]:
    h, s, v = rng.uniform(), rng.uniform(*sat), rng.uniform(*val)
    return [float(c) ** 2.2 for c in colorsys.hsv_to_rgb(h, s, v)]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _direction(azimuth: float, elevation: float) -> list[float]:
    c = math.cos(elevation)
    return [c * math.sin(azimuth), math.sin(elevation), c * math.cos(azimuth)]


def sample_material(rng, diffuse_only: bool, max_frequency: float = 20.0) -> dict:
    """A random material; `max_frequency` bounds its texture's cycles per unit (large
    surfaces seen at a grazing angle alias above a few)."""
    names, weights = zip(*MATERIALS, strict=True)
    kind = "matte" if diffuse_only else str(rng.choice(names, p=np.array(weights) / sum(weights)))
    albedo = _colour(rng)
    m = {"kind": kind, "albedo": albedo, "roughness": 1.0, "f0": [0.0, 0.0, 0.0]}
    if rng.uniform() < 0.4:
        m["texture"] = {
            "pattern": str(rng.choice(["stripes", "checker", "grain"])),
            "other": _colour(rng) if rng.uniform() < 0.5 else [c * 0.4 for c in albedo],
            "frequency": float(rng.uniform(0.15, 1.0) * max_frequency),
            "axis": _unit(rng.normal(size=3)).tolist(),
            "phase": float(rng.uniform(0, 2 * math.pi)),
        }
    if kind == "matte":
        return m
    ranges = {
        "plastic": (0.05, 0.4),
        "varnish": (0.02, 0.12),
        "metal": (0.02, 0.45),
        "ceramic": (0.02, 0.08),
        "paint": (0.03, 0.2),
    }
    lo, hi = ranges[kind]
    m["roughness"] = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    if kind == "metal":
        metal = str(rng.choice(list(METALS)))
        m["metal"] = metal
        m["f0"] = list(METALS[metal])
        m["albedo"] = [0.0, 0.0, 0.0]
        m.pop("texture", None)
    else:
        m["f0"] = [float(rng.uniform(0.03, 0.06))] * 3
    return m


def _sample_lights(rng, studio: bool) -> dict:
    sky_scale = float(rng.uniform(0.01, 0.08) if studio else rng.uniform(0.2, 1.0))
    sky = {
        "zenith": [c * sky_scale for c in _colour(rng, (0.1, 0.7), (0.5, 1.0))],
        "horizon": [c * sky_scale for c in _colour(rng, (0.0, 0.3), (0.6, 1.0))],
        "ground": [c * sky_scale for c in _colour(rng, (0.0, 0.4), (0.1, 0.4))],
        "power": float(rng.uniform(0.3, 2.0)),
    }
    lobes = []  # (axis, sharpness, rgb irradiance at normal incidence)

    def add(axis, radius, irradiance, colour):
        sharp = 2.0 / radius**2
        lobes.append(
            {
                "axis": _unit(axis).tolist(),
                "sharpness": float(sharp),
                # amplitude A such that the lobe's integral A 2pi/sharp is `irradiance`
                "amplitude": [float(irradiance * c * sharp / (2 * math.pi)) for c in colour],
            }
        )

    if not studio and rng.uniform() < 0.7:  # the sun
        warm = [1.0, float(rng.uniform(0.8, 1.0)), float(rng.uniform(0.6, 0.95))]
        axis = _direction(rng.uniform(0, 2 * math.pi), rng.uniform(0.15, 1.2))
        add(axis, rng.uniform(0.01, 0.05), rng.uniform(2, 8) * sky_scale * 3, warm)
    for _ in range(int(rng.integers(0 if not studio else 1, 4))):  # softboxes and windows
        axis = _direction(rng.uniform(0, 2 * math.pi), rng.uniform(0.05, 1.3))
        add(axis, rng.uniform(0.08, 0.4), rng.uniform(0.5, 3.0), _colour(rng, (0, 0.2), (0.8, 1)))
    if rng.uniform() < 0.4:  # a strip light: a row of small lobes along an arc
        az, el = rng.uniform(0, 2 * math.pi), rng.uniform(0.2, 1.2)
        turn, rise = rng.uniform(-0.6, 0.6), rng.uniform(-0.4, 0.4)
        colour, each = _colour(rng, (0, 0.15), (0.8, 1)), rng.uniform(0.3, 1.0)
        for k in range(5):
            s = k / 4 - 0.5
            add(_direction(az + turn * s, el + rise * s), rng.uniform(0.04, 0.08), each, colour)
    return {"sky": sky, "lobes": lobes}


def _sample_objects(rng, diffuse_only: bool) -> list[dict]:
    objects: list[dict] = []
    for _ in range(60):
        if len(objects) >= int(rng.integers(2, 7)):
            break
        shape = str(rng.choice(["sphere", "box", "cylinder"], p=[0.45, 0.25, 0.3]))
        size = float(rng.uniform(0.15, 0.6))
        x, z = rng.uniform(-1.4, 1.4, 2)
        o = {"shape": shape, "material": sample_material(rng, diffuse_only)}
        if shape == "sphere":
            o.update(centre=[float(x), size, float(z)], radius=size)
        elif shape == "box":
            half = [size * float(rng.uniform(0.5, 1.2)) for _ in range(3)]
            o.update(centre=[float(x), half[1], float(z)], half=half)
            o["yaw"] = float(rng.uniform(0, math.pi))
        else:
            o.update(
                centre=[float(x), 0.0, float(z)],
                radius=size * float(rng.uniform(0.4, 1.0)),
                height=size * float(rng.uniform(1.0, 3.0)),
            )
        if all(_footprint_gap(o, other) > 0.05 for other in objects):
            objects.append(o)
    return objects


def _footprint(o: dict) -> float:
    if o["shape"] == "box":
        return math.hypot(o["half"][0], o["half"][2])
    return o["radius"]


def _footprint_gap(a: dict, b: dict) -> float:
    (ax, _, az), (bx, _, bz) = a["centre"], b["centre"]
    return math.hypot(ax - bx, az - bz) - _footprint(a) - _footprint(b)


def _top(o: dict) -> float:
    if o["shape"] == "sphere":
        return 2 * o["radius"]
    if o["shape"] == "box":
        return 2 * o["half"][1]
    return o["height"]


def sample_scene(rng: np.random.Generator) -> dict:
    """Every random choice of one scene, as a JSON-able dict (kept in meta.json)."""
    diffuse_only = bool(rng.uniform() < DIFFUSE_SCENE_P)
    studio = bool(rng.uniform() < 0.4)
    scene = {
        "family": FAMILY,
        "diffuse_only": diffuse_only,
        "studio": studio,
        "floor": sample_material(rng, diffuse_only, max_frequency=4.0),
        "objects": _sample_objects(rng, diffuse_only),
        **_sample_lights(rng, studio),
        "orbs": [],
    }
    if rng.uniform() < 0.5:
        scene["wall"] = {
            "z": float(rng.uniform(-3.5, -2.0)),
            "material": sample_material(rng, True, max_frequency=4.0),
        }
    for _ in range(int(rng.integers(0, 4))):
        radius = float(rng.uniform(0.03, 0.1))
        intensity = float(rng.uniform(0.3, 3.0))
        colour = _colour(rng, (0.0, 0.8), (0.8, 1.0))
        scene["orbs"].append(
            {
                "centre": [
                    float(rng.uniform(-2, 2)),
                    float(rng.uniform(0.8, 2.5)),
                    float(rng.uniform(-2, 2)),
                ],
                "radius": radius,
                # radiance of the orb's surface: intensity / (pi r^2)
                "radiance": [intensity * c / (math.pi * radius**2) for c in colour],
            }
        )
    return scene


def camera_is_free(scene: dict, pos: np.ndarray) -> bool:
    """Inside the room, above the floor, and CLEARANCE away from every object and orb."""
    if pos[1] < CLEARANCE or ("wall" in scene and pos[2] < scene["wall"]["z"] + CLEARANCE):
        return False
    for o in scene["objects"]:
        c = np.asarray(o["centre"])
        horizontal = math.hypot(pos[0] - c[0], pos[2] - c[2]) - _footprint(o)
        if horizontal < CLEARANCE and pos[1] < _top(o) + CLEARANCE:
            return False
    return all(
        np.linalg.norm(pos - np.asarray(orb["centre"])) > orb["radius"] + CLEARANCE
        for orb in scene["orbs"]
    )


def choose_camera(rng, scene: dict) -> dict:
    """Look at a random object from 1-3.5 units, 3-45 degrees above it."""
    for _ in range(200):
        obj = scene["objects"][int(rng.integers(len(scene["objects"])))]
        target = np.asarray(obj["centre"]) + [0.0, 0.5 * _top(obj) - obj["centre"][1], 0.0]
        target = target + rng.normal(0, 0.1, 3)
        dist, az = rng.uniform(1.0, 3.5), rng.uniform(0, 2 * math.pi)
        if "wall" in scene:  # face the wall, as a photographer would
            az = rng.uniform(-1.2, 1.2)
        pos = target + dist * np.asarray(_direction(az, math.radians(rng.uniform(3, 45))))
        if camera_is_free(scene, pos):
            return {
                "position": pos.tolist(),
                "target": target.tolist(),
                "fov_x_deg": float(rng.uniform(40, 70)),
                "roll_deg": float(rng.normal(0, 3)),
            }
    raise RuntimeError("no free camera position in 200 tries")
