"""Random materials: JSON-able parameters and their Mitsuba dictionaries."""

import colorsys

import numpy as np

from .textures import make_texture, sample_texture

# (type, weight) of the material families the issue asks for.
FAMILIES = (
    ("diffuse", 0.18),
    ("plastic", 0.10),
    ("roughplastic", 0.20),
    ("roughconductor", 0.20),
    ("principled", 0.22),
    ("dielectric", 0.05),
    ("roughdielectric", 0.05),
)
CONDUCTORS = ("Ag", "Al", "Au", "Be", "Cr", "Cu", "Hg", "Ir", "Ni_palik", "Rh", "TiN", "W")
OPAQUE = tuple(name for name, _ in FAMILIES if "dielectric" not in name)
# Metals of product photographs: chrome, copper, gold, silver, aluminium, nickel, and
# steel, which Mitsuba has no table for (iron's complex index of refraction at the RGB
# wavelengths, eta + i k).
PHOTO_METALS = ("Cr", "Cu", "Au", "Ag", "Al", "Ni_palik", "steel")
STEEL = {"eta": [2.87, 2.95, 2.65], "k": [3.18, 2.93, 2.81]}
# What photographed things are made of, as `sample_recipe` builds them from Mitsuba's
# plugins: a clear coat over a diffuse base is `plastic` (smooth) or `roughplastic`,
# car paint is `principled` with its clear-coat lobe, brushed metal an anisotropic
# `roughconductor`.
RECIPES = (
    "varnished_wood",
    "car_paint",
    "polished_stone",
    "honed_stone",
    "polished_metal",
    "brushed_metal",
    "glazed_ceramic",
    "plastic",
    "glass",
    "matte",
    "paint",
    "paper",
    "acrylic",
    "rubber",
    "tinted_glass",
    "wood_floor",
    "glossy_tiles",
    "concrete",
    "carpet",
)


def random_colour(rng: np.random.Generator, sat=(0.0, 0.85), val=(0.15, 0.9)) -> list[float]:
    """A linear RGB colour drawn in HSV space (gamma 2.2 to linearise the value)."""
    h, s, v = rng.uniform(), rng.uniform(*sat), rng.uniform(*val)
    return [float(c) ** 2.2 for c in colorsys.hsv_to_rgb(h, s, v)]


def _sample_albedo(rng: np.random.Generator, texture_prob: float) -> dict:
    base = random_colour(rng)
    if rng.uniform() >= texture_prob:
        return {"rgb": base}
    other = random_colour(rng) if rng.uniform() < 0.5 else [c * rng.uniform(0.2, 0.7) for c in base]
    return {"texture": sample_texture(rng), "lo": other, "hi": base}


def _sample_roughness(rng: np.random.Generator, lo: float, hi: float, texture_prob: float):
    a = float(rng.uniform(lo, hi))
    if rng.uniform() >= texture_prob:
        return {"value": a}
    b = float(np.clip(a + rng.uniform(-0.3, 0.3), lo, hi))
    return {"texture": sample_texture(rng), "lo": min(a, b), "hi": max(a, b)}


