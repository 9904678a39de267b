"""Rectified coordinates (alpha, beta, gamma) of Baran et al. 2010, §3 and §9.

Notation (``o`` eye point, ``q = p - o``, ``(b1, b2, axis)`` the frame's
orthonormal basis, ``axis`` from the eye toward the light):

``alpha``  slice: the angle of the half-plane bounded by the camera-light axis
           that contains ``p``, ``alpha = atan2(q.b2, q.b1)`` in ``(-pi, pi]``.
``beta``   view ray: the angle between the view ray through ``p`` and the
           light direction ``axis``, ``beta = angle(q, axis)`` in ``[0, pi]``
           (§3: an angle, not a screen distance, so every slice has the same
           geometry).  ``(alpha, beta)`` are spherical coordinates of the view
           direction with the pole at the epipole.
``t``      distance from the eye along the view ray: ``p = o + t d(alpha, beta)``
           with ``d = sin(beta) (cos(alpha) b1 + sin(alpha) b2) + cos(beta) axis``.

Light side, directional light (§3): ``gamma`` = distance from the light ray
through ``p`` to the eye point (= to the axis), ``gamma = t sin(beta)``, and
``u = q.axis = t cos(beta) = gamma cot(beta)`` the signed coordinate along the
light direction (growing toward the light).  ``(alpha, gamma, u)`` are
cylindrical coordinates around the axis.

Light side, point/spot light at ``p_l`` (§9): ``gamma`` = the angle the light
ray ``p_l -> p`` makes with the direction from the light to the camera
(``-axis``), in ``[0, pi]``; ``u = |p - p_l|`` the distance from the light.
``(alpha, gamma, u)`` are spherical coordinates around ``p_l``.  With
``L = |p_l - o|``, the view ray ``beta`` and the light ray ``gamma`` of a slice
meet at ``t = L sin(gamma) / sin(beta + gamma)`` (if ``beta + gamma < pi``).

Every fast function takes/returns Dr.Jit arrays of the active variant; its
``*_reference`` twin is the plain float64 NumPy definition the tests compare
against.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ._dr import const, vec3
from .epipole import EpipolarFrame

# --------------------------------------------------------------------------
# NumPy references (float64, written from the definitions)
# --------------------------------------------------------------------------


def _angle(v, w):
    """Angle between vector(s) v (..., 3) and unit w (accurate near 0 and pi)."""
    return np.arctan2(np.linalg.norm(np.cross(v, w), axis=-1), v @ w)


def direction_to_alpha_beta_reference(frame: EpipolarFrame, d):
    """(alpha, beta) of direction(s) ``d`` (..., 3), any length."""
    d = np.asarray(d, dtype=np.float64)
    alpha = np.arctan2(d @ frame.b2, d @ frame.b1)
    return alpha, _angle(d, frame.axis)


def alpha_beta_to_direction_reference(frame: EpipolarFrame, alpha, beta):
    """Unit direction(s) (..., 3) of slice ``alpha`` at angle ``beta`` from the axis."""
    alpha = np.asarray(alpha, dtype=np.float64)[..., None]
    beta = np.asarray(beta, dtype=np.float64)[..., None]
    return (np.sin(beta) * (np.cos(alpha) * frame.b1 + np.sin(alpha) * frame.b2)
            + np.cos(beta) * frame.axis)


def pixel_to_alpha_beta_reference(frame: EpipolarFrame, x, y):
    return direction_to_alpha_beta_reference(frame, frame.camera.direction(x, y))


def alpha_beta_to_pixel_reference(frame: EpipolarFrame, alpha, beta):
    """(x, y, z): film position [px] of the view ray, z = its forward component
    (z <= 0: the ray does not reach the film; x, y are then meaningless)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return frame.camera.project_direction(alpha_beta_to_direction_reference(frame, alpha, beta))


def world_to_view_coords_reference(frame: EpipolarFrame, p):
    """World point(s) (..., 3) -> (alpha, beta, t)."""
    q = np.asarray(p, dtype=np.float64) - frame.camera.origin
    alpha, beta = direction_to_alpha_beta_reference(frame, q)
    return alpha, beta, np.linalg.norm(q, axis=-1)


def view_coords_to_world_reference(frame: EpipolarFrame, alpha, beta, t):
    d = alpha_beta_to_direction_reference(frame, alpha, beta)
    return frame.camera.origin + np.asarray(t, dtype=np.float64)[..., None] * d


