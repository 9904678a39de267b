"""The light side of a point or spot light's light rays: intensity,
projected texture and the light-side transmittance of each light ray
(Baran et al. 2010 §9).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.light_transport import point, sample_light, scalar, vector
from .blockers import sub_ray_gamma
from .light_factor import LOCAL_LIGHT_SIDE_RANGE, gray, light_ray_channels, light_side_extinction
from .light_rays.local import LocalLightRays, light_ray_direction
from .queries import EpipolarQueries


def light_intensity(params, frame, w) -> mi.Color3f:
    """Mitsuba's intensity toward unit directions ``w`` from the light (spot
    fall-off and texture included): the delivered radiance at distance ``L``
    times ``L²``."""
    ell = float(frame.light_distance)
    _, _, spec = sample_light(params, point(frame.light_position) + w * scalar(ell))
    return spec * scalar(ell * ell)


def projects_texture(params) -> bool:
    """Whether the light is a spot light with a projected ``texture``."""
    return params.light.kind == "spot" and params.light.textured


def _channels(params) -> int:
    """Colour channels of the per-light-ray factor: 1 for an untextured light
    in a grey medium (its colour is then a per-query factor), else 3."""
    return 1 if (not projects_texture(params) and gray(params.medium.sigma_t)) else 3


def _light_colour(params, frame) -> mi.Color3f:
    """The intensity along the spot axis (fall-off 1), or of the point light."""
    axis = params.light.spot_axis if params.light.kind == "spot" else frame.axis
    return light_intensity(params, frame, vector(axis))


def _point_light_factor(params, queries: EpipolarQueries, rays: LocalLightRays, k: int):
    """:func:`light_ray_factor` of a point light, whose intensity is the
    same toward every direction: Ī is its colour, no sub-ray asked for it
    (the same factor to float rounding, without the sub-rays' light
    queries and their mean); ``lit``: every sub-ray of an existing light
    ray, where the light shines at all."""
    frame = queries.frame
    colour = _light_colour(params, frame)          # one lane: read where it is used
    lit = rays.used(k) & (dr.max(colour) > 0.0)
    exists = rays.used(1)                          # 0 on the padding, as the mean has it
    if _channels(params) == 1:
        intensity = [dr.select(exists, 1.0, 0.0)]
    else:
        intensity = [dr.select(exists, colour[ch], 0.0) for ch in range(3)]
        colour = mi.Color3f(1.0)
    return _with_light_side(params, queries, rays, intensity, lit), colour, lit


def light_ray_factor(params, queries: EpipolarQueries, rays: LocalLightRays, k: int = 1,
                     seed: int = 0):
    """(L, colour, lit): the tree's per-light-ray factor (§6 textured light)

        L(α, γ) = Ī(α, γ) · e^{-σt (L − r_in(α, γ))}

    (n, d) or (n, d, 3) (:func:`_channels`), Ī the intensity averaged over
    the ``k`` sub-rays of :func:`~integrators.epipolar.blockers.sub_ray_gamma`
    (same ``seed``: the blockers' sub-rays; prefilters the texture and the
    cone's edge); ``colour``: the light's intensity along its axis when L
    is grey (L then holds the fall-off alone), else 1; ``lit`` (n·d·k,):
    existing sub-rays carrying light.  A point light's Ī is its colour
    (:func:`_point_light_factor`); a spot light's is averaged over the
    sub-rays (:func:`_sub_ray_factor`)."""
    if params.light.kind == "point":
        return _point_light_factor(params, queries, rays, k)
    return _sub_ray_factor(params, queries, rays, k, seed)


def _sub_ray_factor(params, queries: EpipolarQueries, rays: LocalLightRays, k: int, seed: int):
    """:func:`light_ray_factor` with Ī averaged over the ``k`` sub-rays of
    each light ray (Mitsuba's intensity toward each)."""
    frame = queries.frame
    used = rays.used(k)                       # sub-rays of existing light rays
    dr.schedule(used)                         # with the sub-rays' kernel
    s, gamma = sub_ray_gamma(rays, k, seed, evaluated=True)
    idx = dr.compress(used)
    w = light_ray_direction(frame, dr.gather(mi.Float, queries.alpha, dr.gather(mi.UInt32, s, idx)),
                            dr.gather(mi.Float, gamma, idx))
    I = light_intensity(params, frame, w)
    lit = dr.zeros(mi.Bool, dr.width(s))
    dr.scatter(lit, dr.max(I) > 0, idx)
    n_rays = queries.n * rays.d
    I_sum = dr.zeros(mi.Color3f, n_rays)
    dr.scatter_reduce(dr.ReduceOp.Add, I_sum, I, idx // k)
    I_mean = I_sum * (1.0 / k)
    if _channels(params) == 1:
        colour = _light_colour(params, frame)
        if dr.width(idx):       # written by the lit flags' kernel (one lane of it)
            colour_at = dr.zeros(mi.Color3f, 1)
            dr.scatter(colour_at, colour, mi.UInt32(0),
                       active=dr.arange(mi.UInt32, dr.width(idx)) == 0)
            colour = colour_at
        dr.eval(colour)
        intensity = np.array([float(colour[i][0]) for i in range(3)])
        c = int(np.argmax(intensity))
        scale = 1.0 / intensity[c] if intensity[c] > 0 else 0.0
        mean = [I_mean[c] * scalar(scale)]
    else:
        mean = [I_mean[ch] for ch in range(3)]
        colour = mi.Color3f(1.0)
    return _with_light_side(params, queries, rays, mean, lit), colour, lit


def _with_light_side(params, queries: EpipolarQueries, rays: LocalLightRays, intensity: list,
                     *also) -> mi.TensorXf:
    """L = Ī_ch · e^{-σt,ch (L − r_in)} per light ray, evaluated (with
    ``also``): ``intensity`` one Float (grey σt: σt[0]) or one per colour
    channel."""
    sigma_t = np.asarray(params.medium.sigma_t, np.float64)
    depth = scalar(queries.frame.light_distance) - rays.r_in
    values = [i * light_side_extinction(sigma_t[ch], depth, c=LOCAL_LIGHT_SIDE_RANGE)
              for ch, i in enumerate(intensity)]
    L = light_ray_channels(values, queries.n, rays.d)
    dr.eval(L.array, *also)
    return L
