"""Pinhole cameras in the project's convention (OpenCV axes: x right, y down, z forward).

Mitsuba's sensors use x left, y up, z forward; `to_mitsuba` flips the first two axes.
Pixel centres sit at integer coordinates (OpenCV), so the principal point of a centred
camera is ((W - 1) / 2, (H - 1) / 2).
"""

import math
from dataclasses import dataclass

import numpy as np

# Mitsuba camera axes expressed in OpenCV camera axes.
_CV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])


@dataclass(frozen=True)
class Camera:
    world_from_camera: np.ndarray  # 4x4, OpenCV camera axes
    width: int
    height: int
    fov_x_deg: float

    @property
    def fx(self) -> float:
        return 0.5 * self.width / math.tan(math.radians(self.fov_x_deg) / 2)

    @property
    def fy(self) -> float:
        return self.fx

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2

    @property
    def centre(self) -> np.ndarray:
        return self.world_from_camera[:3, 3].copy()

    @property
    def rotation(self) -> np.ndarray:
        return self.world_from_camera[:3, :3].copy()

    def to_mitsuba(self) -> np.ndarray:
        """world_from_camera in Mitsuba's sensor axes."""
        return self.world_from_camera @ _CV_TO_MITSUBA

    def translated(self, offset_cam: np.ndarray) -> "Camera":
        """The same camera moved by `offset_cam` (expressed in this camera's frame)."""
        m = self.world_from_camera.copy()
        m[:3, 3] = self.centre + self.rotation @ np.asarray(offset_cam, dtype=float)
        return Camera(m, self.width, self.height, self.fov_x_deg)

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixel coordinates (u, v) and z-depth of world points, shape (N, 3)."""
        pts = np.atleast_2d(points_world) - self.centre
        cam = pts @ self.rotation  # rows: R^T p
        z = cam[:, 2]
        u = self.fx * cam[:, 0] / z + self.cx
        v = self.fy * cam[:, 1] / z + self.cy
        return np.stack([u, v, z], axis=1)

    def meta(self) -> dict:
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "fov_x_deg": self.fov_x_deg,
            "world_from_camera": self.world_from_camera.tolist(),
        }


def look_at(origin, target, up=(0.0, 1.0, 0.0), roll_deg: float = 0.0) -> np.ndarray:
    """world_from_camera (OpenCV axes) for a camera at `origin` looking at `target`."""
    origin = np.asarray(origin, dtype=float)
    forward = np.asarray(target, dtype=float) - origin
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=float))
    if np.linalg.norm(right) < 1e-6:  # looking straight along `up`
        right = np.cross(forward, np.array([1.0, 0.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    if roll_deg:
        a = math.radians(roll_deg)
        right, down = (
            math.cos(a) * right + math.sin(a) * down,
            -math.sin(a) * right + math.cos(a) * down,
        )
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, down, forward, origin
    return m


def sample_shell(rng: np.random.Generator, r_min: float = 0.1, r_max: float = 0.3) -> np.ndarray:
    """A point uniformly distributed (by volume) in the shell r_min <= |p| <= r_max."""
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    radius = rng.uniform(r_min**3, r_max**3) ** (1.0 / 3.0)
    return direction * radius
