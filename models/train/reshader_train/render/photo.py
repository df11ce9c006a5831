"""Photographic procedural families: `products`, `rooms` and `diffuse`.

A network trained on the older families moved highlights only faintly on photos of shiny
things: their scenes are lit by a sky, a sun and orbs, and made of a few generic
materials. These families look like what people photograph:

- `products`: product shots on a studio's seamless backdrop (a sweep) or on a counter,
  lit by environments made in code (studio softboxes and strip lights, interiors with
  windows, skies) and by emissive softboxes and strip lights; objects of varnished wood,
  car paint, polished and honed stone, polished and brushed metal, glazed ceramic,
  plastic, a little glass, with matte objects mixed in. Seen from 0.8-2.5 units.
- `rooms`: rooms 4-10 units across with varnished floors, counters along a wall, tables
  and, in one room of four, a car-like body in clear-coat paint, lit by windows (daylight
  emitters behind frames and glazing bars), ceiling panels and the sky through missing
  walls. Seen from 1-4.5 units.
- `diffuse`: the scenes of both with every material made Lambertian. Nothing there
  changes between views, so these examples teach the network to leave such photos alone.

Geometry, lights and environment are drawn first; `_dress` then draws every material
from its slot's role (a counter top is stone, wood, steel or acrylic; a wall is paint or
tiles), so that `restyle` re-dresses a fixed layout with the same rules. Each family
draws from its own random stream (`STREAMS`): the same --seed gives unrelated scenes in
different families. Everything is at the project's one scale (y up, units ~metres).
"""

import copy
import math

import numpy as np

from . import meshes, procedural
from .materials import RECIPES, lambertian, material_dict, random_colour, sample_recipe

PHOTO_FAMILIES = procedural.PHOTO_FAMILIES
STREAMS = {"products": 9_100_001, "rooms": 9_100_002, "diffuse": 9_100_003}

# Material recipes (materials.RECIPES) per role, with their weights.
ROLES = {
    "product": (
        ("varnished_wood", 0.07),
        ("car_paint", 0.08),
        ("polished_stone", 0.06),
        ("honed_stone", 0.04),
        ("polished_metal", 0.14),
        ("brushed_metal", 0.10),
        ("glazed_ceramic", 0.15),
        ("plastic", 0.14),
        ("glass", 0.04),
        ("matte", 0.18),
    ),
    "backdrop": (("paper", 0.55), ("acrylic", 0.3), ("paint", 0.15)),
    "counter_top": (
        ("polished_stone", 0.35),
        ("honed_stone", 0.15),
        ("varnished_wood", 0.3),
        ("brushed_metal", 0.1),
        ("acrylic", 0.1),
    ),
    "cabinet": (("paint", 0.6), ("varnished_wood", 0.25), ("acrylic", 0.15)),
    "table": (("varnished_wood", 0.65), ("polished_stone", 0.2), ("paint", 0.15)),
    "floor": (
        ("wood_floor", 0.45),
        ("glossy_tiles", 0.15),
        ("polished_stone", 0.1),
        ("concrete", 0.15),
        ("carpet", 0.15),
    ),
    "wall": (("paint", 0.85), ("glossy_tiles", 0.15)),
    "ceiling": (("paint", 1.0),),
    "frame": (("paint", 0.7), ("varnished_wood", 0.3)),
    "car_paint": (("car_paint", 1.0),),
    "car_glass": (("tinted_glass", 1.0),),
    "tyre": (("rubber", 1.0),),
    "rim": (("polished_metal", 0.6), ("brushed_metal", 0.4)),
}
assert all(r in RECIPES for choices in ROLES.values() for r, _ in choices)
# Glass only on closed shapes whose normals point outwards (meshes.blob's point inwards,
# which would swap a dielectric's inside and outside); it is also the most expensive
# material to render.
CLOSED = ("sphere", "rounded", "torus", "cube")
# (shape, weight) of products; bottles and bowls are vases with their own profiles.
PRODUCT_SHAPES = (
    ("rounded", 0.22),
    ("sphere", 0.12),
    ("cylinder", 0.13),
    ("bottle", 0.12),
    ("vase", 0.09),
    ("bowl", 0.08),
    ("blob", 0.1),
    ("torus", 0.06),
    ("cube", 0.08),
)
# Material slots of each object shape: key in the object -> role.
SLOTS = {
    "table": {"material": "table"},
    "counter": {"material": "counter_top", "body_material": "cabinet"},
    "car": {
        "material": "car_paint",
        "glass_material": "car_glass",
        "tyre_material": "tyre",
        "rim_material": "rim",
    },
}
ROOM_SLOTS = {
    "floor_material": "floor",
    "wall_material": "wall",
    "ceiling_material": "ceiling",
    "frame_material": "frame",
}
# World size of one texture tile on large surfaces, per texture kind (a plank floor's
# boards come out 0.14-0.2 wide whatever the room's size).
TILE_UNITS = {
    "planks": (0.14, 0.2),  # per row of boards
    "tiles": (0.15, 0.45),  # per tile
    "marble": (0.8, 2.0),
    "granite": (0.6, 1.2),
    "noise": (1.0, 3.0),
    "stripes": (0.5, 2.0),
    "wood": (0.6, 1.5),
}