def sample_material(rng: np.random.Generator, families=None) -> dict:
    """Random material parameters; `families` restricts the types drawn."""
    names = [n for n, _ in FAMILIES if families is None or n in families]
    weights = np.array([w for n, w in FAMILIES if n in names])
    kind = str(rng.choice(names, p=weights / weights.sum()))
    m: dict = {"type": kind}
    if kind == "diffuse":
        m["albedo"] = _sample_albedo(rng, 0.6)
    elif kind in ("plastic", "roughplastic"):
        m["albedo"] = _sample_albedo(rng, 0.6)
        m["ior"] = float(rng.uniform(1.3, 1.7))
        if kind == "roughplastic":
            m["alpha"] = float(rng.uniform(0.03, 0.4))
    elif kind == "roughconductor":
        m["conductor"] = str(rng.choice(CONDUCTORS))
        m["tint"] = random_colour(rng, sat=(0.0, 0.5), val=(0.6, 1.0))
        m["alpha"] = _sample_roughness(rng, 0.01, 0.5, 0.4)
    elif kind == "principled":
        m["albedo"] = _sample_albedo(rng, 0.6)
        m["roughness"] = _sample_roughness(rng, 0.03, 0.9, 0.4)
        m["metallic"] = float(rng.choice([0.0, rng.uniform(), 1.0]))
        m["specular"] = float(rng.uniform(0.2, 1.0))
        m["clearcoat"] = float(rng.choice([0.0, rng.uniform()]))
    else:
        m["ior"] = float(rng.uniform(1.3, 1.8))
        m["tint"] = random_colour(rng, sat=(0.0, 0.4), val=(0.8, 1.0))
        if kind == "roughdielectric":
            m["alpha"] = float(rng.uniform(0.02, 0.3))
    return m


def _wood_colours(rng: np.random.Generator) -> tuple[list[float], list[float]]:
    """Light and dark tones of one wood (linear RGB)."""
    hue = rng.uniform(0.03, 0.11)  # oranges to yellow-browns
    s, v = rng.uniform(0.4, 0.8), rng.uniform(0.35, 0.85)
    hi = [float(c) ** 2.2 for c in colorsys.hsv_to_rgb(hue, s, v)]
    return [c * float(rng.uniform(0.25, 0.6)) for c in hi], hi


def _stone_albedo(rng: np.random.Generator) -> dict:
    kind = str(rng.choice(["marble", "granite"]))
    light = random_colour(rng, sat=(0.0, 0.25), val=(0.55, 0.95))
    dark = random_colour(rng, sat=(0.0, 0.4), val=(0.05, 0.4))
    lo, hi = (dark, light) if rng.uniform() < 0.65 else (light, dark)
    return {"texture": sample_texture(rng, (kind,)), "lo": lo, "hi": hi}


