"""Projective rectification (Klehm et al. 2014, §4.2).

One 4x4 matrix replaces the light's view-projection matrix so that a shadow
map rendered (or traced) with it is already rectified:

- every view ray maps to one row (its epipolar slice) and runs left to right,
- the depth is constant along every view ray,
- every light ray maps to one texel (so it *is* a shadow map),
- the camera frustum ``[near, far]`` fills ``[-1, 1]^3`` tightly.

Construction (light view space: origin at the eye, ``z`` along the frame's
axis toward the light, ``x`` the bisectrix of the camera frustum projected
along the light, ``y = z x x``), with ``c = (1 - z/L)/x`` (``L`` the light
distance, ``1/L = 0`` for a directional light), ``r = y/x``, ``g = -z/x``::

    column = A_c c + B_c      row = A_r r + B_r      depth = A_d g + B_d

which is a projective map with ``w = x`` ("a perspective projection along
x", Klehm §4.2).  ``r`` is constant on each plane through the axis (a slice),
``g`` is constant along each view ray ``t d`` and grows away from the light
along light rays, ``c`` decreases along view rays and is constant along
light rays (for a point light ``p_l + s w`` gives ``c = -w_z/(L w_x)``; the
``-z/L`` term is the extension of Klehm's directional construction to
point/spot lights: the plane ``x = 0`` sent to infinity contains both the eye
and the light).  ``A_c < 0`` so columns increase with distance from the eye.

It needs ``x > 0`` on the whole frustum, i.e. no view ray parallel to the
axis: the epipole (and anti-epipole) must be off screen, and Klehm falls
back to epipolar resampling when it is close ("easily detectable as distance
of the epipole to screen border").  :func:`projective_rectification` returns
``(None, reason)`` then; the threshold is the smallest angle between a view
ray and the axis (``min_angle_deg``).

Rows and columns of a directional light's map (:func:`projective_rows`,
:func:`projective_columns`, NumPy): rows equally spaced in NDC, as many as
keep every pixel within half a pixel of a row; columns equally spaced in
the column coordinate (1/x) within each of Klehm's splits.  The
``fourier_filter`` integrator traces the light ray of every texel instead
of rasterising the map.

Blockers between the light and the frustum project outside the depth range:
clamp their NDC depth to ``[-1, 1]`` when writing the map (Klehm's
``NV_DEPTH_CLAMP``, §4.1-4.2) so they still shadow the frustum.  Points
nearer to the eye than ``near`` fall outside the map (Klehm: "at most the
region from the camera to the camera's near plane is not accessible").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ._dr import const
from .epipole import EpipolarFrame
from .slices import Slices, exit_edges, uniform_edge_points, slice_lines

DEFAULT_MIN_ANGLE_DEG = 5.0


@dataclass(frozen=True, eq=False)
class ProjectiveRectification:
    matrix: np.ndarray      # (4, 4) world -> clip; ndc = clip[:3] / clip[3]
    view: np.ndarray        # (4, 4) world -> light view space (x bisectrix, z axis)
    near: float             # frustum depth range along the optical axis
    far: float
    min_angle_deg: float    # smallest angle between a frustum view ray and +-axis


def _frustum_corner_dirs(frame: EpipolarFrame) -> np.ndarray:
    cam = frame.camera
    return np.array([cam.forward + sx * cam.x_axis + sy * cam.y_axis
                     for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def _angle_to_arc(v, a, b) -> float:
    """Angle between unit v and the great-circle arc from a to b (< pi)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    n = np.cross(a, b)
    n = n / np.linalg.norm(n)
    p = v - (v @ n) * n
    if np.linalg.norm(p) > 1e-15 and np.cross(a, p) @ n >= 0 and np.cross(p, b) @ n >= 0:
        return math.atan2(abs(v @ n), np.linalg.norm(p))
    return min(math.acos(np.clip(v @ a, -1, 1)), math.acos(np.clip(v @ b, -1, 1)))


def frustum_axis_angle(frame: EpipolarFrame) -> float:
    """Smallest angle [deg] between a view ray of the image and the line of the
    camera-light axis (0 if the epipole or anti-epipole is on screen)."""
    if frame.in_image:
        return 0.0
    c = _frustum_corner_dirs(frame)
    best = math.pi
    for v in (frame.axis, -frame.axis):
        for i in range(4):
            best = min(best, _angle_to_arc(v, c[i], c[(i + 1) % 4]))
    return math.degrees(best)