def family_rng(rng: np.random.Generator, family: str) -> np.random.Generator:
    """The family's own stream, seeded from one draw of the example's `rng`."""
    return np.random.default_rng([STREAMS[family], int(rng.integers(2**63))])


def _choice(rng, weighted) -> str:
    names = [n for n, _ in weighted]
    w = np.array([w for _, w in weighted], dtype=float)
    return str(rng.choice(names, p=w / w.sum()))


def _material(rng, role: str, shape: str | None = None) -> dict:
    choices = [(r, w) for r, w in ROLES[role] if r != "glass" or shape in CLOSED]
    m = sample_recipe(rng, _choice(rng, choices))
    m["role"] = role
    return m


def _fit_texture(rng, m: dict, size_u: float, size_v: float) -> None:
    """Scale the albedo texture of `m` on a surface of size_u x size_v world units (whose
    uv run over [0, 1]) so that its tiles have their kind's world size."""
    albedo = m.get("albedo", {})
    if "texture" not in albedo:
        return
    t = albedo["texture"]
    per_tile = rng.uniform(*TILE_UNITS.get(t["kind"], (1.0, 2.0)))
    if t["kind"] == "planks":
        per_tile *= t["rows"]
    elif t["kind"] == "tiles":
        per_tile *= t["count"]
    t["uv_scale"] = [float(size_u / per_tile), float(size_v / per_tile)]


# --- geometry -------------------------------------------------------------------------


def _sample_product(rng, support: float, scale: float = 1.0) -> dict:
    shape = _choice(rng, PRODUCT_SHAPES)
    size = float(rng.uniform(0.1, 0.4) * scale)
    obj: dict = {"shape": shape, "size": size, "yaw": float(rng.uniform(0, 2 * math.pi))}
    obj["support"] = support
    if shape == "rounded":
        obj["extent"] = [float(v) for v in size * rng.uniform(0.35, 1.0, 3)]
        obj["exponents"] = [float(v) for v in rng.uniform(0.15, 0.6, 2)]
    elif shape == "cube":
        obj["extent"] = [float(v) for v in size * rng.uniform(0.4, 1.0, 3)]
    elif shape == "cylinder":
        obj["height"] = float(size * rng.uniform(0.8, 3.0))
    elif shape == "torus":
        obj["minor"] = float(size * rng.uniform(0.15, 0.4))
        obj["tilt"] = float(rng.choice([0.0, math.pi / 2]))
    elif shape == "blob":
        obj["amplitude"] = float(rng.uniform(0.05, 0.25))
        obj["seed"] = int(rng.integers(2**31))
    elif shape == "bottle":
        r = size * rng.uniform(0.35, 0.6)
        neck = rng.uniform(0.25, 0.4)
        obj.update(shape="vase", style="bottle", height=float(size * rng.uniform(2.5, 4.0)))
        obj["radii"] = [float(r * k) for k in (0.92, 1.0, 1.0, 1.0, 0.95, neck + 0.1, neck, neck)]
    elif shape == "bowl":
        obj.update(shape="vase", style="bowl", height=float(size * rng.uniform(0.45, 0.9)))
        obj["radii"] = [float(size * k) for k in (0.45, 0.75, 0.92, 1.0)]
    else:  # vase
        obj["height"] = float(size * rng.uniform(1.5, 3.5))
        obj["radii"] = [float(v) for v in size * rng.uniform(0.3, 1.0, int(rng.integers(3, 6)))]
    return obj


def _place_products(rng, objects, count, support, centre, spread, bounds, scale=1.0) -> None:
    for _ in range(count):
        procedural._place(
            rng, objects, _sample_product(rng, support, scale), centre, spread, bounds
        )