def sample_recipe(rng: np.random.Generator, recipe: str) -> dict:
    """Random parameters of one of `RECIPES` (a `material_dict` input that names its recipe)."""
    if recipe == "varnished_wood" or recipe == "wood_floor":
        lo, hi = _wood_colours(rng)
        kinds = ("planks",) if recipe == "wood_floor" else ("wood",)
        albedo = {"texture": sample_texture(rng, kinds), "lo": lo, "hi": hi}
        if rng.uniform() < 0.6:  # gloss varnish
            m = {"type": "plastic", "albedo": albedo, "ior": float(rng.uniform(1.45, 1.6))}
        else:  # satin varnish
            m = {"type": "roughplastic", "albedo": albedo, "ior": float(rng.uniform(1.45, 1.6))}
            m["alpha"] = float(rng.uniform(0.04, 0.15))
    elif recipe == "car_paint":
        m = {
            "type": "principled",
            "albedo": {"rgb": random_colour(rng, sat=(0.3, 1.0), val=(0.1, 0.9))},
            "roughness": {"value": float(rng.uniform(0.2, 0.5))},
            "metallic": float(rng.choice([0.0, rng.uniform(0.3, 0.9)])),
            "specular": 0.5,
            "clearcoat": 1.0,
            "clearcoat_gloss": float(rng.uniform(0.85, 1.0)),
        }
    elif recipe in ("polished_stone", "honed_stone"):
        m = {"type": "plastic", "albedo": _stone_albedo(rng), "ior": float(rng.uniform(1.5, 1.7))}
        if recipe == "honed_stone":
            m.update(type="roughplastic", alpha=float(rng.uniform(0.12, 0.35)))
    elif recipe in ("polished_metal", "brushed_metal"):
        m = {
            "type": "roughconductor",
            "conductor": str(rng.choice(PHOTO_METALS)),
            "tint": random_colour(rng, sat=(0.0, 0.1), val=(0.9, 1.0)),
        }
        if recipe == "polished_metal":
            m["alpha"] = {"value": float(np.exp(rng.uniform(np.log(0.003), np.log(0.05))))}
        elif rng.uniform() < 0.6:  # brushed along one surface direction
            m["alpha"] = {"value": float(rng.uniform(0.12, 0.35))}
            m["alpha_v"] = float(rng.uniform(0.01, 0.05))
        else:
            m["alpha"] = {"value": float(rng.uniform(0.06, 0.3))}
    elif recipe == "glazed_ceramic":
        albedo = _sample_albedo(rng, 0.25)
        if "rgb" in albedo and rng.uniform() < 0.4:
            albedo = {"rgb": random_colour(rng, sat=(0.0, 0.1), val=(0.8, 0.95))}  # white
        m = {"type": "plastic", "albedo": albedo, "ior": float(rng.uniform(1.45, 1.6))}
        if rng.uniform() < 0.3:
            m.update(type="roughplastic", alpha=float(rng.uniform(0.02, 0.08)))
    elif recipe == "plastic":
        m = sample_material(rng, ("plastic", "roughplastic"))
        if m["type"] == "roughplastic":
            m["alpha"] = float(rng.uniform(0.03, 0.3))
    elif recipe == "glass":
        m = sample_material(rng, ("dielectric", "roughdielectric"))
        m["ior"] = float(rng.uniform(1.45, 1.55))
        m["tint"] = random_colour(rng, sat=(0.0, 0.25), val=(0.9, 1.0))
    elif recipe == "matte":
        m = {"type": "diffuse", "albedo": _sample_albedo(rng, 0.5)}
    elif recipe == "paint":
        albedo = {"rgb": random_colour(rng, sat=(0.0, 0.5), val=(0.4, 0.95))}
        if rng.uniform() < 0.7:
            m = {"type": "diffuse", "albedo": albedo}
        else:  # eggshell
            m = {"type": "roughplastic", "albedo": albedo, "ior": 1.5}
            m["alpha"] = float(rng.uniform(0.25, 0.5))
    elif recipe == "paper":
        m = {"type": "diffuse", "albedo": {"rgb": random_colour(rng, sat=(0.0, 0.6))}}
    elif recipe == "acrylic":
        val = (0.02, 0.08) if rng.uniform() < 0.4 else (0.3, 0.95)  # black acrylic, often
        albedo = {"rgb": random_colour(rng, sat=(0.0, 0.8), val=val)}
        m = {"type": "plastic", "albedo": albedo, "ior": float(rng.uniform(1.45, 1.55))}
    elif recipe == "rubber":
        albedo = {"rgb": random_colour(rng, sat=(0.0, 0.2), val=(0.08, 0.2))}
        m = {"type": "roughplastic", "albedo": albedo, "ior": 1.5}
        m["alpha"] = float(rng.uniform(0.3, 0.6))
    elif recipe == "tinted_glass":  # opaque stand-in for dark car windows: a black coat
        albedo = {"rgb": random_colour(rng, sat=(0.0, 0.3), val=(0.02, 0.12))}
        m = {"type": "plastic", "albedo": albedo, "ior": 1.5}
    elif recipe == "glossy_tiles":
        albedo = _sample_albedo(rng, 1.0)
        albedo["texture"] = sample_texture(rng, ("tiles",))
        m = {"type": "plastic", "albedo": albedo, "ior": float(rng.uniform(1.45, 1.6))}
    elif recipe == "concrete":
        grey = random_colour(rng, sat=(0.0, 0.15), val=(0.3, 0.7))
        albedo = {"texture": sample_texture(rng, ("noise",)), "lo": [c * 0.7 for c in grey]}
        albedo["hi"] = grey
        m = {"type": "roughplastic", "albedo": albedo, "ior": 1.5}
        m["alpha"] = float(rng.uniform(0.15, 0.45))
    elif recipe == "carpet":
        colour = random_colour(rng, sat=(0.0, 0.7), val=(0.15, 0.7))
        albedo = {"texture": sample_texture(rng, ("noise", "stripes")), "hi": colour}
        albedo["lo"] = [c * float(rng.uniform(0.5, 0.85)) for c in colour]
        m = {"type": "diffuse", "albedo": albedo}
    else:
        raise ValueError(f"unknown material recipe {recipe!r}: expected one of {RECIPES}")
    m["recipe"] = recipe
    return m


