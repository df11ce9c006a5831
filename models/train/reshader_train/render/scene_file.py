"""User scenes: any Mitsuba 3 scene file as a source of dataset examples.

The file's own sensors, film and integrator settings (except max_depth) are ignored:
cameras are placed at random in free space inside the scene's bounds. Materials are
randomised by rewriting the XML (each top-level or shape-level <bsdf> is replaced by a
random one with the same id), so Mitsuba itself stays untouched and every plugin the
file uses keeps working. The scene must be at the dataset's scale (y up, rooms a few
units across, subjects 1-5 units from the camera).
"""

import math
import os
import tempfile
import xml.etree.ElementTree as ET

import numpy as np

from .example import CLEARANCE, camera_is_free, view_hits
from .materials import material_dict, random_colour, sample_material

# BSDFs that carry an alpha mask or no surface at all: replacing them would change
# geometry or media, so they are kept.
KEEP_BSDFS = {"mask", "null"}


def _xml_value(parent, name: str, value) -> None:
    """Append `value` as a Mitsuba XML property called `name`."""
    if isinstance(value, dict):
        tag = "texture" if value["type"] in ("bitmap", "rgb") and name != "material" else "bsdf"
        if value["type"] == "rgb":
            ET.SubElement(parent, "rgb", name=name, value=_floats(value["value"]))
            return
        el = ET.SubElement(parent, tag, type=value["type"])
        if name:
            el.set("name", name)
        for k, v in value.items():
            if k == "uv_scale":
                transform = ET.SubElement(el, "transform", name="to_uv")
                ET.SubElement(transform, "scale", x=repr(v), y=repr(v))
            elif k != "type":
                _xml_value(el, k, v)
    elif isinstance(value, bool):
        ET.SubElement(parent, "boolean", name=name, value=str(value).lower())
    elif isinstance(value, (int, float)):
        ET.SubElement(parent, "float", name=name, value=repr(float(value)))
    elif isinstance(value, str):
        ET.SubElement(parent, "string", name=name, value=value)
    elif isinstance(value, list):
        ET.SubElement(parent, "rgb", name=name, value=_floats(value))
    else:
        raise TypeError(f"cannot write {name}={value!r} as Mitsuba XML")


def _floats(values) -> str:
    return ", ".join(repr(float(v)) for v in np.atleast_1d(values))


def bsdf_element(bsdf: dict, ident: str | None, name: str | None) -> ET.Element:
    holder = ET.Element("holder")
    _xml_value(holder, name or "", bsdf)
    el = holder[0]
    if not name:
        el.attrib.pop("name", None)
    if ident:
        el.set("id", ident)
    return el


class SceneFile:
    def __init__(self, path: str):
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: scene file not found")
        try:
            self.tree = ET.parse(path)
        except ET.ParseError as err:
            raise ValueError(f"{path}: not a valid Mitsuba XML scene: {err}") from None
        if self.tree.getroot().tag != "scene":
            raise ValueError(f"{path}: root element is <{self.tree.getroot().tag}>, not <scene>")
        self.path = os.path.abspath(path)
        self.base = None  # the scene as written, loaded on first use

    def _load(self, mi, xml: str | None = None):
        folder = os.path.dirname(self.path)
        resolver = mi.file_resolver()
        if folder not in [str(p) for p in resolver]:
            resolver.prepend(folder)
        try:
            return mi.load_string(xml) if xml is not None else mi.load_file(self.path)
        except Exception as err:  # Mitsuba raises RuntimeError for any scene problem
            raise ValueError(f"{self.path}: Mitsuba could not load it: {err}") from None

    def max_depth(self) -> int:
        for el in self.tree.getroot().iter("integrator"):
            for prop in el.iter("integer"):
                if prop.get("name") == "max_depth" and int(prop.get("value")) > 0:
                    return int(prop.get("value"))
        return 8

    def up(self, scene) -> np.ndarray:
        """World up: the file's first sensor's up axis, else +y."""
        if scene.sensors():
            m = np.array(scene.sensors()[0].world_transform().matrix, dtype=float).reshape(4, 4)
            up = m[:3, 1]
            return up / np.linalg.norm(up)
        return np.array([0.0, 1.0, 0.0])

    def _rewrite(self, mi, rng, orbs: list, randomize: bool, tmpdir: str) -> tuple[str, dict]:
        root = ET.fromstring(ET.tostring(self.tree.getroot()))
        materials = {}
        count = [0]

        def bitmap(image, uv_scale):
            count[0] += 1
            path = os.path.join(tmpdir, f"texture{count[0]}.exr")
            mi.Bitmap(image).write(path)
            return {
                "type": "bitmap",
                "filename": path,
                "raw": True,
                "wrap_mode": "repeat",
                "uv_scale": float(uv_scale),
            }

        parents = [root, *root.iter("shape")]
        for parent in parents if randomize else []:
            for i, el in enumerate(list(parent)):
                if el.tag != "bsdf" or el.get("type") in KEEP_BSDFS:
                    continue
                if parent.tag == "shape" and parent.find("emitter") is not None:
                    continue
                key = el.get("id") or f"{parent.get('id') or parent.get('type')}#{i}"
                m = sample_material(rng)
                materials[key] = m
                new = bsdf_element(material_dict(mi, m, bitmap), el.get("id"), el.get("name"))
                parent.remove(el)
                parent.insert(i, new)
        for el in _orb_elements(orbs):
            root.append(el)
        return ET.tostring(root, encoding="unicode"), materials

    def load_base(self, mi) -> None:
        if self.base is None:
            self.base = self._load(mi)
            if not self.base.shapes():
                raise ValueError(f"{self.path}: the scene has no shapes to look at")

    def make(self, mi, rng, width: int, height: int, randomize: bool, n_orbs: int):
        self.load_base(mi)
        params: dict = {"kind": "file", "file": self.path, "max_depth": self.max_depth()}
        up = self.up(self.base)
        orbs = sample_free_orbs(rng, self.base, n_orbs)
        scene = self.base
        if randomize or orbs:
            with tempfile.TemporaryDirectory(prefix="reshader-scene-") as tmpdir:
                xml, params["materials"] = self._rewrite(mi, rng, orbs, randomize, tmpdir)
                scene = self._load(mi, xml)
        params["orbs"] = orbs
        params["camera"] = choose_file_camera(rng, scene, up, width, height, self.path)
        return params, scene, params.pop("camera")


