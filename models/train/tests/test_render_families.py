"""The photographic procedural families (products, rooms, diffuse): tiny renders."""

import json
import math
import os

import numpy as np
import pytest

mitsuba_env = pytest.importorskip("reshader_train.render.mitsuba_env")

from reshader_train.render import materials, meshes, photo, procedural, textures  # noqa: E402

PHOTO = ("products", "rooms", "diffuse")


@pytest.fixture(scope="module")
def mi():
    return mitsuba_env.load_mitsuba(threads=2)


def run_cli(*argv) -> int:
    from reshader_train.cli import main

    return main(list(argv))


def draw(family: str, i: int) -> dict:
    return procedural.sample_scene(np.random.default_rng([5, i]), family)


def all_materials(scene: dict) -> list[dict]:
    holders = (scene["stage"], *scene["objects"])
    return [v for h in holders for k, v in h.items() if k.endswith("material")]


@pytest.mark.parametrize("family", PHOTO)
def test_each_photographic_family_renders_an_example_with_a_valid_layout(mi, tmp_path, family):
    out = str(tmp_path / family)
    args = ["render", "--out", out, "--count", "1", "--size", "32x32", "--spp", "4"]
    assert run_cli(*args, "--seed", "2", "--scenes", f"procedural:{family}") == 0
    (ex,) = os.listdir(out)
    folder = os.path.join(out, ex)
    assert sorted(os.listdir(folder)) == sorted(
        ["input.exr", "reshaded.exr", "novel.exr", "depth.exr", "mask.png", "meta.json"]
    )
    meta = json.load(open(os.path.join(folder, "meta.json")))
    scene = meta["scene"]
    assert scene["family"] == scene["kind"] == family
    assert (
        scene["objects"] and scene["orbs"] and scene["stage"]["type"] in ("sweep", "floor", "room")
    )
    near, far = scene["camera_distance"]
    cam = scene["camera"]
    assert near <= math.dist(cam["position"], cam["target"]) <= far
    images = {n: np.array(mi.Bitmap(os.path.join(folder, n))) for n in os.listdir(folder)
              if n != "meta.json"}  # fmt: skip
    for name in ("input.exr", "reshaded.exr", "novel.exr"):
        assert images[name].shape == (32, 32, 3) and np.isfinite(images[name]).all()
    assert images["input.exr"].mean() > 0  # lit, not a black frame
    assert np.isfinite(images["depth.exr"]).mean() >= 0.3
    assert set(np.unique(images["mask.png"])) <= {0, 255}


def relative_change(mi, folder: str) -> float:
    """Mean |reshaded - input| over valid pixels, relative to the input's mean."""

    def read(name):
        return np.array(mi.Bitmap(os.path.join(folder, name)), dtype=np.float64)

    inp, resh = read("input.exr"), read("reshaded.exr")
    valid = read("mask.png").reshape(inp.shape[:2]) > 0
    return float(np.abs(resh - inp)[valid].mean() / inp[valid].mean())


def test_diffuse_family_reshades_to_its_input_and_products_do_not(mi, tmp_path):
    from reshader_train.render.example import RenderSettings, render_example
    from reshader_train.render.sources import ProceduralSource

    # The same sample seed renders input and reshaded: on Lambertian surfaces the paths
    # are the same whatever the viewing direction, so only float noise may differ. A
    # product shot changes as much as its glossy objects cover of the frame.
    settings = RenderSettings(32, 32, 8)
    change = {}
    for family in ("diffuse", "products"):
        source = ProceduralSource(family)
        metas = [render_example(mi, source, str(tmp_path), i, 0, settings) for i in range(1, 5)]
        change[family] = [relative_change(mi, str(tmp_path / m["id"])) for m in metas]
    # Measured: diffuse at most 1e-5; products 0.003, 0.0007, 0.034 and 0.19.
    assert max(change["diffuse"]) < 2e-3
    assert np.mean(change["products"]) > max(0.01, 10 * max(change["diffuse"]))


