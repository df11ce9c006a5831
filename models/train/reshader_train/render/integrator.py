"""The reshading integrator and the depth pass (Mitsuba's LLVM variant must be active).

Reshading (paper section 3.2): the primary ray from the input camera finds the surface
point x; shading and every secondary ray then use the novel primary ray, from the novel
camera centre c' towards x. Mitsuba stays unmodified: we start a new ray just in front
of x along normalize(x - c') and hand it to the built-in `path` integrator, which finds
x again and shades it as seen from c'.
"""

import drjit as dr
import mitsuba as mi
import numpy as np

from .cameras import Camera

# How far in front of x the novel ray starts, in scene units: far above float error at
# scene coordinates of ~10 (1e-6) and far below any feature size (rooms are metres).
REHIT_EPSILON = 1e-3
# Output channels after RGB, one float each, averaged over the samples of a pixel.
AOVS = ("invalid", "z_primary", "z_rehit")


class ReshadeIntegrator(mi.SamplingIntegrator):
    """Shades the input camera's first hits as if seen from `novel_centre`."""

    def __init__(self, props=None):
        super().__init__(props if props is not None else mi.Properties())
        max_depth = props.get("max_depth", 8) if props is not None else 8
        self.path = make_path(max_depth)
        self.set_cameras(np.zeros(3), np.zeros(3), np.array([0.0, 0.0, 1.0]))

    def set_cameras(self, novel_centre, input_centre, input_forward) -> None:
        # Opaque so that the compiled kernel is reused when only the cameras change.
        self.novel_centre = mi.Point3f(*map(float, novel_centre))
        self.input_centre = mi.Point3f(*map(float, input_centre))
        self.forward = mi.Vector3f(*map(float, input_forward))
        dr.make_opaque(self.novel_centre, self.input_centre, self.forward)

    def aov_names(self):
        return [f"{name}.Y" for name in AOVS]

    def sample(self, scene, sampler, ray, medium=None, active=True):
        si = scene.ray_intersect(ray, active)
        hit = si.is_valid()
        x = si.p
        # Misses see the environment, which is infinitely far: same direction from c'.
        d = dr.select(hit, dr.normalize(x - self.novel_centre), ray.d)
        o = dr.select(hit, x - d * REHIT_EPSILON, ray.o)
        novel_ray = mi.Ray3f(o, d, ray.time, ray.wavelengths)
        spec, valid, _ = self.path.sample(scene, sampler, novel_ray, medium, active)

        # The side of the surface that the input camera sees must also face c'.
        n = si.n * dr.sign(dr.dot(si.n, -ray.d))
        invalid = hit & (dr.dot(n, self.novel_centre - x) <= 0)

        rehit = scene.ray_intersect(novel_ray, active & hit)
        z_primary = dr.select(hit, dr.dot(x - self.input_centre, self.forward), 0.0)
        z_rehit = dr.select(
            rehit.is_valid(), dr.dot(rehit.p - self.input_centre, self.forward), 0.0
        )
        return spec, valid, [dr.select(invalid, 1.0, 0.0), z_primary, z_rehit]

    def to_string(self):
        return "ReshadeIntegrator[]"


def register() -> None:
    mi.register_integrator("reshade", lambda props: ReshadeIntegrator(props))


def make_reshade(novel: Camera, input_camera: Camera, max_depth: int) -> ReshadeIntegrator:
    integrator = mi.load_dict({"type": "reshade", "max_depth": max_depth})
    integrator.set_cameras(novel.centre, input_camera.centre, input_camera.rotation[:, 2])
    return integrator


def make_sensor(camera: Camera, spp: int):
    return mi.load_dict(
        {
            "type": "perspective",
            "fov": camera.fov_x_deg,
            "fov_axis": "x",
            "near_clip": 1e-3,
            "to_world": mi.ScalarTransform4f(camera.to_mitsuba().tolist()),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {
                "type": "hdrfilm",
                "width": camera.width,
                "height": camera.height,
                "pixel_format": "rgb",
                # Box: each sample lands in exactly one pixel, which the mask's
                # "invalid if any sample is invalid" rule relies on.
                "rfilter": {"type": "box"},
            },
        }
    )


def pixel_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Unit world directions through every pixel centre, and their cosines to the axis."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    d_cam = np.stack(
        [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1
    )
    d_cam /= np.linalg.norm(d_cam, axis=-1, keepdims=True)
    return d_cam @ camera.rotation.T, d_cam[..., 2]


def trace_distances(scene, origin, directions: np.ndarray) -> np.ndarray:
    """Distance to the first hit along each ray (inf on a miss); directions shape (..., 3)."""
    flat = directions.reshape(-1, 3).astype(np.float32)
    n = flat.shape[0]
    # Opaque: a literal origin would compile a new kernel for every camera candidate.
    o = mi.Point3f(*[dr.opaque(mi.Float, float(c), n) for c in origin])
    d = mi.Vector3f(mi.Float(flat[:, 0]), mi.Float(flat[:, 1]), mi.Float(flat[:, 2]))
    si = scene.ray_intersect(mi.Ray3f(o, d))
    t = np.array(dr.select(si.is_valid(), si.t, dr.inf), dtype=np.float32)
    return t.reshape(directions.shape[:-1])


def render_depth(scene, camera: Camera) -> np.ndarray:
    """z-depth (along the optical axis) of each pixel centre's first hit; inf on a miss."""
    directions, cos_axis = pixel_rays(camera)
    t = trace_distances(scene, camera.centre, directions)
    return (t * cos_axis).astype(np.float32)


def make_path(max_depth: int):
    return mi.load_dict({"type": "path", "max_depth": max_depth})


def render_image(scene, camera: Camera, spp: int, seed: int, integrator) -> np.ndarray:
    """(H, W, C) float32: RGB, then the integrator's AOVs."""
    sensor = make_sensor(camera, spp)
    image = mi.render(scene, sensor=sensor, integrator=integrator, spp=spp, seed=seed)
    return np.array(image, dtype=np.float32)
