"""Procedural textures and skies as numpy arrays (tileable, deterministic from parameters).

`sample_texture` draws a JSON-able parameter set; `make_texture` turns it into an image.
Keeping the two apart lets meta.json record every randomised parameter and lets anyone
regenerate the exact bitmap from it.
"""

import math

import numpy as np

KINDS = ("noise", "wood", "tiles", "stripes")
TEXTURE_SIZE = 128


def value_noise(rng: np.random.Generator, size: int, base: int, octaves: int) -> np.ndarray:
    """Tileable fractal value noise in [0, 1]."""
    out = np.zeros((size, size))
    weight_sum = 0.0
    for k in range(octaves):
        cells = base * 2**k
        grid = rng.random((cells, cells))
        pos = np.arange(size) * cells / size
        i0 = np.floor(pos).astype(int)
        f = pos - i0
        f = f * f * (3 - 2 * f)  # smoothstep: no visible grid creases
        i1 = (i0 + 1) % cells
        rows0 = grid[i0][:, i0] * (1 - f)[None, :] + grid[i0][:, i1] * f[None, :]
        rows1 = grid[i1][:, i0] * (1 - f)[None, :] + grid[i1][:, i1] * f[None, :]
        layer = rows0 * (1 - f)[:, None] + rows1 * f[:, None]
        weight = 0.5**k
        out += weight * layer
        weight_sum += weight
    return out / weight_sum


def _pattern(p: dict, size: int) -> np.ndarray:
    """Scalar pattern in [0, 1] for texture parameters `p`."""
    rng = np.random.default_rng(p["seed"])
    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size
    kind = p["kind"]
    if kind == "noise":
        return value_noise(rng, size, p["scale"], 4)
    if kind == "wood":
        turb = value_noise(rng, size, 4, 3)
        # Rings around a centre outside the tile, wrapped so the tile repeats seamlessly.
        cx, cy = p["centre"]
        r = np.hypot(np.sin(math.pi * (x - cx)), np.sin(math.pi * (y - cy)))
        rings = (r * p["rings"] + p["turbulence"] * turb) % 1.0
        return np.clip(rings**0.7, 0, 1)
    if kind == "tiles":
        n = p["count"]
        gx, gy = (x * n) % 1.0, (y * n) % 1.0
        grout = (np.minimum(gx, 1 - gx) < p["grout"]) | (np.minimum(gy, 1 - gy) < p["grout"])
        tile_ids = (np.floor(y * n) * n + np.floor(x * n)).astype(int)
        shades = rng.uniform(0.55, 1.0, n * n)[tile_ids]
        return np.where(grout, 0.0, shades)
    if kind == "stripes":
        angle = p["angle"]
        # Integer frequencies along both axes keep the stripes tileable.
        fx, fy = round(p["count"] * math.cos(angle)), round(p["count"] * math.sin(angle))
        s = 0.5 + 0.5 * np.sin(2 * math.pi * (fx * x + fy * y))
        return np.clip((s - 0.5) * p["sharpness"] + 0.5, 0, 1)
    raise ValueError(f"unknown texture kind {kind!r}")


def sample_texture(rng: np.random.Generator, kinds=KINDS) -> dict:
    """Random texture parameters (JSON-able)."""
    kind = str(rng.choice(kinds))
    p = {"kind": kind, "seed": int(rng.integers(2**31)), "uv_scale": float(rng.uniform(1, 4))}
    if kind == "noise":
        p["scale"] = int(rng.integers(2, 9))
    elif kind == "wood":
        p.update(
            centre=[float(v) for v in rng.uniform(-0.5, 0.5, 2)],
            rings=float(rng.uniform(4, 14)),
            turbulence=float(rng.uniform(0.2, 1.5)),
        )
    elif kind == "tiles":
        p.update(count=int(rng.integers(2, 9)), grout=float(rng.uniform(0.02, 0.08)))
    else:
        p.update(
            count=int(rng.integers(2, 12)),
            angle=float(rng.uniform(0, math.pi)),
            sharpness=float(rng.uniform(1, 8)),
        )
    return p


def make_texture(p: dict, lo, hi, size: int = TEXTURE_SIZE) -> np.ndarray:
    """Pattern mapped linearly from `lo` to `hi` (scalars or RGB), shape (size, size, C)."""
    t = _pattern(p, size)[..., None]
    lo, hi = np.atleast_1d(lo).astype(float), np.atleast_1d(hi).astype(float)
    return (lo + (hi - lo) * t).astype(np.float32)


def make_sky(p: dict, height: int = 64) -> np.ndarray:
    """Latitude-longitude environment (height x 2*height x 3, linear HDR), +y up.

    A vertical gradient from `horizon` to `zenith` above the horizon, `ground` below,
    plus a soft sun disc of radiance `sun_radiance` at (sun_elevation, sun_azimuth).
    """
    width = 2 * height
    v, u = (np.mgrid[0:height, 0:width] + 0.5) / np.array([height, width])[:, None, None]
    theta = v * math.pi  # 0 at the zenith
    phi = u * 2 * math.pi
    elevation = math.pi / 2 - theta
    up = np.clip(np.sin(elevation), 0, 1)[..., None] ** p["gradient_power"]
    zenith, horizon, ground = (np.array(p[k]) for k in ("zenith", "horizon", "ground"))
    sky = np.where(elevation[..., None] >= 0, horizon + (zenith - horizon) * up, ground)
    d = np.stack([np.sin(theta) * np.cos(phi), np.cos(theta), np.sin(theta) * np.sin(phi)], axis=-1)
    se, sa = p["sun_elevation"], p["sun_azimuth"]
    sun_dir = np.array([math.cos(se) * math.cos(sa), math.sin(se), math.cos(se) * math.sin(sa)])
    angle = np.arccos(np.clip(d @ sun_dir, -1, 1))
    sun = np.exp(-((angle / p["sun_size"]) ** 2))[..., None] * np.array(p["sun_radiance"])
    return (sky * p["intensity"] + sun).astype(np.float32)