def _sample_counter(rng, position, extent_x, extent_z) -> dict:
    return {
        "shape": "counter",
        "yaw": 0.0,
        "support": 0.0,
        "position": [float(position[0]), 0.0, float(position[1])],
        "extent": [float(extent_x), float(rng.uniform(0.02, 0.04)), float(extent_z)],
        "height": float(rng.uniform(0.86, 0.95)),
        "overhang": float(rng.uniform(0.02, 0.05)),
    }


def _support_top(obj: dict) -> tuple[float, tuple]:
    """Height of a table's or counter's top and its (x0, x1, z0, z1), inset a little."""
    x, _, z = obj["position"]
    ex, ey, ez = obj["extent"]
    inset = 0.03
    return obj["height"] + ey, (x - ex + inset, x + ex - inset, z - ez + inset, z + ez - inset)


def _mottle(rng, most: float) -> dict:
    return {
        "seed": int(rng.integers(2**31)),
        "scale": int(rng.integers(3, 9)),
        "amount": float(rng.uniform(0.1, most)),
    }


def _studio_sky(rng) -> dict:
    """A studio: a dim backdrop of one grey, softboxes, strip lights and umbrellas."""
    sky = procedural._sample_sky(rng, (0.02, 0.2), 0.0)
    grey = random_colour(rng, sat=(0.0, 0.15), val=(0.3, 1.0))
    top = float(rng.uniform(0.4, 1.6))  # lighter or darker towards the ceiling
    sky.update(zenith=[c * top for c in grey], horizon=grey, ground=[c * 0.5 for c in grey])
    sky["mottle"] = _mottle(rng, 0.5)
    panels = []
    for _ in range(int(rng.integers(1, 5))):
        kind = _choice(rng, (("softbox", 0.5), ("strip", 0.3), ("umbrella", 0.2)))
        colour = random_colour(rng, sat=(0.0, 0.15), val=(0.9, 1.0))
        q = {
            "kind": kind,
            "shape": "disc" if kind == "umbrella" else "rect",
            "elevation": float(rng.uniform(math.radians(-5), math.radians(70))),
            "azimuth": float(rng.uniform(0, 2 * math.pi)),
            "softness": float(rng.uniform(0.02, 0.2)),
            "roll_deg": float(rng.normal(0, 10)),
        }
        if kind == "strip":
            q.update(
                half_width=float(rng.uniform(0.04, 0.09)), half_height=float(rng.uniform(0.4, 0.9))
            )
            gain = rng.uniform(5, 20)
        else:
            q["half_width"] = float(rng.uniform(0.15, 0.45))
            q["half_height"] = float(q["half_width"] * rng.uniform(0.6, 1.5))
            gain = rng.uniform(2, 12)
        q["radiance"] = [float(c * gain) for c in colour]
        panels.append(q)
    sky.update(panels=panels, environment="studio")
    return sky


def _interior_sky(rng) -> dict:
    """An interior around the subject: walls of one colour, windows, a lamp or two."""
    sky = procedural._sample_sky(rng, (0.1, 0.5), 0.0)
    wall = random_colour(rng, sat=(0.0, 0.3), val=(0.4, 0.9))
    sky.update(zenith=wall, horizon=wall, ground=[c * float(rng.uniform(0.2, 0.6)) for c in wall])
    sky["mottle"] = _mottle(rng, 0.8)
    panels = []
    for _ in range(int(rng.integers(1, 3))):
        daylight = random_colour(rng, sat=(0.0, 0.25), val=(0.9, 1.0))
        q = {
            "kind": "window",
            "shape": "rect",
            "elevation": float(rng.uniform(math.radians(5), math.radians(30))),
            "azimuth": float(rng.uniform(0, 2 * math.pi)),
            "half_width": float(rng.uniform(0.3, 0.7)),
            "half_height": float(rng.uniform(0.4, 0.8)),
            "softness": 0.01,
            "bars": [
                int(rng.integers(1, 4)),
                int(rng.integers(1, 4)),
                float(rng.uniform(0.01, 0.03)),
            ],
            "radiance": [float(c * rng.uniform(3, 12)) for c in daylight],
        }
        panels.append(q)
    for _ in range(int(rng.integers(0, 3))):
        warm = random_colour(rng, sat=(0.1, 0.4), val=(0.95, 1.0))
        half = float(rng.uniform(0.03, 0.08))
        panels.append(
            {
                "kind": "lamp",
                "shape": "disc",
                "elevation": float(rng.uniform(math.radians(40), math.radians(85))),
                "azimuth": float(rng.uniform(0, 2 * math.pi)),
                "half_width": half,
                "half_height": half,
                "softness": 0.1,
                "radiance": [float(c * rng.uniform(20, 80)) for c in warm],
            }
        )
    sky.update(panels=panels, environment="interior")
    return sky