def world_to_light_coords_reference(frame: EpipolarFrame, p):
    """World point(s) -> (alpha, gamma, u); see the module docstring."""
    p = np.asarray(p, dtype=np.float64)
    q = p - frame.camera.origin
    alpha = np.arctan2(q @ frame.b2, q @ frame.b1)
    if frame.is_directional:
        u = q @ frame.axis
        gamma = np.linalg.norm(q - u[..., None] * frame.axis, axis=-1)
        return alpha, gamma, u
    w = p - frame.light_position               # from the light to p
    return alpha, _angle(w, -frame.axis), np.linalg.norm(w, axis=-1)


def light_coords_to_world_reference(frame: EpipolarFrame, alpha, gamma, u):
    alpha = np.asarray(alpha, dtype=np.float64)[..., None]
    gamma = np.asarray(gamma, dtype=np.float64)[..., None]
    u = np.asarray(u, dtype=np.float64)[..., None]
    perp = np.cos(alpha) * frame.b1 + np.sin(alpha) * frame.b2
    if frame.is_directional:
        return frame.camera.origin + gamma * perp + u * frame.axis
    return frame.light_position + u * (np.sin(gamma) * perp - np.cos(gamma) * frame.axis)


def view_to_light_reference(frame: EpipolarFrame, alpha, beta, t):
    """(alpha, beta, t) -> (gamma, u), via the world point."""
    _, gamma, u = world_to_light_coords_reference(
        frame, view_coords_to_world_reference(frame, alpha, beta, t))
    return gamma, u


def light_to_view_reference(frame: EpipolarFrame, alpha, gamma, u):
    """(alpha, gamma, u) -> (beta, t), via the world point."""
    _, beta, t = world_to_view_coords_reference(
        frame, light_coords_to_world_reference(frame, alpha, gamma, u))
    return beta, t


def ray_meeting_t_reference(frame: EpipolarFrame, beta, gamma):
    """Distance t along view ray ``beta`` to light ray ``gamma`` (same slice),
    by intersecting the two lines in the slice plane; (t, valid)."""
    beta = np.atleast_1d(np.asarray(beta, dtype=np.float64))
    gamma = np.atleast_1d(np.asarray(gamma, dtype=np.float64))
    beta, gamma = np.broadcast_arrays(beta, gamma)
    t = np.zeros(beta.shape)
    valid = np.zeros(beta.shape, dtype=bool)
    for i in np.ndindex(beta.shape):
        view = np.array([np.cos(beta[i]), np.sin(beta[i])])      # (along axis, perp)
        if frame.is_directional:
            start, light = np.array([0.0, gamma[i]]), np.array([1.0, 0.0])
        else:
            start = np.array([frame.light_distance, 0.0])
            light = np.array([-np.cos(gamma[i]), np.sin(gamma[i])])
        m = np.column_stack([view, -light])                       # t*view = start + s*light
        if abs(np.linalg.det(m)) < 1e-14:
            continue
        ts, s = np.linalg.solve(m, start)
        if ts > 0 and (s >= 0 or frame.is_directional):
            t[i], valid[i] = ts, True
    return t, valid


# --------------------------------------------------------------------------
# Dr.Jit (active variant)
# --------------------------------------------------------------------------


def _basis(frame: EpipolarFrame):
    return vec3(frame.b1), vec3(frame.b2), vec3(frame.axis)


def direction_to_alpha_beta(frame: EpipolarFrame, d: mi.Vector3f):
    """(alpha, beta) of (unnormalised) directions ``d``."""
    b1, b2, ax = _basis(frame)
    q1, q2, qa = dr.dot(d, b1), dr.dot(d, b2), dr.dot(d, ax)
    alpha = dr.atan2(q2, q1)
    beta = dr.atan2(dr.sqrt(dr.fma(q1, q1, q2 * q2)), qa)
    return alpha, beta


def alpha_beta_to_direction(frame: EpipolarFrame, alpha, beta) -> mi.Vector3f:
    b1, b2, ax = _basis(frame)
    sa, ca = dr.sincos(mi.Float(alpha))
    sb, cb = dr.sincos(mi.Float(beta))
    return sb * (ca * b1 + sa * b2) + cb * ax


def film_direction(frame: EpipolarFrame, x, y) -> mi.Vector3f:
    """Unnormalised world direction through film position (x, y) [px]."""
    cam = frame.camera
    u = mi.Float(x) * const(2.0 / cam.width) - 1.0
    v = mi.Float(y) * const(2.0 / cam.height) - 1.0
    return vec3(cam.forward) + u * vec3(cam.x_axis) + v * vec3(cam.y_axis)


def pixel_to_alpha_beta(frame: EpipolarFrame, x, y):
    return direction_to_alpha_beta(frame, film_direction(frame, x, y))


