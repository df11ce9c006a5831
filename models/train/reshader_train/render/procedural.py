"""Procedural scenes: rooms and outdoor tabletops at one global scale (y up, units ~metres).

`sample_scene` draws every random choice into a JSON-able dict (stored in meta.json);
`build_scene` turns that dict into a Mitsuba scene. Rooms are 3.5-8 units across and
2.5-3.5 high; the camera stands 1-4.5 units from the object it looks at. The
photographic families (products, rooms, diffuse) live in `photo`.
"""

import copy
import math

import numpy as np

from . import meshes
from .materials import OPAQUE, material_dict, random_colour, sample_material
from .textures import make_environment

SHAPES = ("sphere", "cube", "cylinder", "torus", "blob", "vase")
# Scene families. "mixed" is everything the generator makes. "highlights" narrows it to
# what a small network can learn from a few hundred examples: curved glossy objects on
# a tabletop under a sun and coloured orbs, seen from close by. Mirrors reflecting unseen
# surroundings and glass are left out; their change between cameras is mostly unknowable
# from one photo.
# "studio" is "highlights" under a dim uniform environment: the sun and the orbs light the
# scene, so that what changes between cameras is mostly their highlights, which a network
# can predict from the photo, rather than reflections of a sky it cannot see.
# "products", "rooms" and "diffuse" are the photographic families of `photo`: product
# shots and rooms of the materials people photograph under studio and interior lighting,
# and the same scenes with every material Lambertian.
FAMILIES = ("mixed", "highlights", "studio", "products", "rooms", "diffuse")
PHOTO_FAMILIES = ("products", "rooms", "diffuse")
# Objects that others stand on.
SUPPORTS = ("table", "counter")
GLOSSY_FAMILIES = ("highlights", "studio")
GLOSSY = ("plastic", "roughplastic", "principled", "roughconductor")
CURVED = ("sphere", "cylinder", "torus", "blob", "vase")
GLOSSY_GROUNDS = ("diffuse", "roughplastic")
ROOM_SURFACES = ("diffuse", "roughplastic", "principled")


def check_family(family: str) -> None:
    if not isinstance(family, str) or family not in FAMILIES:
        raise ValueError(
            f"unknown procedural family {family!r}: expected one of " + ", ".join(FAMILIES)
        )


def _sample_sky(rng: np.random.Generator, intensity: tuple[float, float], sun_p=0.6) -> dict:
    sun = rng.uniform() < sun_p
    return {
        "zenith": random_colour(rng, sat=(0.2, 0.8), val=(0.4, 1.0)),
        "horizon": random_colour(rng, sat=(0.0, 0.4), val=(0.6, 1.0)),
        "ground": random_colour(rng, sat=(0.0, 0.5), val=(0.1, 0.5)),
        "gradient_power": float(rng.uniform(0.3, 2.0)),
        "intensity": float(rng.uniform(*intensity)),
        "sun_elevation": float(rng.uniform(0.1, 1.3)),
        "sun_azimuth": float(rng.uniform(0, 2 * math.pi)),
        "sun_size": float(rng.uniform(0.03, 0.12)),
        "sun_radiance": [
            c * float(rng.uniform(50, 300)) * sun
            for c in random_colour(rng, sat=(0.0, 0.3), val=(0.9, 1.0))
        ],
    }


def _sample_object(rng: np.random.Generator, support: float, family: str) -> dict:
    highlights = family in GLOSSY_FAMILIES
    shape = str(rng.choice(CURVED if highlights else SHAPES))
    size = float(rng.uniform(0.15, 0.6))
    obj = {
        "shape": shape,
        "size": size,
        "yaw": float(rng.uniform(0, 2 * math.pi)),
        "support": support,
        "material": sample_material(rng, GLOSSY if highlights else None),
    }
    if shape == "cube":
        obj["extent"] = [float(v) for v in size * rng.uniform(0.4, 1.0, 3)]
    elif shape == "cylinder":
        obj["height"] = float(size * rng.uniform(0.8, 3.0))
    elif shape == "torus":
        obj["minor"] = float(size * rng.uniform(0.15, 0.4))
        obj["tilt"] = float(rng.choice([0.0, math.pi / 2]))
    elif shape == "blob":
        obj["amplitude"] = float(rng.uniform(0.05, 0.3))
        obj["seed"] = int(rng.integers(2**31))
    elif shape == "vase":
        obj["height"] = float(size * rng.uniform(1.5, 3.5))
        obj["radii"] = [float(v) for v in size * rng.uniform(0.3, 1.0, int(rng.integers(3, 6)))]
    return obj