def _product_sky(rng) -> dict:
    kind = _choice(rng, (("studio", 0.5), ("interior", 0.3), ("outdoor", 0.2)))
    if kind == "studio":
        sky = _studio_sky(rng)
    elif kind == "interior":
        sky = _interior_sky(rng)
    else:
        sky = procedural._sample_sky(rng, (0.5, 3.0), 0.7)
        sky["environment"] = "outdoor"
    sky["height"] = 128  # 1.4 degrees per texel: strip lights keep their shape
    return sky


def _area_light(rng, centre, kind: str) -> dict:
    """A softbox or strip light 1.3-2.8 units from `centre`, facing it."""
    a, el = rng.uniform(0, 2 * math.pi), rng.uniform(math.radians(10), math.radians(60))
    dist = rng.uniform(1.3, 2.8)
    c = np.asarray(centre, dtype=float)
    pos = c + dist * np.array(
        [math.cos(el) * math.cos(a), math.sin(el), math.cos(el) * math.sin(a)]
    )
    colour = random_colour(rng, sat=(0.0, 0.2), val=(0.9, 1.0))
    if kind == "strip":
        size, gain = (
            [float(rng.uniform(0.12, 0.3)), float(rng.uniform(0.8, 1.8))],
            rng.uniform(6, 25),
        )
    else:
        size, gain = [float(v) for v in rng.uniform(0.4, 1.2, 2)], rng.uniform(3, 12)
    return {
        "kind": kind,
        "position": [float(v) for v in pos],
        "target": [float(c[0]), float(c[1] + 0.2), float(c[2])],
        "size": size,
        "radiance": [float(v * gain) for v in colour],
    }


def _sample_products(rng) -> dict:
    scene: dict = {"base_depth": int(rng.integers(3, 5)), "camera_distance": [0.8, 2.5]}
    objects: list = []
    if rng.uniform() < 0.5:
        width, depth = float(rng.uniform(4, 7)), float(rng.uniform(2.5, 4))
        radius, height = float(rng.uniform(0.4, 1.2)), float(rng.uniform(2.5, 3.5))
        scene["stage"] = {
            "type": "sweep",
            "width": width,
            "floor_depth": depth,
            "radius": radius,
            "height": height,
        }
        centre = (float(rng.uniform(-0.5, 0.5)), depth * float(rng.uniform(0.25, 0.45)))
        inner = (-width / 2 + 0.2, width / 2 - 0.2, 0.05, depth - 0.3)
        _place_products(rng, objects, int(rng.integers(2, 7)), 0.0, centre, 0.8, inner, 1.3)
        # Cameras may stand a little in front of the sweep, never behind or beside it.
        scene["bounds"] = [-width / 2, width / 2, -radius, depth + 1.0, 0.0, height]
        light_centre = (centre[0], 0.3, centre[1])
    else:
        wall = float(rng.uniform(0.4, 1.5)) if rng.uniform() < 0.5 else None
        counter = _sample_counter(rng, (0.0, 0.0), rng.uniform(0.6, 1.4), rng.uniform(0.3, 0.6))
        scene["stage"] = {"type": "floor", "size": 20.0}
        z0 = -5.0
        if wall is not None:
            z0 = -counter["extent"][2] - wall
            scene["stage"]["wall_z"] = z0
        objects.append(counter)
        top, top_bounds = _support_top(counter)
        centre = ((top_bounds[0] + top_bounds[1]) / 2, (top_bounds[2] + top_bounds[3]) / 2)
        _place_products(rng, objects, int(rng.integers(2, 6)), top, centre, 0.8, top_bounds)
        floor_bounds = (-3.0, 3.0, z0 + 0.2, 3.0)
        _place_products(
            rng, objects, int(rng.integers(0, 3)), 0.0, (0.0, 1.0), 1.5, floor_bounds, 1.5
        )
        scene["bounds"] = [-5.0, 5.0, z0, 5.0, 0.0, 3.5]
        light_centre = (0.0, top, 0.0)
    scene["sky"] = _product_sky(rng)
    n_panels = len(scene["sky"].get("panels", []))
    lights = []
    for _ in range(int(rng.integers(0 if n_panels else 1, 3))):
        kind = "strip" if rng.uniform() < 0.35 else "softbox"
        light = _area_light(rng, light_centre, kind)
        x0, x1, z0, z1, _, y1 = scene["bounds"]
        p = light["position"]
        if x0 + 0.2 < p[0] < x1 - 0.2 and z0 + 0.2 < p[2] < z1 - 0.2 and p[1] < y1 - 0.1:
            lights.append(light)
    scene["area_lights"] = lights
    scene["objects"] = objects
    return scene


