"""Procedural textures and skies as numpy arrays (tileable, deterministic from parameters).

`sample_texture` draws a JSON-able parameter set; `make_texture` turns it into an image.
Keeping the two apart lets meta.json record every randomised parameter and lets anyone
regenerate the exact bitmap from it.
"""

import math

import numpy as np

# The default kinds of `sample_texture`. "marble", "granite" and "planks" are drawn by
# name only (the photographic families' stone and floors), so that the older families'
# random streams stay as they were.
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
    if kind == "marble":
        # Veins where a tileable sine, bent by fractal noise, crosses zero.
        turb = value_noise(rng, size, 3, 5)
        phase = math.pi * (p["fx"] * x + p["fy"] * y) + 2 * math.pi * p["turbulence"] * turb
        veins = np.abs(np.sin(phase)) ** p["vein_power"]
        return np.clip(0.15 + 0.85 * veins + 0.1 * (turb - 0.5), 0, 1)
    if kind == "granite":
        grains = value_noise(rng, size, 32, 2)
        mottle = value_noise(rng, size, 4, 3)
        speckle = (grains > p["threshold"]).astype(float)
        return np.clip(0.55 + 0.35 * (mottle - 0.5) + 0.45 * (speckle - 0.5), 0, 1)
    if kind == "planks":
        # `rows` boards across, `boards` along each row (staggered); grain along the board.
        rows, boards = p["rows"], p["boards"]
        row = np.floor(y * rows).astype(int)
        offsets = rng.uniform(0, 1, rows)
        along = (x * boards + offsets[row]) % 1.0
        board = (row * boards + np.floor((x * boards + offsets[row]) % boards)).astype(int)
        shades = rng.uniform(0.6, 1.0, rows * boards)[board % (rows * boards)]
        turb = value_noise(rng, size, 4, 3)
        across = (y * rows) % 1.0
        grain = 0.5 + 0.5 * np.sin(2 * math.pi * (p["grain"] * across + 3 * turb))
        gap = (np.minimum(across, 1 - across) < 0.03) | (np.minimum(along, 1 - along) < 0.004)
        return np.where(gap, 0.05, shades * (0.7 + 0.3 * grain))
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
    elif kind == "stripes":
        p.update(
            count=int(rng.integers(2, 12)),
            angle=float(rng.uniform(0, math.pi)),
            sharpness=float(rng.uniform(1, 8)),
        )
    elif kind == "marble":
        p.update(
            fx=int(rng.integers(1, 4)),
            fy=int(rng.integers(0, 3)),
            turbulence=float(rng.uniform(0.5, 2.0)),
            vein_power=float(rng.uniform(0.15, 0.5)),
        )
    elif kind == "granite":
        p["threshold"] = float(rng.uniform(0.5, 0.7))
    elif kind == "planks":
        p.update(
            rows=int(rng.integers(4, 9)),
            boards=int(rng.integers(1, 3)),
            grain=float(rng.uniform(2, 6)),
        )
    else:
        raise ValueError(f"unknown texture kind {kind!r}")
    return p


def make_texture(p: dict, lo, hi, size: int = TEXTURE_SIZE) -> np.ndarray:
    """Pattern mapped linearly from `lo` to `hi` (scalars or RGB), shape (size, size, C)."""
    t = _pattern(p, size)[..., None]
    lo, hi = np.atleast_1d(lo).astype(float), np.atleast_1d(hi).astype(float)
    return (lo + (hi - lo) * t).astype(np.float32)


def env_directions(height: int) -> np.ndarray:
    """World direction of every texel centre of a (height x 2*height) latitude-longitude
    map as Mitsuba's `envmap` reads it: u = atan2(x, -z) / 2pi, v = acos(y) / pi."""
    v, u = (np.mgrid[0:height, 0 : 2 * height] + 0.5) / np.array([height, 2 * height])[
        :, None, None
    ]
    theta, phi = v * math.pi, u * 2 * math.pi
    return np.stack(
        [np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], axis=-1
    )


def direction(elevation: float, azimuth: float) -> np.ndarray:
    """World unit vector (y up) at `elevation` above the horizon, `azimuth` from +x to +z."""
    return np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.sin(elevation),
            math.cos(elevation) * math.sin(azimuth),
        ]
    )


def _panel(dirs: np.ndarray, q: dict) -> np.ndarray:
    """Coverage in [0, 1] of one environment panel: a rectangle or disc of half-sizes
    (`half_width`, `half_height`) in the plane tangent to the sphere at its centre, so that
    a chrome ball mirrors a softbox as a rectangle; edges fade over `softness`."""
    c = direction(q["elevation"], q["azimuth"])
    right = np.cross(c, [0.0, 1.0, 0.0])
    if np.linalg.norm(right) < 1e-6:  # straight up or down
        right = np.array([1.0, 0.0, 0.0])
    right = right / np.linalg.norm(right)
    up = np.cross(right, c)
    a = math.radians(q.get("roll_deg", 0.0))
    right, up = math.cos(a) * right + math.sin(a) * up, -math.sin(a) * right + math.cos(a) * up
    dc = dirs @ c
    front = dc > 1e-3
    safe = np.where(front, dc, 1.0)
    x = (dirs @ right) / safe / q["half_width"]
    y = (dirs @ up) / safe / q["half_height"]
    r = np.hypot(x, y) if q["shape"] == "disc" else np.maximum(np.abs(x), np.abs(y))
    soft = max(q.get("softness", 0.05), 1e-3)
    cover = np.clip((1 + soft - r) / (2 * soft), 0, 1)
    if q.get("bars"):  # a window: glazing bars cross the panes
        nx, ny, bar = q["bars"]
        gx, gy = ((x + 1) / 2 * nx) % 1.0, ((y + 1) / 2 * ny) % 1.0
        on_bar = (np.minimum(gx, 1 - gx) < bar * nx) | (np.minimum(gy, 1 - gy) < bar * ny)
        cover = np.where(on_bar & (np.abs(x) < 1) & (np.abs(y) < 1), 0.0, cover)
    return np.where(front, cover, 0.0)


def make_environment(p: dict) -> np.ndarray:
    """`make_sky` at `p["height"]` rows (default 64), its brightness varied by smooth noise
    (`p["mottle"]`: seed, scale, amount), plus `p["panels"]`: softboxes, strip lights,
    windows and lamps painted into the environment map, each of radiance `radiance`
    (2x2 supersampled, so that small panels keep their shape)."""
    height = int(p.get("height", 64))
    sky = make_sky(p, height)
    if p.get("mottle"):  # walls and stands of an interior or studio, out of focus
        m = p["mottle"]
        noise = value_noise(np.random.default_rng(m["seed"]), 2 * height, m["scale"], 3)
        sky = sky * (1 + m["amount"] * (2 * noise[:height] - 1))[..., None]
    panels = p.get("panels") or []
    if not panels:
        return sky
    dirs = env_directions(2 * height)
    light = np.zeros(dirs.shape, dtype=np.float64)
    for q in panels:
        light += _panel(dirs, q)[..., None] * np.asarray(q["radiance"], dtype=float)
    light = light.reshape(height, 2, 2 * height, 2, 3).mean(axis=(1, 3))
    return (sky + light).astype(np.float32)


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
