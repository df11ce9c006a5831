"""Where scenes come from: the procedural generator or a user's Mitsuba scene file."""

import numpy as np

from . import procedural
from .example import choose_procedural_camera

# Separates the layouts' random streams from the examples' (seed, index, stream) ones.
LAYOUT_STREAM = 7_000_001


class ProceduralSource:
    """Procedural scenes of one family. With `layouts` K > 0, example i uses layout i mod K
    (geometry, sky, area lights drawn from `layout_seed` alone, so that a training and a
    validation set share them) with its own materials, orbs and cameras: the paper's
    protocol of a few fixed scenes re-dressed for every pair."""

    def __init__(self, family: str = "mixed", layouts: int = 0, layout_seed: int = 0):
        procedural.check_family(family)
        if layouts < 0:
            raise ValueError(f"--layouts {layouts}: need 0 (a new scene per example) or more")
        self.family, self.layouts, self.layout_seed = family, layouts, layout_seed
        self.name = "procedural" if family == "mixed" else f"procedural:{family}"
        if layouts:
            self.name += f" ({layouts} layouts, layout seed {layout_seed})"

    def _layout(self, index: int) -> dict:
        layout = index % self.layouts
        rng = np.random.default_rng([LAYOUT_STREAM, self.layout_seed, layout])
        for _ in range(10):
            params = procedural.sample_scene(rng, self.family)
            if params["objects"]:
                return {**params, "layout": layout, "layout_seed": self.layout_seed}
        raise RuntimeError(f"layout {layout} has no objects in 10 tries")

    def _params(self, rng, index: int) -> dict:
        if self.layouts:
            return procedural.restyle(rng, self._layout(index))
        return procedural.sample_scene(rng, self.family)

    def prepare(self, mi) -> None:
        """Nothing to load up front."""

    def make(self, mi, rng, width: int, height: int, index: int):
        """(scene parameters, Mitsuba scene, camera parameters) for example `index`."""
        for _ in range(10):
            params = self._params(rng, index)
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

    def make(self, mi, rng, width: int, height: int, index: int):
        return self.file.make(mi, rng, width, height, self.randomize_materials, self.orbs)