def _radius(obj: dict) -> float:
    """Footprint radius used to keep objects, orbs and cameras apart."""
    if obj["shape"] in ("cube", "table", "rounded", "counter"):
        return math.hypot(obj["extent"][0], obj["extent"][2])
    if obj["shape"] == "car":
        return math.hypot(obj["length"] / 2, obj["width"] / 2)
    if obj["shape"] == "torus":
        return obj["size"] + obj["minor"]
    if obj["shape"] == "vase":
        return max(obj["radii"])
    return obj["size"] * (1.3 if obj["shape"] == "blob" else 1.0)


def _height(obj: dict) -> float:
    shape = obj["shape"]
    if shape in SUPPORTS:
        return obj["height"] + obj["extent"][1]
    if shape in ("cube", "rounded"):
        return 2 * obj["extent"][1]
    if shape == "car":
        cabin = obj["cabin"]
        return obj["clearance"] + 0.8 * obj["body_height"] + cabin["height"]
    if shape in ("cylinder", "vase"):
        return obj["height"]
    if shape == "torus":
        return 2 * (obj["size"] + obj["minor"]) if obj["tilt"] else 2 * obj["minor"]
    return 2 * obj["size"] * (1.3 if shape == "blob" else 1.0)


def _place(rng, objects: list, obj: dict, centre, spread: float, bounds) -> bool:
    """Put `obj` at a free spot within `spread` of `centre` inside bounds (x0, x1, z0, z1)."""
    r = _radius(obj)
    for _ in range(40):
        a, d = rng.uniform(0, 2 * math.pi), spread * math.sqrt(rng.uniform())
        x, z = centre[0] + d * math.cos(a), centre[1] + d * math.sin(a)
        if not (bounds[0] + r < x < bounds[1] - r and bounds[2] + r < z < bounds[3] - r):
            continue
        # Objects standing on the table may overlap the table's footprint, nothing else.
        others = [o for o in objects if not (obj["support"] > 0 and o["shape"] in SUPPORTS)]
        if all(
            math.hypot(x - o["position"][0], z - o["position"][2]) > r + _radius(o) + 0.05
            for o in others
        ):
            obj["position"] = [float(x), obj["support"], float(z)]
            objects.append(obj)
            return True
    return False


