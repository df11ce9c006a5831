"""Where scenes come from: the procedural generator or a user's Mitsuba scene file."""

from . import procedural
from .example import choose_procedural_camera


class ProceduralSource:
    def __init__(self, family: str = "mixed"):
        if family not in procedural.FAMILIES:
            raise ValueError(
                f"unknown procedural family {family!r}: expected one of "
                + ", ".join(procedural.FAMILIES)
            )
        self.family = family
        self.name = "procedural" if family == "mixed" else f"procedural:{family}"

    def prepare(self, mi) -> None:
        """Nothing to load up front."""

    def make(self, mi, rng, width: int, height: int):
        """(scene parameters, Mitsuba scene, camera parameters) for one example."""
        for _ in range(10):
            params = procedural.sample_scene(rng, self.family)
            if not params["objects"]:
                continue
            scene = procedural.build_scene(mi, params)
            try:
                cam = choose_procedural_camera(rng, scene, params, width, height)
            except RuntimeError:
                continue  # a cramped layout: draw another scene from the same stream
            return params, scene, cam
        raise RuntimeError("procedural generator found no usable scene in 10 tries")


class SceneFileSource:
    """A user's Mitsuba 3 scene with random cameras, optional random materials and orbs."""

    name = "scene file"

    def __init__(self, path: str, randomize_materials: bool, orbs: int):
        from . import scene_file

        self.name = path
        self.file = scene_file.SceneFile(path)
        self.randomize_materials = randomize_materials
        self.orbs = orbs

    def prepare(self, mi) -> None:
        """Load the file once up front, so that a broken scene fails before any example."""
        self.file.load_base(mi)

    def make(self, mi, rng, width: int, height: int):
        return self.file.make(mi, rng, width, height, self.randomize_materials, self.orbs)