def lambertian(rng: np.random.Generator, m: dict) -> dict:
    """A diffuse material in the colours of `m` (metals and glass get a plain colour)."""
    albedo = m.get("albedo")
    if albedo is None:
        base = m.get("tint") or random_colour(rng)
        albedo = {"rgb": [float(c) * float(rng.uniform(0.3, 0.8)) for c in base]}
    return {"type": "diffuse", "albedo": albedo, "recipe": f"diffuse {m.get('recipe', m['type'])}"}


def in_memory_bitmap(mi, image, uv_scale: float) -> dict:
    return {
        "type": "bitmap",
        "data": mi.TensorXf(image),
        "raw": True,
        "wrap_mode": "repeat",
        "to_uv": mi.ScalarTransform3f().scale(uv_scale),
    }


def material_dict(mi, m: dict, bitmap=None) -> dict:
    """Mitsuba BSDF dictionary for parameters `m` (opaque ones are two-sided).

    `bitmap(image, uv_scale)` makes the texture dictionaries (default: in memory).
    """
    bitmap = bitmap or (lambda image, uv_scale: in_memory_bitmap(mi, image, uv_scale))

    def _texture_dict(_, spec: dict):
        if "rgb" in spec:
            return {"type": "rgb", "value": spec["rgb"]}
        if "value" in spec:
            return spec["value"]
        t = spec["texture"]
        return bitmap(make_texture(t, spec["lo"], spec["hi"]), t["uv_scale"])

    kind = m["type"]
    if kind == "diffuse":
        bsdf = {"type": "diffuse", "reflectance": _texture_dict(mi, m["albedo"])}
    elif kind in ("plastic", "roughplastic"):
        bsdf = {
            "type": kind,
            "diffuse_reflectance": _texture_dict(mi, m["albedo"]),
            "int_ior": m["ior"],
        }
        if kind == "roughplastic":
            bsdf.update(distribution="ggx", alpha=m["alpha"])
    elif kind == "roughconductor":
        bsdf = {
            "type": "roughconductor",
            "distribution": "ggx",
            "specular_reflectance": {"type": "rgb", "value": m["tint"]},
        }
        if m["conductor"] == "steel":
            bsdf.update({k: {"type": "rgb", "value": v} for k, v in STEEL.items()})
        else:
            bsdf["material"] = m["conductor"]
        if "alpha_v" in m:  # anisotropic (brushed): alpha along u, alpha_v along v
            bsdf.update(alpha_u=_texture_dict(mi, m["alpha"]), alpha_v=m["alpha_v"])
        else:
            bsdf["alpha"] = _texture_dict(mi, m["alpha"])
    elif kind == "principled":
        bsdf = {
            "type": "principled",
            "base_color": _texture_dict(mi, m["albedo"]),
            "roughness": _texture_dict(mi, m["roughness"]),
            "metallic": m["metallic"],
            "specular": m["specular"],
            "clearcoat": m["clearcoat"],
        }
        if "clearcoat_gloss" in m:
            bsdf["clearcoat_gloss"] = m["clearcoat_gloss"]
    else:
        bsdf = {
            "type": kind,
            "int_ior": m["ior"],
            "specular_transmittance": {"type": "rgb", "value": m["tint"]},
        }
        if kind == "roughdielectric":
            bsdf.update(distribution="ggx", alpha=m["alpha"])
        return bsdf
    return {"type": "twosided", "material": bsdf}
