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


def _signed_power(x, e: float):
    return np.sign(x) * np.abs(x) ** e


def superellipsoid(half_extents, e_vertical: float, e_horizontal: float, nu=48, nv=32):
    """A rounded box (exponents ~0.2-0.5) or pebble (~1) of `half_extents` (x, y, z),
    centred on the origin, faces wound so that the geometric normals point outwards."""
    a, b, c = (float(v) for v in half_extents)

    def fn(u, v):
        eta = math.pi * (v - 0.5)  # latitude, bottom to top
        omega = 2 * math.pi * u
        ce, se = _signed_power(np.cos(eta), e_vertical), _signed_power(np.sin(eta), e_vertical)
        co, so = (
            _signed_power(np.cos(omega), e_horizontal),
            _signed_power(np.sin(omega), e_horizontal),
        )
        return np.stack([a * ce * co, b * se, c * ce * so], axis=-1)

    verts, faces, uv = _surface(fn, nu, nv)
    return verts, orient_outwards(verts, faces), uv


def orient_outwards(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """`faces` with their winding flipped if most face normals point towards the centroid
    (for closed, roughly convex meshes)."""
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = np.sum(normal * (tri.mean(axis=1) - verts.mean(axis=0)), axis=1)
    return faces if outward.sum() >= 0 else faces[:, ::-1].copy()


def sweep(width: float, floor_depth: float, radius: float, height: float, nu=8, nv=48):
    """A photo studio's seamless backdrop: a floor from z = floor_depth to z = 0, a
    quarter-circle cove of `radius` up to a back wall at z = -radius, up to `height`;
    `width` across x (centred). Faces wound so that the normals face the subject."""
    arc = math.pi / 2 * radius
    wall = height - radius
    total = floor_depth + arc + wall

    def fn(u, v):
        s = v * total
        x = (u - 0.5) * width
        on_floor, on_arc = s < floor_depth, s < floor_depth + arc
        angle = np.clip((s - floor_depth) / radius, 0, math.pi / 2)
        y = np.where(
            on_floor,
            0.0,
            np.where(on_arc, radius * (1 - np.cos(angle)), radius + s - floor_depth - arc),
        )
        z = np.where(on_floor, floor_depth - s, np.where(on_arc, -radius * np.sin(angle), -radius))
        return np.stack([x, y, z], axis=-1)

    # Rows of vertices at the floor's end and the cove's ends, so the profile keeps its shape.
    verts, faces, uv = _surface(fn, nu, nv)
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if normal[:, 1].sum() < 0:  # the floor part must face up
        faces = faces[:, ::-1].copy()
    return verts, faces, uv