def _orb_elements(orbs: list) -> list:
    elements = []
    for orb in orbs:
        shape = ET.Element("shape", type="sphere")
        ET.SubElement(shape, "point", name="center", value=_floats(orb["position"]))
        ET.SubElement(shape, "float", name="radius", value=repr(orb["radius"]))
        emitter = ET.SubElement(shape, "emitter", type="area")
        ET.SubElement(emitter, "rgb", name="radiance", value=_floats(orb["radiance"]))
        elements.append(shape)
    return elements


def _bounds(scene) -> tuple[np.ndarray, np.ndarray]:
    bbox = scene.bbox()
    return np.array(bbox.min, dtype=float), np.array(bbox.max, dtype=float)


def sample_free_orbs(rng, scene, count: int) -> list:
    """`count` emissive orbs at random free spots inside the scene's bounds."""
    lo, hi = _bounds(scene)
    orbs = []
    for _ in range(count):
        radius = float(rng.uniform(0.03, 0.12))
        for _ in range(50):
            p = rng.uniform(lo + radius, hi - radius)
            if camera_is_free(scene, p) and all(
                math.dist(p, q["position"]) > radius + q["radius"] for q in orbs
            ):
                hue = random_colour(rng, sat=(0.6, 1.0), val=(1.0, 1.0))
                orbs.append(
                    {
                        "position": [float(v) for v in p],
                        "radius": radius,
                        "radiance": [c * float(rng.uniform(5, 40)) for c in hue],
                    }
                )
                break
    return orbs


def choose_file_camera(rng, scene, up, width: int, height: int, path: str) -> dict:
    """A free position inside the bounds, looking at geometry 1-5 units away."""
    from .example import make_camera

    lo, hi = _bounds(scene)
    lo, hi = lo + CLEARANCE, hi - CLEARANCE
    if np.any(hi <= lo):
        raise ValueError(f"{path}: scene bounds {lo}..{hi} are too small for a camera")
    # Horizontal directions relative to the file's up axis.
    a = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    for _ in range(300):
        pos = rng.uniform(lo, hi)
        if not camera_is_free(scene, pos):
            continue
        yaw, pitch = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(-25, 15))
        forward = math.cos(pitch) * (math.cos(yaw) * a + math.sin(yaw) * b) + math.sin(pitch) * up
        cam = {
            "position": pos.tolist(),
            "target": (pos + forward).tolist(),
            "up": up.tolist(),
            "fov_x_deg": float(rng.uniform(45, 75)),
            "roll_deg": float(rng.normal(0, 3)),
        }
        hits = view_hits(scene, make_camera(cam, width, height))
        finite = hits[np.isfinite(hits)]
        if finite.size >= 0.5 * hits.size and 1.0 <= np.median(finite) <= 5.0:
            return cam
    raise RuntimeError(
        f"{path}: no free camera with geometry 1-5 units away in 300 tries "
        "(is the scene at the dataset's scale: rooms a few units across?)"
    )