def _sample_window(rng, wall: int, length: float, height: float) -> dict | None:
    width = float(rng.uniform(0.8, min(2.2, length - 0.8)))
    sill = float(rng.uniform(0.5, 1.1))
    win_h = float(rng.uniform(1.0, max(1.0, min(1.8, height - sill - 0.2))))
    if width < 0.6 or sill + win_h > height - 0.1:
        return None
    daylight = random_colour(rng, sat=(0.0, 0.25), val=(0.9, 1.0))
    return {
        "wall": wall,
        "offset": float(rng.uniform(-(length - width) / 2 + 0.3, (length - width) / 2 - 0.3)),
        "sill": sill,
        "size": [width, win_h],
        "radiance": [float(c * rng.uniform(4, 20)) for c in daylight],
        "panes": [int(rng.integers(1, 4)), int(rng.integers(1, 4))],
        "bar": float(rng.uniform(0.03, 0.07)),
    }


def _sample_rooms(rng) -> dict:
    has_car = rng.uniform() < 0.25
    if has_car:
        w, d = float(rng.uniform(8, 10)), float(rng.uniform(6.5, 8.5))
    else:
        w, d = float(rng.uniform(4, 8)), float(rng.uniform(4, 8))
    h = float(rng.uniform(2.6, 3.4))
    # Closed rooms cost twice what open ones do (no path leaves them): a wall or the
    # ceiling is missing in about half of them, letting the sky in.
    walls = [bool(rng.uniform() < 0.85) for _ in range(4)]
    lengths = (d, d, w, w)
    windows = []
    for i in range(4):
        if walls[i] and len(windows) < 2 and rng.uniform() < 0.45:
            win = _sample_window(rng, i, lengths[i], h)
            if win:
                windows.append(win)
    room = {
        "type": "room",
        "size": [w, h, d],
        "walls": walls,
        "ceiling": bool(rng.uniform() < 0.75),
        "windows": windows,
    }
    # Depth 3: one indirect bounce (a chrome bowl mirrors a wall lit by the window).
    scene: dict = {"base_depth": 3, "camera_distance": [1.0, 4.5]}
    scene["stage"] = room
    bounds = (-w / 2, w / 2, -d / 2, d / 2)
    scene["bounds"] = [*bounds, 0.0, h]
    scene["sky"] = procedural._sample_sky(rng, (0.3, 2.0))
    scene["sky"]["environment"] = "outdoor"

    objects: list = []
    if has_car:
        procedural._place(rng, objects, _sample_car(rng), (0.0, 0.0), 0.6, bounds)
    if rng.uniform() < 0.55:  # a counter along a wall
        i = int(rng.integers(4))
        length = float(rng.uniform(1.4, min(3.0, lengths[i] - 0.8)))
        s = float(rng.uniform(-(lengths[i] - length) / 2 + 0.1, (lengths[i] - length) / 2 - 0.1))
        half_depth = float(rng.uniform(0.28, 0.33))
        inset = half_depth + 0.01
        if i < 2:  # walls at x = +-w/2 run along z
            pos, ext = ((1 if i == 0 else -1) * (w / 2 - inset), s), (half_depth, length / 2)
        else:
            pos, ext = (s, (1 if i == 2 else -1) * (d / 2 - inset)), (length / 2, half_depth)
        counter = _sample_counter(rng, pos, *ext)
        r = procedural._radius(counter)
        clear = all(
            math.dist(pos, (o["position"][0], o["position"][2])) > r + procedural._radius(o)
            for o in objects
        )
        if clear:
            objects.append(counter)
            top, top_bounds = _support_top(counter)
            centre = ((top_bounds[0] + top_bounds[1]) / 2, (top_bounds[2] + top_bounds[3]) / 2)
            _place_products(rng, objects, int(rng.integers(1, 5)), top, centre, 1.5, top_bounds)
    if rng.uniform() < 0.5:
        table = {
            "shape": "table",
            "yaw": 0.0,
            "support": 0.0,
            "extent": [float(rng.uniform(0.5, 1.0)), 0.03, float(rng.uniform(0.35, 0.6))],
            "height": float(rng.uniform(0.7, 0.8)),
        }
        if procedural._place(rng, objects, table, (0.0, 0.0), 2.0, bounds):
            top, top_bounds = _support_top(table)
            centre = (table["position"][0], table["position"][2])
            _place_products(rng, objects, int(rng.integers(1, 4)), top, centre, 0.6, top_bounds)
    n_floor = int(rng.integers(1, 4)) if objects else int(rng.integers(2, 5))
    _place_products(rng, objects, n_floor, 0.0, (0.0, 0.0), 2.5, bounds, 1.6)
    scene["objects"] = objects

    lights = []
    n_lights = int(rng.integers(0 if windows else 1, 3))
    for _ in range(n_lights):
        if rng.uniform() < 0.6:
            size = [float(v) for v in rng.uniform(0.3, 1.2, 2)]
            gain = rng.uniform(3, 12)
        else:
            size = [float(rng.uniform(0.1, 0.2)), float(rng.uniform(0.8, 1.5))]
            gain = rng.uniform(8, 25)
        pos = [
            float(rng.uniform(-w / 2 + 0.8, w / 2 - 0.8)),
            h - 0.01,
            float(rng.uniform(-d / 2 + 0.8, d / 2 - 0.8)),
        ]
        colour = random_colour(rng, sat=(0.0, 0.3), val=(0.9, 1.0))
        lights.append(
            {
                "kind": "ceiling",
                "position": pos,
                "target": [pos[0], 0.0, pos[2]],
                "size": size,
                "radiance": [float(c * gain) for c in colour],
            }
        )
    scene["area_lights"] = lights
    return scene