def project_direction(frame: EpipolarFrame, d: mi.Vector3f):
    """(x, y, z) film position [px] of direction ``d`` and its forward
    component z; finite everywhere (x, y meaningless where z <= 0)."""
    cam = frame.camera
    xa, ya = np.asarray(cam.x_axis), np.asarray(cam.y_axis)
    z = dr.dot(d, vec3(cam.forward))
    zs = dr.select(dr.abs(z) > 1e-20, z, 1e-20)
    a = dr.dot(d, vec3(xa / (xa @ xa))) / zs
    b = dr.dot(d, vec3(ya / (ya @ ya))) / zs
    return (a + 1.0) * const(0.5 * cam.width), (b + 1.0) * const(0.5 * cam.height), z


def alpha_beta_to_pixel(frame: EpipolarFrame, alpha, beta):
    return project_direction(frame, alpha_beta_to_direction(frame, alpha, beta))


def world_to_view_coords(frame: EpipolarFrame, p: mi.Point3f):
    """World points -> (alpha, beta, t)."""
    q = mi.Vector3f(p - vec3(frame.camera.origin))
    alpha, beta = direction_to_alpha_beta(frame, q)
    return alpha, beta, dr.norm(q)


def view_coords_to_world(frame: EpipolarFrame, alpha, beta, t) -> mi.Point3f:
    return mi.Point3f(vec3(frame.camera.origin) + mi.Float(t) * alpha_beta_to_direction(frame, alpha, beta))


def world_to_light_coords(frame: EpipolarFrame, p: mi.Point3f):
    """World points -> (alpha, gamma, u)."""
    b1, b2, ax = _basis(frame)
    q = mi.Vector3f(p - vec3(frame.camera.origin))
    q1, q2, qa = dr.dot(q, b1), dr.dot(q, b2), dr.dot(q, ax)
    alpha = dr.atan2(q2, q1)
    rho = dr.sqrt(dr.fma(q1, q1, q2 * q2))       # distance from the axis
    if frame.is_directional:
        return alpha, rho, qa
    # from the light: along -axis the light is at (L - qa), across at rho
    along = const(frame.light_distance) - qa
    return alpha, dr.atan2(rho, along), dr.sqrt(dr.fma(along, along, rho * rho))


def light_coords_to_world(frame: EpipolarFrame, alpha, gamma, u) -> mi.Point3f:
    b1, b2, ax = _basis(frame)
    sa, ca = dr.sincos(mi.Float(alpha))
    perp = ca * b1 + sa * b2
    gamma, u = mi.Float(gamma), mi.Float(u)
    if frame.is_directional:
        return mi.Point3f(vec3(frame.camera.origin) + gamma * perp + u * ax)
    sg, cg = dr.sincos(gamma)
    return mi.Point3f(vec3(frame.light_position) + u * (sg * perp - cg * ax))


def view_to_light(frame: EpipolarFrame, alpha, beta, t):
    """(alpha, beta, t) -> (gamma, u) within the slice (alpha is unchanged)."""
    sb, cb = dr.sincos(mi.Float(beta))
    t = mi.Float(t)
    along, rho = t * cb, t * sb                    # 2-D slice coordinates
    if frame.is_directional:
        return rho, along
    along = const(frame.light_distance) - along
    return dr.atan2(rho, along), dr.sqrt(dr.fma(along, along, rho * rho))


def light_to_view(frame: EpipolarFrame, alpha, gamma, u):
    """(alpha, gamma, u) -> (beta, t) within the slice."""
    gamma, u = mi.Float(gamma), mi.Float(u)
    if frame.is_directional:
        along, rho = u, gamma
    else:
        sg, cg = dr.sincos(gamma)
        along, rho = const(frame.light_distance) - u * cg, u * sg
    return dr.atan2(rho, along), dr.sqrt(dr.fma(along, along, rho * rho))


def ray_meeting_t(frame: EpipolarFrame, beta, gamma):
    """Distance along view ray ``beta`` to light ray ``gamma`` of the same
    slice and whether they meet: directional ``t = gamma / sin(beta)``,
    point ``t = L sin(gamma) / sin(beta + gamma)``.  t = 0 where invalid."""
    beta, gamma = mi.Float(beta), mi.Float(gamma)
    if frame.is_directional:
        num, den = gamma, dr.sin(beta)
    else:
        num, den = const(frame.light_distance) * dr.sin(gamma), dr.sin(beta + gamma)
    valid = (den > 0) & (num >= 0)
    return dr.select(valid, num / dr.select(valid, den, 1.0), 0.0), valid