def test_unknown_families_name_every_family(mi, tmp_path, capsys):
    args = ["render", "--out", str(tmp_path), "--count", "1", "--scenes", "procedural:shiny"]
    assert run_cli(*args) == 2
    err = capsys.readouterr().err
    assert "'shiny'" in err and all(f in err for f in procedural.FAMILIES)
    from reshader_train.render.sources import ProceduralSource

    with pytest.raises(ValueError, match="products, rooms, diffuse"):
        ProceduralSource("product")


def test_diffuse_scenes_are_lambertian_and_the_others_are_not():
    for i in range(20):
        scene = draw("diffuse", i)
        assert scene["base"] in ("products", "rooms")
        assert {m["type"] for m in all_materials(scene)} == {"diffuse"}
    glossy = [m["type"] for i in range(20) for m in all_materials(draw("products", i))]
    assert {"roughconductor", "plastic", "principled"} <= set(glossy)


def test_products_draw_the_materials_of_photographed_things():
    recipes = [
        o["material"]["recipe"]
        for i in range(60)
        for o in draw("products", i)["objects"]
        if o["shape"] != "counter"
    ]
    assert set(recipes) == {r for r, _ in photo.ROLES["product"]}
    assert recipes.count("glass") < 0.1 * len(recipes)  # sparingly: expensive and noisy
    glass = [o["shape"] for i in range(60) for o in draw("products", i)["objects"]
             if o["material"]["recipe"] == "glass"]  # fmt: skip
    assert set(glass) <= set(photo.CLOSED) and "blob" not in photo.CLOSED
    metals = [
        o["material"]
        for i in range(60)
        for o in draw("products", i)["objects"]
        if o["material"]["recipe"] == "brushed_metal"
    ]
    assert any("alpha_v" in m for m in metals)  # anisotropic
    assert {m["conductor"] for m in metals} >= {"Cr", "Cu", "Au", "steel"}


def test_rooms_have_windows_counters_and_cars():
    rooms = [draw("rooms", i) for i in range(40)]
    assert all(r["stage"]["type"] == "room" for r in rooms)
    assert all(r["stage"]["windows"] or r["area_lights"] for r in rooms)  # always lit
    shapes = {o["shape"] for r in rooms for o in r["objects"]}
    assert {"car", "counter", "table"} <= shapes
    cars = [o for r in rooms for o in r["objects"] if o["shape"] == "car"]
    assert all(o["material"]["recipe"] == "car_paint" for o in cars)
    floors = {r["stage"]["floor_material"]["recipe"] for r in rooms}
    assert "wood_floor" in floors
    for r in rooms:  # every object inside its room
        x0, x1, z0, z1, _, _ = r["bounds"]
        assert all(x0 < o["position"][0] < x1 and z0 < o["position"][2] < z1 for o in r["objects"])


def test_families_draw_from_their_own_streams_and_layouts_keep_their_geometry():
    a, b = draw("products", 0), draw("diffuse", 0)
    assert a["objects"] != b["objects"]
    rng = np.random.default_rng(9)
    for family in PHOTO:
        layout = draw(family, 3)
        again = procedural.restyle(rng, layout)
        shapes = [(o["shape"], o["position"]) for o in again["objects"]]
        assert shapes == [(o["shape"], o["position"]) for o in layout["objects"]]
        assert again["sky"] == layout["sky"] and again["area_lights"] == layout["area_lights"]
        assert all_materials(again) != all_materials(layout)
        if family == "diffuse":
            assert {m["type"] for m in all_materials(again)} == {"diffuse"}


def test_every_recipe_loads_in_mitsuba(mi):
    rng = np.random.default_rng(1)
    for recipe in materials.RECIPES:
        for _ in range(3):
            m = materials.sample_recipe(rng, recipe)
            assert m["recipe"] == recipe
            mi.load_dict(materials.material_dict(mi, m))
    with pytest.raises(ValueError, match="unknown material recipe"):
        materials.sample_recipe(rng, "velvet")