def _sample_car(rng) -> dict:
    """A car-like body from rounded boxes: body, cabin, four wheels with rims."""
    length, width = float(rng.uniform(3.6, 4.4)), float(rng.uniform(1.6, 1.85))
    wheel = float(rng.uniform(0.3, 0.36))
    return {
        "shape": "car",
        "yaw": float(rng.uniform(0, 2 * math.pi)),
        "support": 0.0,
        "length": length,
        "width": width,
        "wheel_radius": wheel,
        "clearance": float(wheel * rng.uniform(0.45, 0.65)),
        "body_height": float(rng.uniform(0.5, 0.7)),
        "body_exponents": [float(rng.uniform(0.2, 0.35)), float(rng.uniform(0.25, 0.45))],
        "cabin": {
            "length": float(length * rng.uniform(0.42, 0.6)),
            "height": float(rng.uniform(0.38, 0.5)),
            "offset": float(length * rng.uniform(-0.12, 0.0)),
            "exponents": [float(rng.uniform(0.35, 0.6)), float(rng.uniform(0.4, 0.7))],
        },
    }


# --- materials ------------------------------------------------------------------------


def _dress(rng, scene: dict) -> None:
    """Draw every material of `scene` from its slot's role (in place)."""
    stage = scene["stage"]
    if stage["type"] == "sweep":
        stage["material"] = _material(rng, "backdrop")
        arc = math.pi / 2 * stage["radius"]
        profile = stage["floor_depth"] + arc + stage["height"] - stage["radius"]
        _fit_texture(rng, stage["material"], stage["width"], profile)
    elif stage["type"] == "floor":
        stage["material"] = _material(rng, "floor")
        _fit_texture(rng, stage["material"], 2 * stage["size"], 2 * stage["size"])
        if "wall_z" in stage:
            stage["wall_material"] = _material(rng, "wall")
            _fit_texture(rng, stage["wall_material"], 20.0, 5.0)
    else:
        w, h, d = stage["size"]
        for key, role in ROOM_SLOTS.items():
            stage[key] = _material(rng, role)
        _fit_texture(rng, stage["floor_material"], w, d)
        _fit_texture(rng, stage["wall_material"], max(w, d), h)
        _fit_texture(rng, stage["ceiling_material"], w, d)
    glass = False
    for obj in scene["objects"]:
        for key, role in SLOTS.get(obj["shape"], {"material": "product"}).items():
            obj[key] = _material(rng, role, obj["shape"])
            glass |= "dielectric" in obj[key]["type"]
    scene["max_depth"] = scene["base_depth"] + int(glass)


def _lambertian_everywhere(rng, scene: dict) -> None:
    """Every material of `scene` made diffuse, keeping its colours (in place)."""
    for holder in (scene["stage"], *scene["objects"]):
        for key, value in list(holder.items()):
            if key.endswith("material") and isinstance(value, dict):
                holder[key] = lambertian(rng, value)
    scene["max_depth"] = scene["base_depth"]


def _orbs(rng, scene: dict) -> list:
    x0, x1, z0, z1, _, h = scene["bounds"]
    centre = np.mean([o["position"] for o in scene["objects"]], axis=0)[[0, 2]]
    return procedural.sample_orbs(rng, (x0, x1, z0, z1), (0.15, h - 0.3), scene["objects"], centre)


