"""The epipolar frame of a camera and a light (Baran et al. 2010, §3 and §9).

All slices (Baran's "epipolar slices") are half-planes bounded by the
*camera-light axis*: the line through the eye point ``o`` along ``axis``, the
unit vector from the camera toward the light:

- directional light: ``axis = w_l``, the direction *toward* the light (from the
  scene to the sun).  Mitsuba's ``directional`` emitter stores the opposite
  (the direction the light travels): pass ``-emitter_direction``;
- point / spot light at ``p_l``: ``axis = (p_l - o) / |p_l - o|``.

The image of the axis is the *epipole*: the vanishing point of ``axis``
(directional light: the image of the sun; point light: the projection of
``p_l``).  Its :attr:`EpipolarFrame.case` is one of

``on_screen``   in front of the camera, inside the closed image rectangle;
``off_screen``  in front of the camera, outside the image;
``at_infinity`` ``axis`` (nearly) parallel to the image plane: the epipolar
                lines are parallel, along :attr:`EpipolarFrame.direction`;
``behind``      the light is behind the camera: the epipolar lines converge on
                the *anti-epipole*, the image of ``-axis`` (for a directional
                light the anti-solar point, where the shafts of direction
                ``-w_l`` converge); :attr:`EpipolarFrame.in_image` tells
                whether it is on screen.

:attr:`EpipolarFrame.epipole` is always the finite pixel position the lines
converge on (epipole, or anti-epipole when ``behind``); at infinity it is a
far-away stand-in ``centre + FAR_PX * direction``.  :attr:`epipole_h` is the
same point in homogeneous pixel coordinates ``(X, Y, W)``, ``W >= 0``,
``W = 0`` exactly at infinity: code that must be exact at infinity (slice
lines) uses it.

The orthonormal basis ``(b1, b2, axis)`` defines Baran's slice angle
``alpha = atan2(q.b2, q.b1)`` of a point ``o + q``; ``b1`` is the part of the
optical axis orthogonal to ``axis``, so ``alpha = 0`` is the slice through the
image centre and the visible ``alpha`` of an off-screen epipole form one
interval inside ``(-pi, pi)`` (see :mod:`rectify.coords`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rectify.camera import CameraParams

CASES = ("on_screen", "off_screen", "at_infinity", "behind")
LIGHT_KINDS = ("directional", "point", "spot")

#: |axis . forward| at or below which the epipole is treated as at infinity
#: (the finite epipole would be ~1e9 image widths away).
INFINITY_EPS = 1e-9
#: distance [px] of the stand-in epipole used when it is at infinity.
FAR_PX = 1e9


@dataclass(frozen=True)
class LightGeometry:
    """Where a light is, as far as the epipolar geometry cares.

    ``kind`` is ``directional`` (give ``direction``: unit vector *toward* the
    light) or ``point``/``spot`` (give ``position``).
    """
    kind: str
    direction: tuple | None = None
    position: tuple | None = None

    @staticmethod
    def coerce(light: Any) -> "LightGeometry":
        """Accept a LightGeometry, a ``(kind, vector)`` pair, a mapping with
        ``kind`` and ``direction``/``position``, or any object with those
        attributes (duck typing, e.g. the scene parameters of a light)."""
        if isinstance(light, LightGeometry):
            return light
        if isinstance(light, (tuple, list)) and len(light) == 2 and isinstance(light[0], str):
            kind, vec = light
            vec = tuple(np.asarray(vec, dtype=np.float64).tolist())
            return (LightGeometry(kind, direction=vec) if kind == "directional"
                    else LightGeometry(kind, position=vec))
        get = light.get if isinstance(light, dict) else (lambda k, d=None: getattr(light, k, d))
        kind = get("kind")
        d, p = get("direction"), get("position")
        return LightGeometry(
            kind,
            direction=None if d is None else tuple(np.asarray(d, dtype=np.float64).tolist()),
            position=None if p is None else tuple(np.asarray(p, dtype=np.float64).tolist()))


@dataclass(frozen=True, eq=False)
class EpipolarFrame:
    """Camera + light epipolar geometry (build with :func:`epipolar_frame`)."""
    camera: CameraParams
    light_kind: str               # directional | point | spot
    axis: np.ndarray              # (3,) unit, from the eye toward the light
    light_position: np.ndarray | None   # (3,) point/spot, None for directional
    light_distance: float | None  # |p_l - o| for point/spot, None for directional
    b1: np.ndarray                # (3,) unit, orthogonal to axis; alpha = 0
    b2: np.ndarray                # (3,) unit, axis x b1; alpha = pi/2
    case: str                     # one of CASES
    epipole: np.ndarray           # (2,) finite pixel position the lines converge on
    epipole_h: np.ndarray         # (3,) same in homogeneous pixels, unit norm, W >= 0
    direction: np.ndarray         # (2,) unit image direction centre -> epipole (lines' direction at infinity)
    in_image: bool                # epipole inside the closed image rectangle
    wraps: bool                   # epipole strictly inside: slices go all the way round

    @property
    def width(self) -> int:
        return self.camera.width

    @property
    def height(self) -> int:
        return self.camera.height

    @property
    def is_directional(self) -> bool:
        return self.light_kind == "directional"

    @property
    def at_infinity(self) -> bool:
        return self.case == "at_infinity"

    @property
    def converge_sign(self) -> float:
        """+1 if the epipolar lines converge on the image of ``axis``, -1 if on
        the image of ``-axis`` (light behind the camera)."""
        return -1.0 if self.case == "behind" else 1.0


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n == 0.0:
        raise ValueError(f"expected a non-zero finite vector, got {v!r}")
    return v / n


def _perp_basis(axis: np.ndarray, camera: CameraParams):
    """b1: the optical axis made orthogonal to ``axis`` (fallbacks: the film's
    x axis, then any vector), b2 = axis x b1."""
    for cand in (camera.forward, camera.x_axis, camera.y_axis,
                 np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
        c = np.asarray(cand, dtype=np.float64)
        c = c / np.linalg.norm(c)
        p = c - (c @ axis) * axis
        n = float(np.linalg.norm(p))
        if n > 1e-6:
            b1 = p / n
            break
    b2 = np.cross(axis, b1)
    return b1, b2 / np.linalg.norm(b2)


def _homogeneous_epipole(camera: CameraParams, axis: np.ndarray):
    """(X, Y, W) with W >= 0 of the image of +axis (or of -axis if behind)."""
    f = np.asarray(camera.forward, dtype=np.float64)
    z = float(axis @ f)
    if abs(z) <= INFINITY_EPS:
        v, case = axis, "at_infinity"
    elif z > 0.0:
        v, case = axis, None
    else:
        v, case = -axis, "behind"
    xa = np.asarray(camera.x_axis, dtype=np.float64)
    ya = np.asarray(camera.y_axis, dtype=np.float64)
    a = float(v @ xa) / float(xa @ xa)
    b = float(v @ ya) / float(ya @ ya)
    w = 0.0 if case == "at_infinity" else abs(z)
    h = np.array([0.5 * (a + w) * camera.width, 0.5 * (b + w) * camera.height, w])
    return h / np.linalg.norm(h), case


def _make_frame(camera: CameraParams, kind: str, axis: np.ndarray,
                position: np.ndarray | None, distance: float | None) -> EpipolarFrame:
    b1, b2 = _perp_basis(axis, camera)
    eh, case = _homogeneous_epipole(camera, axis)
    W, H = camera.width, camera.height
    centre = np.array([0.5 * W, 0.5 * H])
    if case == "at_infinity":
        direction = eh[:2] / np.linalg.norm(eh[:2])
        epipole = centre + FAR_PX * direction
        in_image = wraps = False
    else:
        epipole = eh[:2] / eh[2]
        off = epipole - centre
        n = float(np.linalg.norm(off))
        direction = off / n if n > 0 else np.array([1.0, 0.0])
        ex, ey = epipole
        in_image = bool(0.0 <= ex <= W and 0.0 <= ey <= H)
        wraps = bool(0.0 < ex < W and 0.0 < ey < H)
        if case is None:
            case = "on_screen" if in_image else "off_screen"
    return EpipolarFrame(camera=camera, light_kind=kind, axis=axis,
                         light_position=position, light_distance=distance,
                         b1=b1, b2=b2, case=case, epipole=epipole, epipole_h=eh,
                         direction=direction, in_image=in_image, wraps=wraps)


def directional_frame(camera: CameraParams, w_l) -> EpipolarFrame:
    """Frame of a directional light; ``w_l`` points *toward* the light."""
    return _make_frame(camera, "directional", _unit(w_l), None, None)


def point_frame(camera: CameraParams, p_l, kind: str = "point") -> EpipolarFrame:
    """Frame of a point (or spot) light at ``p_l`` (Baran §9).

    A light at the eye point itself has no epipolar geometry; the axis then
    falls back to the optical axis (and the distance to a tiny positive value)
    so that nothing downstream divides by zero.
    """
    p = np.asarray(p_l, dtype=np.float64)
    q = p - np.asarray(camera.origin, dtype=np.float64)
    dist = float(np.linalg.norm(q))
    if not np.isfinite(dist):
        raise ValueError(f"light position must be finite, got {p_l!r}")
    scale = max(1.0, float(np.linalg.norm(camera.origin)))
    if dist <= 1e-12 * scale:
        axis, dist = _unit(camera.forward), 1e-12 * scale
    else:
        axis = q / dist
    return _make_frame(camera, kind, axis, p, dist)


def epipolar_frame(camera: CameraParams, light) -> EpipolarFrame:
    """Frame of ``camera`` and ``light`` (anything :meth:`LightGeometry.coerce`
    accepts)."""
    lg = LightGeometry.coerce(light)
    if lg.kind not in LIGHT_KINDS:
        raise ValueError(f"unsupported light kind {lg.kind!r}; expected one of {LIGHT_KINDS}")
    if lg.kind == "directional":
        if lg.direction is None:
            raise ValueError("a directional light needs `direction` (unit vector toward the light)")
        return directional_frame(camera, lg.direction)
    if lg.position is None:
        raise ValueError(f"a {lg.kind} light needs `position`")
    return point_frame(camera, lg.position, kind=lg.kind)


def make_camera(origin, forward, up=(0.0, 1.0, 0.0), fov_x_deg: float = 60.0,
                width: int = 64, height: int = 48, near_clip: float = 1e-2) -> CameraParams:
    """A pinhole camera with square pixels looking along ``forward`` (for tests,
    experiments and examples; scenes use ``CameraParams.from_mitsuba``)."""
    f = _unit(forward)
    up = np.asarray(up, dtype=np.float64)
    right = np.cross(f, up)          # (right, down, forward) is right-handed
    if np.linalg.norm(right) < 1e-9:
        right = np.cross(f, np.array([1.0, 0.0, 0.0]) if abs(f[0]) < 0.9
                         else np.array([0.0, 0.0, 1.0]))
    right = right / np.linalg.norm(right)
    down = np.cross(f, right)        # film y grows downwards
    tx = math.tan(math.radians(fov_x_deg) / 2)
    ty = tx * height / width
    return CameraParams(origin=np.asarray(origin, dtype=np.float64), forward=f,
                        x_axis=right * tx, y_axis=down * ty, width=int(width),
                        height=int(height), near_clip=near_clip)