def sample_scene(rng: np.random.Generator, family: str = "mixed") -> dict:
    """Every random choice of one procedural scene of `family` (cameras are chosen later)."""
    check_family(family)
    if family in PHOTO_FAMILIES:
        from . import photo

        return photo.sample_scene(rng, family)
    highlights = family in GLOSSY_FAMILIES
    kind = "room" if rng.uniform() < (0.0 if highlights else 0.7) else "tabletop"
    depths = (3, 5) if highlights else (4, 8)
    scene: dict = {"kind": kind, "max_depth": int(rng.integers(*depths))}
    if highlights:
        scene["family"] = family
    if kind == "room":
        w, d, h = rng.uniform(3.5, 8.0), rng.uniform(3.5, 8.0), rng.uniform(2.5, 3.5)
        scene["room"] = {
            "size": [float(w), float(h), float(d)],
            # Openings let the sky in; at least one of the walls or ceiling is open half the time.
            "walls": [bool(rng.uniform() < 0.85) for _ in range(4)],
            "ceiling": bool(rng.uniform() < 0.7),
            **_room_materials(rng),
        }
        bounds = (-w / 2, w / 2, -d / 2, d / 2)
        scene["sky"] = _sample_sky(rng, (0.3, 2.0))
    else:
        scene["ground_material"] = sample_material(rng, GLOSSY_GROUNDS if highlights else OPAQUE)
        bounds = (-10.0, 10.0, -10.0, 10.0)
        h = 6.0
        scene["sky"] = _sample_sky(rng, (0.5, 3.0), 1.0 if highlights else 0.6)
        if family == "studio":
            grey = scene["sky"]["horizon"]
            intensity = float(rng.uniform(0.02, 0.1))
            scene["sky"].update(zenith=grey, ground=grey, intensity=intensity)
    scene["bounds"] = [float(v) for v in bounds] + [0.0, float(h)]

    cx = rng.uniform(bounds[0] * 0.4, bounds[1] * 0.4) if kind == "room" else 0.0
    cz = rng.uniform(bounds[2] * 0.4, bounds[3] * 0.4) if kind == "room" else 0.0
    objects: list = []
    support = 0.0
    if rng.uniform() < 0.5:
        table = {
            "shape": "table",
            "yaw": 0.0,
            "support": 0.0,
            "extent": [float(rng.uniform(0.5, 1.0)), 0.03, float(rng.uniform(0.35, 0.6))],
            "height": float(rng.uniform(0.65, 0.9)),
            "material": sample_material(rng, OPAQUE),
        }
        if _place(rng, objects, table, (cx, cz), 0.5, bounds):
            support = table["height"] + 0.03
    for _ in range(int(rng.integers(3, 9))):
        on_table = support > 0 and rng.uniform() < 0.5
        obj = _sample_object(rng, support if on_table else 0.0, family)
        if on_table:
            t = objects[0]
            tb = (
                t["position"][0] - t["extent"][0],
                t["position"][0] + t["extent"][0],
                t["position"][2] - t["extent"][2],
                t["position"][2] + t["extent"][2],
            )
            _place(rng, objects, obj, (t["position"][0], t["position"][2]), 0.6, tb)
        else:
            _place(rng, objects, obj, (cx, cz), 2.0, bounds)
    scene["objects"] = objects

    scene["area_lights"] = []
    for _ in range(int(rng.integers(0 if kind == "tabletop" else 1, 3))):
        size = [float(v) for v in rng.uniform(0.2, 1.0, 2)]
        on_ceiling = kind == "room" and scene["room"]["ceiling"] and rng.uniform() < 0.7
        if on_ceiling:
            pos = [
                float(rng.uniform(bounds[0] + 0.6, bounds[1] - 0.6)),
                float(h - 0.01),
                float(rng.uniform(bounds[2] + 0.6, bounds[3] - 0.6)),
            ]
            target = [pos[0], 0.0, pos[2]]
        else:
            a = rng.uniform(0, 2 * math.pi)
            dist = rng.uniform(1.5, 3.0)
            pos = [
                float(cx + dist * math.cos(a)),
                float(rng.uniform(1.5, h - 0.3)),
                float(cz + dist * math.sin(a)),
            ]
            target = [float(cx), 0.5, float(cz)]
        scene["area_lights"].append(
            {
                "position": pos,
                "target": target,
                "size": size,
                "radiance": [
                    c * float(rng.uniform(3, 15))
                    for c in random_colour(rng, sat=(0.0, 0.3), val=(0.9, 1.0))
                ],
            }
        )

    scene["orbs"] = sample_orbs(rng, bounds, (0.15, h - 0.3), objects, (cx, cz))
    return scene


def _room_materials(rng: np.random.Generator) -> dict:
    return {
        "floor_material": sample_material(rng, ROOM_SURFACES),
        "wall_material": sample_material(rng, ROOM_SURFACES),
        "ceiling_material": sample_material(rng, ("diffuse",)),
    }


def restyle(rng: np.random.Generator, layout: dict) -> dict:
    """`layout` with new materials and orbs, as the paper re-draws the materials of its fixed
    scenes for every pair: geometry, sky and area lights stay."""
    if layout.get("family") in PHOTO_FAMILIES:
        from . import photo

        return photo.restyle(rng, layout)
    scene = copy.deepcopy(layout)
    highlights = scene.get("family") in GLOSSY_FAMILIES
    for obj in scene["objects"]:
        table = obj["shape"] == "table"
        obj["material"] = sample_material(rng, OPAQUE if table else GLOSSY if highlights else None)
    if "ground_material" in scene:
        scene["ground_material"] = sample_material(rng, GLOSSY_GROUNDS if highlights else OPAQUE)
    if "room" in scene:
        scene["room"].update(_room_materials(rng))
    x0, x1, z0, z1, _, h = scene["bounds"]
    centre = np.mean([o["position"] for o in scene["objects"]], axis=0)[[0, 2]]
    scene["orbs"] = sample_orbs(rng, (x0, x1, z0, z1), (0.15, h - 0.3), scene["objects"], centre)
    return scene


