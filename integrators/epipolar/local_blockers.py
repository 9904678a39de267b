"""Blocker angles of a point or spot light's light rays, traced from the
light or resampled from a perspective shadow map (Baran et al. 2010 §9).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from rectify.coords import direction_to_alpha_beta

from ..core.light_transport import first_blocker, point, scalar
from .blockers import sub_ray_gamma
from .light_rays.local import LocalLightRays, light_ray_direction
from .queries import EpipolarQueries


# --------------------------------------------------------------------------
# Blocker maps S[α, γ] (§3, §7, §9)
# --------------------------------------------------------------------------

def _eye_beta(frame, p) -> mi.Float:
    """β of world points ``p`` seen from the eye."""
    eye = point(frame.camera.origin)
    return direction_to_alpha_beta(frame, mi.Vector3f(p - eye))[1]


def trace_local_blocker_angles(params, queries: EpipolarQueries, rays: LocalLightRays,
                               k: int = 1, seed: int = 0, lit=None) -> mi.Float:
    """β_b = the eye's angle of the first blocker of ``k`` sub-rays per light
    ray, each traced with Mitsuba from ``p_l`` outward
    (:func:`~integrators.core.light_transport.first_blocker`: split at the medium
    box, which does not block); π where nothing blocks the sub-ray.  (n·d·k,)
    lanes in (row, light ray, sub-ray) order; only the ``lit`` sub-rays are
    traced (the others carry no light: π)."""
    frame = queries.frame
    s, gamma = sub_ray_gamma(rays, k, seed, evaluated=True)
    idx = dr.arange(mi.UInt32, dr.width(s)) if lit is None else dr.compress(lit)
    out = dr.full(mi.Float, math.pi, dr.width(s))
    if dr.width(idx):
        alpha = dr.gather(mi.Float, queries.alpha, dr.gather(mi.UInt32, s, idx))
        w = light_ray_direction(frame, alpha, dr.gather(mi.Float, gamma, idx))
        origin = point(frame.light_position) + dr.zeros(mi.Vector3f, dr.width(idx))
        hit, p = first_blocker(params, origin, w)
        dr.scatter(out, dr.select(hit, _eye_beta(frame, p), math.pi), idx)
    dr.eval(out)
    return out


def radial_map_point(frame, alpha, gamma) -> mi.Point3f:
    """Point/spot light: the point of light ray (α, γ) at the eye's distance
    L from the light (where a perspective or cube map looks it up)."""
    p_l = point(frame.light_position)
    return p_l + light_ray_direction(frame, alpha, gamma) * scalar(frame.light_distance)


def radial_blocker_beta(params, frame, shadow_map, alpha, gamma, z_b) -> mi.Float:
    """Point/spot light: the eye's β of the blocker on light ray (α, γ) at
    ``r_b = z_b + bias`` from the light (a perspective or cube map's own
    test)."""
    p_l = mi.Point3f(point(frame.light_position))
    return _eye_beta(frame, p_l + light_ray_direction(frame, alpha, gamma) * (z_b + shadow_map.bias))
