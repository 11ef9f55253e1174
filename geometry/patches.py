"""The shaderball's surfaces as patches: positions, crease-split normals, chart coordinates.

Every patch is one smooth surface piece with its own vertices, so normals are split
at every crease (cut rims, end faces, pedestal edges) and nowhere else. Material-bearing
patches are also UV charts: each carries an equal-area parametrisation in metres
(Lambert azimuthal for caps, Lambert cylindrical for bands, isometric for planes), so
texel density is uniform up to tessellation, and seams run only along creases and on
the back of the ball (see docs/geometry.md).

Shared boundaries between patches are computed from the same numbers by the same
expressions, so their vertices coincide bit for bit and the shell is watertight.

Band frame: ``z'`` is the band's normal (tilted about the view axis y), ``y' = y``,
``x' = y' x z'``; ``phi`` is measured in the x'y' plane from x'. The cut removes the
shell where ``|z'| < band_width / 2`` and ``phi`` lies in the span centred on -y' (the
camera side).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geometry.params import ShaderballParams

#: Half-angle (latitude) of the core's band chart; its caps take the rest.
CORE_BAND_LATITUDE_DEG = 35.0


@dataclass
class Patch:
    """One smooth surface piece. ``uv`` (metres, chart-local) is None for neutral patches."""

    name: str
    positions: np.ndarray  # (N, 3) float64, world
    normals: np.ndarray  # (N, 3) float64, unit, world
    faces: np.ndarray  # (M, 3) int64, counter-clockwise seen from the normal side
    uv: np.ndarray | None = None  # (N, 2) float64 metres


# --------------------------------------------------------------------------- topology


def grid_faces(rows: int, cols: int, *, periodic: bool = False) -> np.ndarray:
    """Two triangles per cell of a rows x cols vertex grid (index r * cols + c)."""
    ncell_c = cols if periodic else cols - 1
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(ncell_c), indexing="ij")
    r, c = r.ravel(), c.ravel()
    c1 = (c + 1) % cols
    a, b = r * cols + c, r * cols + c1
    d, e = (r + 1) * cols + c, (r + 1) * cols + c1
    return np.concatenate([np.stack([a, b, e], 1), np.stack([a, e, d], 1)])


def cap_faces(rings: int, cols: int) -> np.ndarray:
    """A fan around vertex 0 (the pole) then a periodic grid over ``rings`` rings."""
    c = np.arange(cols)
    fan = np.stack([np.zeros(cols, np.int64), 1 + c, 1 + (c + 1) % cols], 1)
    return np.concatenate([fan, 1 + grid_faces(rings, cols, periodic=True)])


def orient_faces(faces: np.ndarray, positions: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Flip the faces whose winding disagrees with their vertex normals."""
    p = positions[faces]
    geometric = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", geometric, normals[faces].sum(1)) < 0
    out = faces.copy()
    out[flip] = out[flip][:, [0, 2, 1]]
    return out