def sample_orbs(rng, bounds, heights, objects, centre) -> list:
    """2-6 small coloured emissive spheres in free space near `centre`."""
    orbs = []
    for _ in range(int(rng.integers(2, 7))):
        radius = float(rng.uniform(0.03, 0.12))
        for _ in range(30):
            p = [
                float(centre[0] + rng.uniform(-2.5, 2.5)),
                float(rng.uniform(*heights)),
                float(centre[1] + rng.uniform(-2.5, 2.5)),
            ]
            inside = (
                bounds[0] + radius < p[0] < bounds[1] - radius
                and bounds[2] + radius < p[2] < bounds[3] - radius
            )
            free = all(
                math.dist(p, o["position"]) > radius + _radius(o) + 0.05
                or p[1] > o["position"][1] + _height(o) + radius + 0.05
                for o in objects
            ) and all(math.dist(p, q["position"]) > radius + q["radius"] for q in orbs)
            if inside and free:
                hue = random_colour(rng, sat=(0.6, 1.0), val=(1.0, 1.0))
                orbs.append(
                    {
                        "position": p,
                        "radius": radius,
                        "radiance": [c * float(rng.uniform(5, 40)) for c in hue],
                    }
                )
                break
    return orbs


def _object_shapes(mi, obj: dict, name: str) -> dict:
    """Mitsuba shapes (by name) for one object."""
    bsdf = material_dict(mi, obj["material"])
    x, y, z = obj["position"]
    T = mi.ScalarTransform4f
    shape = obj["shape"]
    if shape == "sphere":
        return {
            name: {
                "type": "sphere",
                "center": [x, y + obj["size"], z],
                "radius": obj["size"],
                "bsdf": bsdf,
            }
        }
    if shape == "cube":
        ex, ey, ez = obj["extent"]
        to_world = (
            T()
            .translate([x, y + ey, z])
            .rotate([0, 1, 0], math.degrees(obj["yaw"]))
            .scale([ex, ey, ez])
        )
        return {name: {"type": "cube", "to_world": to_world, "bsdf": bsdf}}
    if shape == "table":
        ex, ey, ez = obj["extent"]
        top = obj["height"]
        parts = {
            f"{name}_top": {
                "type": "cube",
                "bsdf": bsdf,
                "to_world": T().translate([x, top, z]).scale([ex, ey, ez]),
            }
        }
        for i, (sx, sz) in enumerate(((-1, -1), (-1, 1), (1, -1), (1, 1))):
            parts[f"{name}_leg{i}"] = {
                "type": "cube",
                "bsdf": bsdf,
                "to_world": T()
                .translate([x + sx * (ex - 0.05), top / 2, z + sz * (ez - 0.05)])
                .scale([0.03, top / 2, 0.03]),
            }
        return parts
    if shape == "cylinder":
        r, hgt = obj["size"] * 0.5, obj["height"]
        return {
            name: {
                "type": "cylinder",
                "p0": [x, y, z],
                "p1": [x, y + hgt, z],
                "radius": r,
                "bsdf": bsdf,
            },
            f"{name}_cap": {
                "type": "disk",
                "bsdf": bsdf,
                "to_world": T().translate([x, y + hgt, z]).rotate([1, 0, 0], -90).scale(r),
            },
        }
    if shape == "torus":
        verts, faces, uv = meshes.torus(obj["size"], obj["minor"])
    elif shape == "blob":
        verts, faces, uv = meshes.blob(obj["size"], obj["amplitude"], obj["seed"])
    else:
        verts, faces, uv = meshes.vase(obj["height"], obj["radii"])
    rot = meshes.rotation_y(obj["yaw"]) @ meshes.rotation_x(obj.get("tilt", 0.0))
    verts = verts @ rot.T
    verts = verts + np.array([x, y - verts[:, 1].min(), z])
    return {name: meshes.mitsuba_mesh(mi, name, verts, faces, uv, bsdf)}


