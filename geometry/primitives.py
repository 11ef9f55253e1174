"""Built-in objects other than the shaderball: a sphere, a rounded cube and a torus.

Each is returned in its own units (normalised later, :mod:`geometry.objects`) as float64
``(positions, faces, normals, uv)`` with per-vertex UVs, analytic unit normals and faces
wound counter-clockwise seen from the normal side. None has a crease, so normals are
smooth everywhere; vertices are split only along UV seams (same position and normal
on both sides). Tessellation stays under ~20k triangles: renders at 64 px stay fast.
"""

from __future__ import annotations

import numpy as np

from geometry.patches import grid_faces, orient_faces

#: Latitude rows and longitude columns of the UV sphere.
SPHERE_ROWS, SPHERE_COLS = 64, 128
#: Grid vertices along each side of a rounded cube's face, and the edge radius (half side 1).
CUBE_GRID, CUBE_EDGE_RADIUS = 40, 0.25
#: Torus radii (before normalisation) and its grid: around the ring, around the tube.
TORUS_MAJOR, TORUS_MINOR = 0.5, 0.2
TORUS_RING, TORUS_TUBE = 128, 48
#: Tilt of the torus's axis from the view axis (y) towards +z, degrees: the camera sees
#: the hole and the tube's top at once.
TORUS_TILT_DEG = 30.0

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def sphere() -> Arrays:
    """Unit UV sphere: u along longitude (seam at +x), v from the south pole (0) to the north (1).

    The pole rows keep one vertex per column so each keeps its own u; the triangles that
    would have two vertices at a pole are left out.
    """
    rows, cols = SPHERE_ROWS, SPHERE_COLS
    theta = np.linspace(0.0, np.pi, rows + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, cols + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    normals = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    normals[: cols + 1] = (0.0, 0.0, 1.0)  # exact poles, whatever sin(pi) rounds to
    normals[-(cols + 1) :] = (0.0, 0.0, -1.0)
    _close_seam(normals.reshape(rows + 1, cols + 1, 3))
    uv = np.stack([p / (2.0 * np.pi), 1.0 - t / np.pi], -1).reshape(-1, 2)
    faces = grid_faces(rows + 1, cols + 1)
    pos = normals.copy()
    p0 = pos[faces]
    area = np.linalg.norm(np.cross(p0[:, 1] - p0[:, 0], p0[:, 2] - p0[:, 0]), axis=1)
    faces = faces[area > 1e-12]
    return pos, orient_faces(faces, pos, normals), normals, uv


def rounded_cube() -> Arrays:
    """Cube of half side 1 with edges and corners rounded to CUBE_EDGE_RADIUS.

    Each face is a grid on the cube pushed onto the rounded surface (the point's nearest
    point on the inner cube, plus the radius along the offset); the six faces are six UV
    charts laid out 3 x 2 in the unit square with a margin. The same grid numbers on two
    faces give bit-identical positions along their shared edge.
    """
    n, r = CUBE_GRID, CUBE_EDGE_RADIUS
    s = np.linspace(-1.0, 1.0, n)
    a, b = np.meshgrid(s, s, indexing="ij")
    a, b = a.ravel(), b.ravel()
    one = np.ones_like(a)
    # (axis, sign): each face's outward axis and its in-plane (a, b) axes, right-handed.
    faces_def = [(0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)]
    positions, normals, uvs, tris = [], [], [], []
    base = grid_faces(n, n)
    cell = 1.0 / 3.0
    margin = 0.02
    for k, (axis, sign) in enumerate(faces_def):
        u_axis, v_axis = (axis + 1) % 3, (axis + 2) % 3
        cube = np.zeros((len(a), 3))
        cube[:, axis] = sign * one
        cube[:, u_axis] = a
        cube[:, v_axis] = b
        inner = np.clip(cube, -(1.0 - r), 1.0 - r)
        offset = cube - inner
        normal = offset / np.linalg.norm(offset, axis=1, keepdims=True)
        pos = inner + r * normal
        col, row = k % 3, k // 3
        u = (col + margin + (1.0 - 2 * margin) * (a + 1.0) / 2.0) * cell
        v = (row + margin + (1.0 - 2 * margin) * (b + 1.0) / 2.0) * cell
        uv = np.stack([u, v], 1)
        tris.append(orient_faces(base, pos, normal) + k * len(a))
        positions.append(pos)
        normals.append(normal)
        uvs.append(uv)
    return np.concatenate(positions), np.concatenate(tris), np.concatenate(normals), np.concatenate(uvs)


def torus() -> Arrays:
    """Torus of radii TORUS_MAJOR/TORUS_MINOR, its axis tilted TORUS_TILT_DEG from y to z.

    UVs are the natural parametrisation: u around the ring in [0, 1], v around the tube in
    [0, TORUS_MINOR / TORUS_MAJOR], so texels are square on the tube's centre circle.
    """
    ring, tube = TORUS_RING, TORUS_TUBE
    u = np.linspace(0.0, 2.0 * np.pi, ring + 1)
    v = np.linspace(0.0, 2.0 * np.pi, tube + 1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    centre = np.stack([np.cos(uu), np.sin(uu), np.zeros_like(uu)], -1)
    normals = np.cos(vv)[..., None] * centre + np.sin(vv)[..., None] * np.array([0.0, 0.0, 1.0])
    positions = TORUS_MAJOR * centre + TORUS_MINOR * normals
    for grid in (positions, normals):
        _close_seam(grid)
        _close_seam(grid.transpose(1, 0, 2))
    uv = np.stack([uu / (2.0 * np.pi), vv / (2.0 * np.pi) * (TORUS_MINOR / TORUS_MAJOR)], -1)
    # Axis z -> tilted: rotate about x so the ring's axis points mostly along -y (the camera).
    angle = np.radians(90.0 - TORUS_TILT_DEG)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    positions = positions.reshape(-1, 3) @ rot.T
    normals = normals.reshape(-1, 3) @ rot.T
    faces = grid_faces(ring + 1, tube + 1)
    return positions, orient_faces(faces, positions, normals), normals, uv.reshape(-1, 2)


def _close_seam(grid: np.ndarray) -> None:
    """Copy the first column over the last (angle 2 pi), in place: sin(2 pi) is not 0 in
    floats, and a seam's two sides must share their positions bit for bit."""
    grid[:, -1] = grid[:, 0]


PRIMITIVES = {"sphere": sphere, "rounded_cube": rounded_cube, "torus": torus}