def sample_scene(rng: np.random.Generator, family: str) -> dict:
    """Every random choice of one scene of a photographic `family` (cameras come later)."""
    rng = family_rng(rng, family)
    base = family
    if family == "diffuse":
        base = "products" if rng.uniform() < 0.5 else "rooms"
    scene = _sample_products(rng) if base == "products" else _sample_rooms(rng)
    scene.update(kind=family, family=family)
    if family == "diffuse":
        scene["base"] = base
    _dress(rng, scene)
    if family == "diffuse":
        _lambertian_everywhere(rng, scene)
    scene["orbs"] = _orbs(rng, scene) if scene["objects"] else []
    return scene


def restyle(rng: np.random.Generator, layout: dict) -> dict:
    """`layout` with new materials and orbs (geometry, environment and lights stay)."""
    scene = copy.deepcopy(layout)
    _dress(rng, scene)
    if scene["family"] == "diffuse":
        _lambertian_everywhere(rng, scene)
    scene["orbs"] = _orbs(rng, scene)
    return scene


# --- Mitsuba shapes -------------------------------------------------------------------


def _mesh(mi, name, verts, faces, uv, bsdf, yaw, position):
    verts = verts @ meshes.rotation_y(yaw).T + np.asarray(position, dtype=float)
    return meshes.mitsuba_mesh(mi, name, verts, faces, uv, bsdf)


def object_shapes(mi, obj: dict, name: str) -> dict:
    """Mitsuba shapes of the photographic families' own object shapes."""
    T = mi.ScalarTransform4f
    x, y, z = obj["position"]
    shape = obj["shape"]
    if shape == "rounded":
        ex, ey, ez = obj["extent"]
        verts, faces, uv = meshes.superellipsoid(obj["extent"], *obj["exponents"])
        bsdf = material_dict(mi, obj["material"])
        return {name: _mesh(mi, name, verts, faces, uv, bsdf, obj["yaw"], [x, y + ey, z])}
    if shape == "counter":
        ex, ey, ez = obj["extent"]
        top, over = obj["height"], obj["overhang"]
        body_h = (top - ey) / 2
        return {
            f"{name}_top": {
                "type": "cube",
                "bsdf": material_dict(mi, obj["material"]),
                "to_world": T().translate([x, top, z]).scale([ex, ey, ez]),
            },
            f"{name}_body": {
                "type": "cube",
                "bsdf": material_dict(mi, obj["body_material"]),
                "to_world": T().translate([x, body_h, z]).scale([ex - over, body_h, ez - over]),
            },
        }
    if shape == "car":
        return _car_shapes(mi, obj, name)
    shapes = procedural._object_shapes(mi, obj, name)
    if obj.get("style") in ("bowl", "bottle"):  # close the vase's bottom
        shapes[f"{name}_base"] = {
            "type": "disk",
            "bsdf": material_dict(mi, obj["material"]),
            "to_world": T()
            .translate([x, y + 0.002, z])
            .rotate([1, 0, 0], -90)
            .scale(obj["radii"][0]),
        }
    return shapes


def _car_shapes(mi, car: dict, name: str) -> dict:
    T = mi.ScalarTransform4f
    x, y, z = car["position"]
    yaw = car["yaw"]
    L, W, r = car["length"], car["width"], car["wheel_radius"]
    bottom, bh = car["clearance"], car["body_height"]
    cab = car["cabin"]
    shapes = {}
    verts, faces, uv = meshes.superellipsoid([L / 2, bh / 2, W / 2], *car["body_exponents"])
    rot = meshes.rotation_y(yaw)
    base = np.array([x, y, z])

    def world(p):
        return base + rot @ np.asarray(p, dtype=float)

    paint = material_dict(mi, car["material"])
    shapes[f"{name}_body"] = _mesh(
        mi, f"{name}_body", verts, faces, uv, paint, yaw, world([0, bottom + bh / 2, 0])
    )
    verts, faces, uv = meshes.superellipsoid(
        [cab["length"] / 2, cab["height"] / 2, W * 0.42], *cab["exponents"]
    )
    glass = material_dict(mi, car["glass_material"])
    centre = world([cab["offset"], bottom + bh * 0.8 + cab["height"] / 2, 0])
    shapes[f"{name}_cabin"] = _mesh(mi, f"{name}_cabin", verts, faces, uv, glass, yaw, centre)
    tyre = material_dict(mi, car["tyre_material"])
    rim = material_dict(mi, car["rim_material"])
    for i, (sx, sz) in enumerate(((-1, -1), (-1, 1), (1, -1), (1, 1))):
        cx, cz = sx * L * 0.32, sz * (W / 2 - 0.12)
        shapes[f"{name}_wheel{i}"] = {
            "type": "cylinder",
            "p0": world([cx, r, cz - 0.11]).tolist(),
            "p1": world([cx, r, cz + 0.11]).tolist(),
            "radius": r,
            "bsdf": tyre,
        }
        # The tyre's sidewall closes the wheel's outer end; the rim sits just outside it.
        yaw_deg = math.degrees(yaw) + (0 if sz > 0 else 180)
        for part, radius, out, bsdf in (("side", r, 0.110, tyre), ("rim", 0.62 * r, 0.112, rim)):
            shapes[f"{name}_{part}{i}"] = {
                "type": "disk",
                "bsdf": bsdf,
                "to_world": T()
                .translate(world([cx, r, cz + sz * out]).tolist())
                .rotate([0, 1, 0], yaw_deg)
                .scale(radius),
            }
    return shapes