def test_environment_panels_light_the_directions_they_name(mi):
    """A panel painted at (elevation, azimuth) is where Mitsuba's envmap looks it up."""
    sky = draw("products", 0)["sky"]
    sky = {**sky, "sun_radiance": [0.0, 0.0, 0.0], "intensity": 0.0, "height": 64}
    el, az = 0.4, 2.0
    panel = {"shape": "rect", "elevation": el, "azimuth": az, "half_width": 0.1,
             "half_height": 0.1, "softness": 0.05, "radiance": [10.0, 10.0, 10.0]}  # fmt: skip
    env = mi.load_dict(
        {
            "type": "envmap",
            "bitmap": mi.Bitmap(textures.make_environment({**sky, "panels": [panel]})),
        }
    )

    def radiance(d):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*(-float(v) for v in d))
        return float(np.array(env.eval(si)).mean())

    toward = textures.direction(el, az)
    assert radiance(toward) > 5
    assert radiance(textures.direction(el, az + 0.5)) < 0.5
    assert radiance(textures.direction(-el, az)) < 0.5


def test_rounded_boxes_face_outwards_and_the_sweep_faces_the_subject():
    verts, faces, _ = meshes.superellipsoid([0.3, 0.2, 0.1], 0.3, 0.4)
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    big = np.linalg.norm(normal, axis=1) > 1e-9
    assert (np.sum(normal * tri.mean(axis=1), axis=1)[big] > 0).all()
    assert np.abs(verts).max(axis=0) == pytest.approx([0.3, 0.2, 0.1])
    verts, faces, _ = meshes.sweep(5.0, 3.0, 1.0, 3.0)
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = tri.mean(axis=1)
    # Towards a subject standing on the floor in front of the cove.
    assert (np.sum(normal * ([0.0, 1.0, 1.0] - centre), axis=1) > 0).all()
    assert verts[:, 1].max() == pytest.approx(3.0) and verts[:, 2].min() == pytest.approx(-1.0)


def test_further_targets_of_a_path_traced_example_share_its_samples(tmp_path):
    from reshader_train.data import list_examples, load_example

    common = ["render", "--scenes", "procedural:products", "--count", "1", "--seed", "3"]
    common += ["--size", "32x32", "--spp", "4", "--change-seeds", "2", "--threads", "1"]
    one, three = tmp_path / "one", tmp_path / "three"
    assert run_cli(*common, "--out", str(one)) == 0
    assert run_cli(*common, "--out", str(three), "--targets", "3") == 0
    (a,), (b,) = list_examples(one), list_examples(three)

    def files(folder):
        return {p.name: p.read_bytes() for p in folder.iterdir() if p.name != "meta.json"}

    # The first target is the one-target render's, byte for byte.
    assert {k: v for k, v in files(b).items() if k in files(a)} == files(a)
    assert set(files(b)) - set(files(a)) == {
        "reshaded-1.exr", "reshaded-2.exr", "mask-1.png", "mask-2.png"
    }  # fmt: skip
    meta = json.loads((b / "meta.json").read_text())
    offsets = [meta["novel_offset"]] + [e["offset"] for e in meta["extra_targets"]]
    assert all(0.1 <= np.linalg.norm(o) <= 0.3 for o in offsets)
    assert len({tuple(o) for o in offsets}) == 3
    ex = load_example(b)
    assert ex.target_count == 3
    for k in (1, 2):
        target = ex.target(k)
        assert target.reshaded.shape == (32, 32, 3) and np.isfinite(target.reshaded).all()
        # Another camera shades the same samples differently, but the same scene.
        assert not np.array_equal(target.reshaded, ex.reshaded)
        assert abs(target.reshaded.mean() - ex.input.mean()) < 0.5 * ex.input.mean()