def uv_signed_areas(uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    t = uv[faces]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def make_patch(name, positions, normals, faces, uv=None) -> Patch:
    """Orient faces by the normals; mirror a chart whose (u, v, n) is left-handed.

    Mitsuba's shading frame is (dp/du, n x dp/du, n): a mirrored chart would flip the
    tangent-space normal map's y axis.
    """
    faces = orient_faces(faces, positions, normals)
    if uv is not None and uv_signed_areas(uv, faces).sum() < 0:
        uv = uv * np.array([-1.0, 1.0])
    return Patch(name, positions, normals, faces, uv)


# --------------------------------------------------------------------------- sampling


@dataclass(frozen=True)
class BandFrame:
    centre: np.ndarray  # (3,)
    axes: np.ndarray  # (3, 3) columns x', y', z' in world

    def to_world(self, local: np.ndarray) -> np.ndarray:
        return self.dir_to_world(local) + self.centre

    def dir_to_world(self, local: np.ndarray) -> np.ndarray:
        # Element-wise rather than a matrix product: BLAS kernels may round a row
        # differently depending on where it sits in the array, and shared boundary
        # vertices must come out bit-identical.
        local = np.asarray(local, np.float64)
        a = self.axes
        return local[..., 0:1] * a[:, 0] + local[..., 1:2] * a[:, 1] + local[..., 2:3] * a[:, 2]


def band_frame(params: ShaderballParams) -> BandFrame:
    t = math.radians(params.band_tilt_deg)
    z = np.array([-math.sin(t), 0.0, math.cos(t)])
    y = np.array([0.0, 1.0, 0.0])
    x = np.cross(y, z)
    return BandFrame(np.array([0.0, 0.0, params.ball_centre_z_m]), np.stack([x, y, z], 1))


def cos_sin(angles) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of each angle with libm, one scalar at a time.

    numpy's vectorised trig may take a different code path for an element depending
    on its position in the array; shared boundaries need identical bits.
    """
    values = [float(a) for a in np.ravel(angles)]
    return np.array([math.cos(a) for a in values]), np.array([math.sin(a) for a in values])


def sphere_dir(theta, phi) -> np.ndarray:
    """Unit directions for paired angle arrays of equal shape (band-frame coordinates)."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, np.float64), np.asarray(phi, np.float64))
    ct, st = cos_sin(theta)
    cp, sp = cos_sin(phi)
    return np.stack([st * cp, st * sp, ct], -1).reshape(theta.shape + (3,))


@dataclass(frozen=True)
class Sampling:
    """Angles shared by every patch so that common boundaries coincide exactly."""

    phi: np.ndarray  # (nc,) ring angles, one period; phi[0] = cut start, phi[n_cut] = cut end
    n_cut: int
    phi_a: float
    phi_b: float
    n_thick: int
    step: float  # target angular step, radians


def sampling(params: ShaderballParams) -> Sampling:
    step = 2.0 * math.pi / params.segments
    span = math.radians(params.band_span_deg)
    phi_a = -0.5 * math.pi - 0.5 * span
    phi_b = -0.5 * math.pi + 0.5 * span
    n_cut = max(4, round(params.segments * params.band_span_deg / 360.0))
    n_back = max(4, params.segments - n_cut)
    phi = np.concatenate(
        [
            np.linspace(phi_a, phi_b, n_cut + 1)[:-1],
            np.linspace(phi_b, phi_a + 2.0 * math.pi, n_back + 1)[:-1],
        ]
    )
    n_thick = max(1, math.ceil(params.shell_thickness_m / (params.shell_radius_m * step)))
    return Sampling(phi, n_cut, phi_a, phi_b, n_thick, step)


def n_steps(angle: float, step: float) -> int:
    return max(2, math.ceil(angle / step - 1e-9))


# --------------------------------------------------------------------------- spheres


def sphere_cap(frame, radius, theta_edge, phi, *, bottom, inward, name, step) -> Patch:
    """A cap around the +z' (or -z', ``bottom``) pole down to polar angle theta_edge.

    Chart: Lambert azimuthal equal-area about the pole, rho = 2 r sin(alpha / 2).
    """
    rings = n_steps(theta_edge, step)
    alpha = np.linspace(0.0, theta_edge, rings + 1)[1:]  # angle from this cap's pole
    theta = (math.pi - alpha) if bottom else alpha
    if bottom:
        theta[-1] = theta_edge_bottom(theta_edge)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    pole = np.array([[0.0, 0.0, -1.0 if bottom else 1.0]])
    dirs = np.concatenate([pole, sphere_dir(th, ph).reshape(-1, 3)])
    al = np.concatenate([[0.0], np.repeat(alpha, len(phi))])
    ph_all = np.concatenate([[0.0], np.tile(phi, rings)])
    rho = 2.0 * radius * np.sin(0.5 * al)
    uv = np.stack([rho * np.cos(ph_all), rho * np.sin(ph_all)], -1)
    normals = frame.dir_to_world(-dirs if inward else dirs)
    return make_patch(name, frame.to_world(radius * dirs), normals, cap_faces(rings, len(phi)), uv)


def theta_edge_bottom(theta_edge: float) -> float:
    """The polar angle of a bottom cap's edge: one expression, used by every neighbour."""
    return math.pi - theta_edge


def sphere_band(frame, radius, theta_top, theta_bottom, phi_pos, phi_unwrapped, *, inward, name, rows):
    """A band between two polar angles over the given columns (not periodic).

    Chart: Lambert cylindrical equal-area, (u, v) = (r * phi, r * cos(theta)).
    ``phi_pos`` gives the positions (so shared columns match bit for bit) and
    ``phi_unwrapped`` the monotonic angle for u.
    """
    theta = np.linspace(theta_top, theta_bottom, rows + 1)
    th, ph = np.meshgrid(theta, phi_pos, indexing="ij")
    dirs = sphere_dir(th, ph).reshape(-1, 3)
    _, phu = np.meshgrid(theta, phi_unwrapped, indexing="ij")
    uv = np.stack([radius * phu.ravel(), radius * np.cos(th).ravel()], -1)
    normals = frame.dir_to_world(-dirs if inward else dirs)
    faces = grid_faces(rows + 1, len(phi_pos))
    return make_patch(name, frame.to_world(radius * dirs), normals, faces, uv)


# --------------------------------------------------------------------------- the shell


def shell_patches(params: ShaderballParams, frame: BandFrame, s: Sampling) -> list[Patch]:
    """Outer and inner surfaces, the two rims and the two end faces of the cut shell."""
    r_out, r_in = params.shell_radius_m, params.inner_radius_m
    half_w = 0.5 * params.band_width_m
    th_out = math.acos(half_w / r_out)
    th_in = math.acos(half_w / r_in)
    # The back bands run from the cut's end (phi_b) round the back to its start (phi_a).
    back_pos = np.concatenate([s.phi[s.n_cut :], s.phi[:1]])
    back_unwrapped = np.concatenate([s.phi[s.n_cut :], [s.phi_a + 2.0 * math.pi]])
    cut_phi = s.phi[: s.n_cut + 1]
    band_rows = n_steps(theta_edge_bottom(th_out) - th_out, s.step)

    patches = []
    for inward, radius, th_edge, tag in ((False, r_out, th_out, "outer"), (True, r_in, th_in, "inner")):
        for bottom in (False, True):
            name = f"{tag}_{'bottom' if bottom else 'top'}_cap"
            patches.append(
                sphere_cap(frame, radius, th_edge, s.phi, bottom=bottom, inward=inward, name=name, step=s.step)
            )
        patches.append(
            sphere_band(
                frame,
                radius,
                th_edge,
                theta_edge_bottom(th_edge),
                back_pos,
                back_unwrapped,
                inward=inward,
                name=f"{tag}_back_band",
                rows=band_rows,
            )
        )

    fractions = np.linspace(0.0, 1.0, s.n_thick + 1)
    for top in (True, False):
        t_out = th_out if top else theta_edge_bottom(th_out)
        t_in = th_in if top else theta_edge_bottom(th_in)
        inner = r_in * sphere_dir(np.full_like(cut_phi, t_in), cut_phi)
        outer = r_out * sphere_dir(np.full_like(cut_phi, t_out), cut_phi)
        local = _lerp_rows(inner, outer, fractions).reshape(-1, 3)
        normal = frame.dir_to_world(np.array([0.0, 0.0, -1.0 if top else 1.0]))
        patches.append(
            make_patch(
                "rim_top" if top else "rim_bottom",
                frame.to_world(local),
                np.tile(normal, (len(local), 1)),
                grid_faces(len(cut_phi), s.n_thick + 1),
                local[:, :2].copy(),  # the plane's own coordinates: an isometry
            )
        )

    rows_out = np.linspace(th_out, theta_edge_bottom(th_out), band_rows + 1)
    rows_in = np.linspace(th_in, theta_edge_bottom(th_in), band_rows + 1)
    for phi_end, sign, name in ((s.phi_b, -1.0, "end_b"), (s.phi_a, 1.0, "end_a")):
        outer = r_out * sphere_dir(rows_out, np.full_like(rows_out, phi_end))
        inner = r_in * sphere_dir(rows_in, np.full_like(rows_in, phi_end))
        local = _lerp_rows(inner, outer, fractions).reshape(-1, 3)
        # The face bounds the material left beyond the cut, so it faces into the cut.
        e_phi = np.array([-math.sin(phi_end), math.cos(phi_end), 0.0])
        radial = np.array([math.cos(phi_end), math.sin(phi_end), 0.0])
        uv = np.stack([(local * radial).sum(1), local[:, 2]], -1)
        patches.append(
            make_patch(
                name,
                frame.to_world(local),
                np.tile(frame.dir_to_world(sign * e_phi), (len(local), 1)),
                grid_faces(len(rows_out), s.n_thick + 1),
                uv,
            )
        )
    return patches


def _lerp_rows(inner: np.ndarray, outer: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """Points from inner[i] to outer[i]; the end points are copied, not recomputed."""
    out = inner[:, None, :] * (1.0 - fractions)[None, :, None] + outer[:, None, :] * fractions[None, :, None]
    out[:, 0] = inner
    out[:, -1] = outer
    return out


def core_patches(params: ShaderballParams, frame: BandFrame, s: Sampling) -> list[Patch]:
    """The inner core: a band chart around the band's equator, cut on the back, and two caps."""
    radius = params.core_radius_m
    lat = math.radians(CORE_BAND_LATITUDE_DEG)
    cols = len(s.phi)
    # Seam of the band chart on the back (phi = +90 degrees, +y'), hidden behind the core.
    phi = 0.5 * math.pi + np.arange(cols) * (2.0 * math.pi / cols)
    phi_pos = np.concatenate([phi, phi[:1]])
    phi_unwrapped = np.concatenate([phi, [0.5 * math.pi + 2.0 * math.pi]])
    th_edge = 0.5 * math.pi - lat
    band_rows = n_steps(theta_edge_bottom(th_edge) - th_edge, s.step)
    kw = dict(inward=False, step=s.step)
    return [
        sphere_cap(frame, radius, th_edge, phi, bottom=False, name="core_top_cap", **kw),
        sphere_cap(frame, radius, th_edge, phi, bottom=True, name="core_bottom_cap", **kw),
        sphere_band(
            frame,
            radius,
            th_edge,
            theta_edge_bottom(th_edge),
            phi_pos,
            phi_unwrapped,
            inward=False,
            name="core_band",
            rows=band_rows,
        ),
    ]


def material_patches(params: ShaderballParams) -> list[Patch]:
    frame = band_frame(params)
    s = sampling(params)
    return shell_patches(params, frame, s) + core_patches(params, frame, s)


# --------------------------------------------------------------------------- neutral parts


def neutral_patches(params: ShaderballParams) -> list[Patch]:
    """Pedestal (side, chamfer, top) and the neck into the ball, each smooth, split at edges."""
    cols = params.segments
    cp, sp = cos_sin(np.arange(cols) * (2.0 * math.pi / cols))
    ring = np.stack([cp, sp, np.zeros(cols)], -1)
    up = np.array([0.0, 0.0, 1.0])
    rp, hp = params.pedestal_radius_m, params.pedestal_height_m
    chamfer = min(0.01, hp / 3.0, rp / 10.0)
    rn = params.neck_radius_m
    zc = params.ball_centre_z_m
    # The neck ends inside the shell's wall, so its end is never seen.
    z_neck_top = zc - 0.5 * (math.sqrt(params.shell_radius_m**2 - rn**2) + math.sqrt(params.inner_radius_m**2 - rn**2))

    def tube(radius_lo, z_lo, radius_hi, z_hi, normal_xy, normal_z, name):
        pos = np.concatenate([ring * radius_lo + z_lo * up, ring * radius_hi + z_hi * up])
        nrm = np.concatenate([ring * normal_xy + normal_z * up] * 2)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        return make_patch(name, pos, nrm, grid_faces(2, cols, periodic=True))

    top_rings = max(2, math.ceil((rp - chamfer) / (rp * 2.0 * math.pi / cols)))
    radii = np.linspace(0.0, rp - chamfer, top_rings + 1)[1:]
    top_pos = np.concatenate([[hp * up], (radii[:, None, None] * ring[None] + hp * up).reshape(-1, 3)])
    top = make_patch("pedestal_top", top_pos, np.tile(up, (len(top_pos), 1)), cap_faces(top_rings, cols))
    return [
        tube(rp, 0.0, rp, hp - chamfer, 1.0, 0.0, "pedestal_side"),
        tube(rp, hp - chamfer, rp - chamfer, hp, 1.0, 1.0, "pedestal_chamfer"),
        top,
        tube(rn, hp, rn, z_neck_top, 1.0, 0.0, "neck"),
    ]


def ground_patch(params: ShaderballParams) -> Patch:
    h = params.ground_half_size_m
    pos = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    nrm = np.tile([0.0, 0.0, 1.0], (4, 1))
    return make_patch("ground", pos, nrm, np.array([[0, 1, 2], [0, 2, 3]]))