def _room_shapes(mi, room: dict) -> dict:
    w, h, d = room["size"]
    T = mi.ScalarTransform4f
    shapes = {
        "floor": {
            "type": "rectangle",
            "bsdf": material_dict(mi, room["floor_material"]),
            "to_world": T().rotate([1, 0, 0], -90).scale([w / 2, d / 2, 1]),
        }
    }
    if room["ceiling"]:
        shapes["ceiling"] = {
            "type": "rectangle",
            "bsdf": material_dict(mi, room["ceiling_material"]),
            "to_world": T().translate([0, h, 0]).rotate([1, 0, 0], 90).scale([w / 2, d / 2, 1]),
        }
    walls = (
        ([w / 2, h / 2, 0], -90, d),
        ([-w / 2, h / 2, 0], 90, d),
        ([0, h / 2, d / 2], 180, w),
        ([0, h / 2, -d / 2], 0, w),
    )
    wall_bsdf = material_dict(mi, room["wall_material"])
    for i, ((pos, yaw, length), present) in enumerate(zip(walls, room["walls"], strict=True)):
        if present:
            shapes[f"wall{i}"] = {
                "type": "rectangle",
                "bsdf": wall_bsdf,
                "to_world": T().translate(pos).rotate([0, 1, 0], yaw).scale([length / 2, h / 2, 1]),
            }
    return shapes


def light_shapes(mi, scene: dict) -> dict:
    """Area lights and orbs (shared with user scenes)."""
    shapes = {}
    for i, light in enumerate(scene.get("area_lights", [])):
        shapes[f"area_light{i}"] = {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f()
            .look_at(origin=light["position"], target=light["target"], up=[0, 1, 0.01])
            .scale([light["size"][0] / 2, light["size"][1] / 2, 1]),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": light["radiance"]}},
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
        }
    for i, orb in enumerate(scene.get("orbs", [])):
        shapes[f"orb{i}"] = {
            "type": "sphere",
            "center": orb["position"],
            "radius": orb["radius"],
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": orb["radiance"]}},
        }
    return shapes


def build_scene(mi, scene: dict):
    """The Mitsuba scene for parameters from `sample_scene`."""
    d: dict = {
        "type": "scene",
        "sky": {"type": "envmap", "bitmap": mi.Bitmap(make_environment(scene["sky"]))},
    }
    object_shapes = _object_shapes
    if "stage" in scene:
        from . import photo

        d.update(photo.stage_shapes(mi, scene))
        object_shapes = photo.object_shapes
    elif scene["kind"] == "room":
        d.update(_room_shapes(mi, scene["room"]))
    else:
        d["ground"] = {
            "type": "rectangle",
            "bsdf": material_dict(mi, scene["ground_material"]),
            "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(20),
        }
    for i, obj in enumerate(scene["objects"]):
        d.update(object_shapes(mi, obj, f"object{i}"))
    d.update(light_shapes(mi, scene))
    # The scene loader orders the shapes it instantiates, and with them the emitters,
    # differently from one load to the next, and the emitter order decides which light
    # each random number samples. Children handed over as objects keep the dictionary's
    # order, so (seed, index) renders the same image every time.
    bsdfs: dict = {}
    return mi.load_dict({k: v if k == "type" else _load_child(mi, v, bsdfs) for k, v in d.items()})


def _load_child(mi, child, bsdfs: dict):
    """A scene child as an object. A material dict shared by several shapes is loaded once
    (`bsdfs`, keyed by identity): its bitmap tensors cannot be handed to two loads."""
    if not isinstance(child, dict):
        return child
    bsdf = child.get("bsdf")
    if isinstance(bsdf, dict):
        if id(bsdf) not in bsdfs:
            bsdfs[id(bsdf)] = mi.load_dict(bsdf, parallel=False)
        child = {**child, "bsdf": bsdfs[id(bsdf)]}
    return mi.load_dict(child, parallel=False)