def projective_rectification(frame: EpipolarFrame, far: float, near: float | None = None,
                             min_angle_deg: float = DEFAULT_MIN_ANGLE_DEG):
    """``(ProjectiveRectification, "ok")`` or ``(None, reason)`` when the
    epipolar resampling must be used instead."""
    near = frame.camera.near_clip if near is None else near
    if not (far > 0 and np.isfinite(far)):
        return None, f"far must be positive and finite, got {far}"
    if not near > 0:
        near = 1e-4 * far
    if not far > near:
        return None, f"far ({far}) must exceed near ({near})"
    if frame.in_image:
        what = "anti-epipole (light behind the camera)" if frame.case == "behind" else "epipole"
        return None, (f"{what} is on screen at ({frame.epipole[0]:.1f}, {frame.epipole[1]:.1f}) px: "
                      "some view rays are parallel to the light rays")
    angle = frustum_axis_angle(frame)
    if angle < min_angle_deg:
        return None, (f"epipole too close to the screen: view rays come within {angle:.2f} deg "
                      f"of the light direction (< {min_angle_deg} deg)")
    # bisectrix of the frustum projected along the axis (Klehm Fig. 4, top)
    c = _frustum_corner_dirs(frame)
    phi = np.sort(np.arctan2(c @ frame.b2, c @ frame.b1))
    gaps = np.diff(np.append(phi, phi[0] + 2 * np.pi))
    g = int(np.argmax(gaps))                 # the wedge is the complement of the largest gap
    lo = phi[(g + 1) % 4]
    span = 2 * np.pi - gaps[g]
    mid = lo + 0.5 * span
    x_l = math.cos(mid) * frame.b1 + math.sin(mid) * frame.b2
    z_l = frame.axis
    y_l = np.cross(z_l, x_l)
    R = np.stack([x_l, y_l, z_l])
    view = np.eye(4)
    view[:3, :3] = R
    view[:3, 3] = -R @ frame.camera.origin
    # frustum corners in light view space
    pts = np.concatenate([near * c, far * c]) @ R.T
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    inv_l = 0.0 if frame.is_directional else 1.0 / frame.light_distance
    cc, rr, gg = (1 - z * inv_l) / x, y / x, -z / x

    def affine(v, flip=False):
        lo_, hi_ = float(v.min()), float(v.max())
        d = max(hi_ - lo_, 1e-12)
        a, b = 2 / d, -(hi_ + lo_) / d
        return (-a, -b) if flip else (a, b)

    A_c, B_c = affine(cc, flip=True)          # column grows with distance from the eye
    A_r, B_r = affine(rr)
    A_d, B_d = affine(gg)
    P = np.array([[B_c, 0.0, -A_c * inv_l, A_c],
                  [B_r, A_r, 0.0, 0.0],
                  [B_d, 0.0, -A_d, 0.0],
                  [1.0, 0.0, 0.0, 0.0]])
    return ProjectiveRectification(matrix=P @ view, view=view, near=float(near), far=float(far),
                                   min_angle_deg=angle), "ok"


def projective_apply_reference(rect: ProjectiveRectification, p) -> np.ndarray:
    """World point(s) (..., 3) -> (column, row, depth) in NDC (..., 3)."""
    p = np.asarray(p, dtype=np.float64)
    h = np.concatenate([p, np.ones(p.shape[:-1] + (1,))], axis=-1) @ rect.matrix.T
    return h[..., :3] / h[..., 3:]


def projective_apply(rect: ProjectiveRectification, p: mi.Point3f) -> mi.Point3f:
    """Dr.Jit version of :func:`projective_apply_reference`."""
    m = rect.matrix
    rows = [dr.fma(const(m[i, 0]), p.x, dr.fma(const(m[i, 1]), p.y,
                                               dr.fma(const(m[i, 2]), p.z, const(m[i, 3]))))
            for i in range(4)]
    inv_w = dr.rcp(rows[3])
    return mi.Point3f(rows[0] * inv_w, rows[1] * inv_w, rows[2] * inv_w)


# --------------------------------------------------------------------------
# Rows and columns of a projectively rectified shadow map (directional light)
# --------------------------------------------------------------------------
#
# In light view space (x the bisectrix, z the axis) the matrix's row is
# ``A_r r + B_r`` with ``r = y/x = tan(alpha - alpha_mid)``: a row is a slice
# (alpha), and rows equally spaced in NDC are equally spaced in tan(alpha -
# alpha_mid) -- for an epipole far off screen, about equally spaced on
# screen.  A directional light's column is ``A_c / x + B_c``: constant on a
# light ray, and texels equally spaced in NDC are equally spaced in 1/x
# (the "depth-buffer" non-linearity of §4.2).  On the light ray of row r at
# ``x`` the distance from the axis is ``gamma = x sqrt(1 + r^2)``: every row
# has the same texel edges in x, scaled by its own 1/cos(phi).

