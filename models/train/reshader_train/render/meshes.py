"""Generated meshes (numpy) and their conversion to Mitsuba shapes."""

import math

import numpy as np

from .textures import value_noise


def _grid_faces(nu: int, nv: int) -> np.ndarray:
    """Two triangles per cell of an (nu+1) x (nv+1) vertex grid (row-major in v).

    Seam vertices are duplicated (u = 0 and u = 1), so no wrap-around faces are needed.
    """
    faces = []
    for j in range(nv):
        for i in range(nu):
            a = j * (nu + 1) + i
            b, c, d = a + 1, a + nu + 1, a + nu + 2
            faces += [(a, c, b), (b, c, d)]
    return np.array(faces, dtype=np.uint32)


def _surface(fn, nu: int, nv: int):
    """Vertices, faces and UVs of a parametric surface fn(u, v) -> (..., 3), u, v in [0, 1]."""
    v, u = np.mgrid[0 : nv + 1, 0 : nu + 1] / np.array([nv, nu])[:, None, None]
    verts = fn(u, v).reshape(-1, 3)
    uv = np.stack([u, v], axis=-1).reshape(-1, 2)
    return verts, _grid_faces(nu, nv), uv


def torus(major: float, minor: float, nu: int = 48, nv: int = 24):
    def fn(u, v):
        a, b = 2 * math.pi * u, 2 * math.pi * v
        ring = major + minor * np.cos(b)
        return np.stack([ring * np.cos(a), minor * np.sin(b), ring * np.sin(a)], axis=-1)

    return _surface(fn, nu, nv)


def blob(radius: float, amplitude: float, seed: int, nu: int = 48, nv: int = 24):
    """A sphere displaced by smooth noise (periodic in longitude, pinned at the poles)."""
    noise = value_noise(np.random.default_rng(seed), 64, 3, 3)

    def fn(u, v):
        theta, phi = math.pi * v, 2 * math.pi * u
        n = noise[(v * 63).astype(int), (u * 63).astype(int) % 64]
        n = np.where((v == 0) | (v == 1), 0.5, n)
        r = radius * (1 + amplitude * (2 * n - 1))
        d = np.stack([np.sin(theta) * np.cos(phi), np.cos(theta), np.sin(theta) * np.sin(phi)], -1)
        return d * r[..., None]

    return _surface(fn, nu, nv)


def vase(height: float, radii: list[float], nu: int = 48, nv: int = 32):
    """A surface of revolution through radii at evenly spaced heights (open at the top)."""
    profile = np.asarray(radii, dtype=float)
    knots = np.linspace(0, 1, len(profile))

    def fn(u, v):
        r = np.interp(v, knots, profile)
        a = 2 * math.pi * u
        return np.stack([r * np.cos(a), v * height, r * np.sin(a)], axis=-1)

    return _surface(fn, nu, nv)


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals; seam duplicates are merged by position."""
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    keys = np.round(verts, 6)
    _, idx = np.unique(keys, axis=0, return_inverse=True)
    idx = idx.reshape(-1)
    acc = np.zeros((idx.max() + 1, 3))
    for k in range(3):
        np.add.at(acc, idx[faces[:, k]], fn)
    n = acc[idx]
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1)


def rotation_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rotation_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def mitsuba_mesh(mi, name: str, verts, faces, uv, bsdf: dict):
    """A Mitsuba mesh shape from numpy arrays with the BSDF built from `bsdf`."""
    import drjit as dr

    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh(
        name,
        len(verts),
        len(faces),
        props=props,
        has_vertex_normals=True,
        has_vertex_texcoords=True,
    )
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(np.ascontiguousarray(verts.T, np.float32)))
    normals = vertex_normals(verts, faces)
    params["vertex_normals"] = dr.ravel(mi.Normal3f(np.ascontiguousarray(normals.T, np.float32)))
    params["vertex_texcoords"] = dr.ravel(mi.Point2f(np.ascontiguousarray(uv.T, np.float32)))
    params["faces"] = dr.ravel(mi.Vector3u(np.ascontiguousarray(faces.T, np.uint32)))
    params.update()
    return mesh