def stage_shapes(mi, scene: dict) -> dict:
    """Mitsuba shapes of the stage: a sweep, a floor (and back wall), or a room with
    its window emitters."""
    T = mi.ScalarTransform4f
    stage = scene["stage"]
    if stage["type"] == "sweep":
        verts, faces, uv = meshes.sweep(
            stage["width"], stage["floor_depth"], stage["radius"], stage["height"]
        )
        bsdf = material_dict(mi, stage["material"])
        return {"sweep": meshes.mitsuba_mesh(mi, "sweep", verts, faces, uv, bsdf)}
    if stage["type"] == "floor":
        s = stage["size"]
        shapes = {
            "floor": {
                "type": "rectangle",
                "bsdf": material_dict(mi, stage["material"]),
                "to_world": T().rotate([1, 0, 0], -90).scale(s),
            }
        }
        if "wall_z" in stage:
            shapes["back_wall"] = {
                "type": "rectangle",
                "bsdf": material_dict(mi, stage["wall_material"]),
                "to_world": T().translate([0, 2.5, stage["wall_z"]]).scale([10, 2.5, 1]),
            }
        return shapes
    room = {k: v for k, v in stage.items() if k != "type"}
    shapes = procedural._room_shapes(mi, room)
    w, h, d = stage["size"]
    # Wall i: centre, yaw (its rectangle faces into the room), length; as in _room_shapes.
    walls = (
        ([w / 2, 0, 0], -90, d),
        ([-w / 2, 0, 0], 90, d),
        ([0, 0, d / 2], 180, w),
        ([0, 0, -d / 2], 0, w),
    )
    frame = material_dict(mi, stage["frame_material"])
    for i, win in enumerate(stage["windows"]):
        shapes.update(_window_shapes(mi, win, walls[win["wall"]], frame, f"window{i}"))
    return shapes


def _window_shapes(mi, win: dict, wall, frame: dict, name: str) -> dict:
    """A window: an emitter of daylight on the wall behind a frame and glazing bars that
    stand 5 cm out of the wall (and cast their shadows into the room)."""
    T = mi.ScalarTransform4f
    pos, yaw, _ = wall
    rot = meshes.rotation_y(math.radians(yaw))
    inward, along = rot @ [0.0, 0.0, 1.0], rot @ [1.0, 0.0, 0.0]
    width, height = win["size"]
    centre = np.array(pos, dtype=float) + along * win["offset"]
    centre[1] = win["sill"] + height / 2

    def box(offset_along, offset_up, half_along, half_up, depth):
        c = centre + along * offset_along + inward * depth + [0.0, offset_up, 0.0]
        return T().translate(c.tolist()).rotate([0, 1, 0], yaw).scale([half_along, half_up, depth])

    shapes = {
        name: {
            "type": "rectangle",
            "to_world": box(0.0, 0.0, width / 2, height / 2, 0.005),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": win["radiance"]}},
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
        }
    }
    nx, ny = win["panes"]
    bar, depth = win["bar"], 0.025
    for k in range(nx + 1):
        shapes[f"{name}_v{k}"] = {
            "type": "cube",
            "bsdf": frame,
            "to_world": box(-width / 2 + k * width / nx, 0.0, bar / 2, height / 2 + bar / 2, depth),
        }
    for k in range(ny + 1):
        shapes[f"{name}_h{k}"] = {
            "type": "cube",
            "bsdf": frame,
            "to_world": box(
                0.0, -height / 2 + k * height / ny, width / 2 + bar / 2, bar / 2, depth
            ),
        }
    return shapes
