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