#: spacing [px] of the border probes that place and count the rows
ROW_PROBE_PX = 0.25
#: automatic splits: each spans at most this ratio x_hi/x_lo (Klehm §4.2 splits)
SPLIT_RATIO = 2.0
#: texels per split ∝ (split length)^SPLIT_TEXEL_POWER.  Measured (fourier_filter,
#: weights=exact, relMSE against raymarch exact): 0 (Klehm's equal resolution,
#: log-spaced texels) is 1.4-4x the epipolar path's error on the test scenes,
#: 1 (even density) 0.9-1.2x and 1.2x on the nave, 0.5 0.8-1.2x and 1.0x
SPLIT_TEXEL_POWER = 0.5


def light_projection(rect: ProjectiveRectification) -> np.ndarray:
    """P (4, 4) with ``rect.matrix = P @ rect.view``: light view space -> clip."""
    return rect.matrix @ np.linalg.inv(rect.view)


def bisectrix_alpha(frame: EpipolarFrame, rect: ProjectiveRectification) -> float:
    """alpha of the bisectrix x_l (the slice with r = 0)."""
    x_l = rect.view[0, :3]
    return math.atan2(float(x_l @ frame.b2), float(x_l @ frame.b1))


def row_ndc(rect: ProjectiveRectification, r) -> np.ndarray:
    """NDC row of the slices with r = tan(alpha - alpha_mid)."""
    P = light_projection(rect)
    return P[1, 0] + P[1, 1] * np.asarray(r, np.float64)


def row_tangent(rect: ProjectiveRectification, ndc) -> np.ndarray:
    """Inverse of :func:`row_ndc`."""
    P = light_projection(rect)
    return (np.asarray(ndc, np.float64) - P[1, 0]) / P[1, 1]


@dataclass(frozen=True, eq=False)
class ProjectiveRows:
    """The rows of a projectively rectified map: row ``k`` is slice ``k`` of
    ``slices`` (sorted by alpha), at NDC row ``ndc[k]`` (equally spaced
    from -1 to 1) and ``r[k] = tan(alpha_k - alpha_mid)``."""
    slices: Slices
    ndc: np.ndarray
    r: np.ndarray
    alpha_mid: float

    @property
    def count(self) -> int:
        return self.slices.count

    @property
    def inv_cos(self) -> np.ndarray:
        """1/cos(phi) = sqrt(1 + r^2): gamma = x / cos(phi) on row k."""
        return np.sqrt(1.0 + self.r ** 2)


def _border_probes(frame: EpipolarFrame, rect: ProjectiveRectification):
    """(points (P, 2), r (P,)) of points at most ``ROW_PROBE_PX`` apart
    along the exit edges (corners included), sorted by r (duplicated
    corners dropped)."""
    pts = np.concatenate([uniform_edge_points(P0, P1, ROW_PROBE_PX)
                          for P0, P1, _, _ in exit_edges(frame)])
    d = frame.camera.direction(pts[:, 0], pts[:, 1])
    r = (d @ rect.view[1, :3]) / (d @ rect.view[0, :3])
    order = np.argsort(r, kind="stable")
    pts, r = pts[order], r[order]
    keep = np.append(True, np.diff(r) > 1e-12 * max(1.0, float(np.abs(r).max())))
    return pts[keep], r[keep]


def projective_row_count(frame: EpipolarFrame, rect: ProjectiveRectification,
                         probes=None) -> int:
    """Fewest rows, equally spaced in NDC, whose image lines are at most one
    pixel apart along the exit edges (measured across the lines, as Baran's
    §8 sinh slices are): every pixel centre is then within half a pixel of
    a row.  The probes' largest line spacing per unit r sets the step."""
    pts, r = probes if probes is not None else _border_probes(frame, rect)
    lines = slice_lines(frame, Slices(np.zeros(len(pts)), pts, False, "probe"))
    sep = np.abs(np.einsum("ij,ij->i", np.diff(pts, axis=0), lines.normal[:-1]))
    dr_ = np.diff(r)
    ok = sep > 1e-9
    step = float(np.min(dr_[ok] / sep[ok])) if np.any(ok) else float(r[-1] - r[0])
    return max(2, int(math.ceil((r[-1] - r[0]) / max(step, 1e-300) - 1e-9)) + 1)


def projective_rows(frame: EpipolarFrame, rect: ProjectiveRectification,
                    count: int = 0) -> ProjectiveRows:
    """``count`` rows (0: :func:`projective_row_count`) equally spaced in
    NDC over the image's range of r, with their end points on the exit
    edges (exactly: r is a ratio of affine functions along an edge)."""
    pts, r = probes = _border_probes(frame, rect)
    n = int(count) if count > 0 else projective_row_count(frame, rect, probes)
    n = max(n, 2)
    r_rows = np.linspace(r[0], r[-1], n)
    i = np.clip(np.searchsorted(r, r_rows, side="right") - 1, 0, len(r) - 2)
    P0, P1 = pts[i], pts[i + 1]
    d0 = frame.camera.direction(P0[:, 0], P0[:, 1])
    d1 = frame.camera.direction(P1[:, 0], P1[:, 1])
    x_l, y_l = rect.view[0, :3], rect.view[1, :3]
    # r(s) = (y0 + s (y1 - y0)) / (x0 + s (x1 - x0)) on the segment P0 -> P1
    x0, x1, y0, y1 = d0 @ x_l, d1 @ x_l, d0 @ y_l, d1 @ y_l
    den = (y1 - y0) - r_rows * (x1 - x0)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(np.abs(den) > 1e-300, (r_rows * x0 - y0) / den, 0.0)
    s = np.clip(np.nan_to_num(s), 0.0, 1.0)
    points = P0 + s[:, None] * (P1 - P0)
    a_mid = bisectrix_alpha(frame, rect)
    alpha = np.angle(np.exp(1j * (a_mid + np.arctan(r_rows))))
    if np.any(np.diff(alpha) <= 0):
        raise ValueError("projective rows: the image's slices cross alpha = pi "
                         "(cannot happen with the epipole off screen)")
    return ProjectiveRows(Slices(alpha, points, False, "projective"), row_ndc(rect, r_rows),
                          r_rows, a_mid)


def auto_splits(x_lo: float, x_hi: float, ratio: float = SPLIT_RATIO) -> int:
    """Splits of [x_lo, x_hi] (geometric) spanning at most ``ratio`` each."""
    if not (x_hi > x_lo > 0):
        return 1
    return max(1, int(math.ceil(math.log(x_hi / x_lo) / math.log(ratio) - 1e-9)))


@dataclass(frozen=True, eq=False)
class ProjectiveColumns:
    """Texel edges along every row of a directional light's projective map,
    in x (the distance along the bisectrix; gamma = x / cos(phi) on a row).

    Klehm §4.2's splits: ``[x_lo, x_hi]`` is cut at ``split_x`` (geometric,
    growing from left to right), and each split is a projective map of its
    own (equal texels in 1/x, ``texels[j]`` of them) -- the column of
    texel ``k`` of split ``j`` is ``A_j / x + B_j``."""
    edges: np.ndarray      # (d + 1,) x of the texel edges, increasing
    centres: np.ndarray    # (d,) x of the light ray through each texel centre (middle in 1/x)
    split_x: np.ndarray    # (S + 1,) x of the split boundaries
    texels: np.ndarray     # (S,) texels per split

    @property
    def d(self) -> int:
        return len(self.centres)


def projective_columns(x_lo: float, x_hi: float, d: int, splits: int = 1,
                       power: float = SPLIT_TEXEL_POWER) -> ProjectiveColumns:
    """``d`` texels over ``[x_lo, x_hi]`` (0 < x_lo < x_hi) in ``splits``
    geometric splits, each with equal steps in 1/x (its own projective
    column map).  Split ``j`` gets texels in proportion to its length to the
    power ``power`` (at least one): 0 is Klehm's equal resolution per split
    (texel widths then grow like x: a log spacing), 1 an even density
    (:data:`SPLIT_TEXEL_POWER`)."""
    if not (x_hi > x_lo > 0 and np.isfinite(x_hi)):
        raise ValueError(f"projective columns need 0 < x_lo < x_hi, got {x_lo}, {x_hi}")
    splits = int(max(1, min(splits, d)))
    split_x = x_lo * (x_hi / x_lo) ** (np.arange(splits + 1) / splits)
    split_x[0], split_x[-1] = x_lo, x_hi
    texels = share_texels(np.diff(split_x) ** power, d)
    edges, centres = [], []
    for j in range(splits):
        c = np.linspace(1.0 / split_x[j], 1.0 / split_x[j + 1], texels[j] + 1)
        edges.append(1.0 / c[:-1])
        centres.append(2.0 / (c[:-1] + c[1:]))
    edges = np.append(np.concatenate(edges), x_hi)
    return ProjectiveColumns(edges, np.concatenate(centres), split_x, texels)


def share_texels(weights, d: int) -> np.ndarray:
    """``d`` texels shared out in proportion to ``weights`` (largest
    remainders), at least one each."""
    w = np.asarray(weights, np.float64)
    n = len(w)
    if d < n:
        raise ValueError(f"{d} texels cannot fill {n} splits")
    ideal = d * w / w.sum()
    m = np.maximum(np.floor(ideal).astype(int), 1)
    while m.sum() > d:                       # the minimum of one took too many
        over = np.where(m > 1, m - ideal, -np.inf)
        m[int(np.argmax(over))] -= 1
    rest = d - int(m.sum())
    m[np.argsort(-(ideal - m), kind="stable")[:rest]] += 1
    return m
