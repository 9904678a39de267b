"""The light side of a directional light's light rays: the factor
``L(γ) = e^{-σt h(α, γ)}`` of the light-side path through the medium box
(Baran et al. 2010 §6, "textured light"; DESIGN §1).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.light_transport import scalar
from ..core.opaque import scalar_u32
from ..core.reductions import UNSHARED
from .light_rays.directional import LIGHT_SIDE_RANGE, LightRays
from .light_rays.layout import LOWEST_LIGHT_SIDE, covered_depth, finite_or_inf, lowest_or_none
from .queries import EpipolarQueries, frame_memo


def lowest_light_side(queries, rays, path: mi.Float) -> float | None:
    """The smallest finite light-side path length ``path`` of the frame's
    light ``rays`` (the separation's ``light_side_path``: a directional
    light's h, a point light's L − r_in; None: none finite), made once
    per frame's queries and rays (a directional light's automatic light
    rays find it with their light-side step,
    :func:`~integrators.epipolar.light_rays.directional.light_side_step`):
    the SVD's tolerance (:func:`light_side_gains`) and the frame's choices
    read it."""
    def make():
        p = mi.Float(path)
        return lowest_or_none(float(dr.min(finite_or_inf(p))[0]) if dr.width(p) else math.inf)
    return frame_memo(queries, (LOWEST_LIGHT_SIDE, rays), make)


#: a point or spot light's light-side range c (its light rays with
#: σt·(L − r_in) < −c are left out of the sums; the directional light's is
#: ``LIGHT_SIDE_RANGE``, whose samples are marched)
LOCAL_LIGHT_SIDE_RANGE = 7.0


def light_side_gains(sigma_t, lowest: float | None,
                     c: float = LIGHT_SIDE_RANGE) -> list[float]:
    """Per channel of extinction ``sigma_t``: e^{-σt·min(lowest, 0)}, at
    most e^{c}, ``lowest`` the smallest finite light-side path length
    (:func:`lowest_light_side`; None: none, as 0): how much the
    light-side factor (e^{-σt h_ref}·L of the kept light rays) amplifies
    the tree's absolute errors.  The automatic SVD rank divides its
    tolerance by it."""
    lowest = min(0.0 if lowest is None else lowest, 0.0)
    return [math.exp(min(c, -float(st) * lowest))
            for st in np.atleast_1d(np.asarray(sigma_t, np.float64))]


# --------------------------------------------------------------------------
# Light side (DESIGN §1, Baran §6 "textured light")
# --------------------------------------------------------------------------

def gray(sigma_t) -> bool:
    s = np.asarray(sigma_t, np.float64)
    return bool(np.all(s == s[0]))


def light_side_extinction(sigma_t: float, path, ref=None, c: float = LIGHT_SIDE_RANGE):
    """e^{-σt (path − ref)} per light ray (``ref`` None: 0) -- the light
    side of the per-light-ray factor of both light kinds (directional:
    path = h, ref = the row's h_ref; point/spot: path = L − r_in) -- and 0
    where the path is not finite (the light ray misses the box: +inf, NaN)
    or σt·path < −c (``LIGHT_SIDE_RANGE`` unless given).  A light ray whose path is
    negative (it leaves the box toward the light *behind* the eye) has a
    factor above 1, but each of its points is at least |path| from the eye,
    so it contributes at most e^{-σt |path|} of the unattenuated single
    scattering: dropping those beyond c keeps every factor ≤ e^{c}
    (:func:`~integrators.epipolar.light_rays.directional.row_reference`)."""
    rel = path if ref is None else path - ref
    st = scalar(sigma_t)
    return dr.select(dr.isfinite(rel) & (-st * path <= c), dr.exp(-st * rel), 0.0)


def light_ray_channels(values: list, n: int, d: int) -> mi.TensorXf:
    """The per-light-ray factor as the sweep takes it: (n, d) for one
    channel, (n, d, C) for C, from C Floats of n·d light rays."""
    if len(values) == 1:
        return mi.TensorXf(values[0], shape=(n, d))
    C = len(values)
    out = dr.zeros(mi.Float, n * d * C)
    lane = dr.arange(mi.UInt32, n * d)
    for c, v in enumerate(values):
        # each entry written once: an add to the zeros, all channels in one
        # kernel (a plain scatter would launch the last one first), no atomics
        dr.scatter_reduce(dr.ReduceOp.Add, out, v, lane * C + c, mode=UNSHARED)
    return mi.TensorXf(out, shape=(n, d, C))


def light_side_factor(params, queries: EpipolarQueries, rays: LightRays,
                      c: float = LIGHT_SIDE_RANGE) -> mi.TensorXf:
    """L(γ) = e^{-σt (h(α, γ) − h_ref(α))} at every light ray's centre:
    (n, d) if σt is grey, else (n, d, 3).  Relative to the row's h_ref so
    that thick media stay inside float32's range; the factor e^{-σt h_ref}
    is applied per query (:func:`~integrators.epipolar.query_terms.directional_query_terms`). 
    Light rays
    with σt·h < −c are 0 (:func:`light_side_extinction`; ``c``:
    ``LIGHT_SIDE_RANGE`` unless given -- a sum that needs no separated
    kernel may keep more of them); so e^{-σt h_ref}·L ≤ e^{c} everywhere."""
    s, _, _ = rays.lanes()
    h_ref = dr.gather(mi.Float, rays.h_ref, s)
    sigma_t = params.medium.sigma_t
    channels = [0] if gray(sigma_t) else [0, 1, 2]
    return light_ray_channels([light_side_extinction(sigma_t[ch], rays.h, h_ref, c)
                               for ch in channels], queries.n, rays.d)


def samples_over_dropped(params, queries: EpipolarQueries, rays, lowest: float | None,
                         c: float = LIGHT_SIDE_RANGE) -> mi.Bool | None:
    """Camera samples (a mask) whose query covers a light ray that
    :func:`light_side_extinction` dropped (finite h with σt·h < −c, ``c``
    the range the light-side factor was made with, σt the largest
    channel's), to be ray-marched;
    None where the frame has none (``lowest``: its smallest finite h, from
    :func:`lowest_light_side`).

    Such a light ray is worth at most e^{-c} of the *unattenuated* single
    scattering (:func:`~integrators.epipolar.light_rays.directional.row_reference`),
    but a view ray into a thick medium toward the light is itself attenuated
    far below that: along it t + h stays near the eye's own h, so every one
    of its points -- those on the dropped light rays too -- adds about
    e^{-σt h_eye}.  Dropping them left such views up to 26 % dark (held-out
    thick-fog shafts, σt·h_eye ≈ 15, no occluder at all).  A query covers a
    light ray when the ray lies below its rectified depth D in its row."""
    if not queries.count or lowest is None:
        return None
    st = float(np.max(np.asarray(params.medium.sigma_t, np.float64)))
    if not st * lowest < -c:
        return None
    h = rays.h
    dropped = dr.select(dr.isfinite(h) & (scalar(st) * h < -c), 1.0, 0.0)
    before = dr.block_prefix_sum(mi.Float(dropped), rays.d, exclusive=False)   # per row
    d_o = scalar_u32(rays.d)
    D, k0 = covered_depth(queries, rays, d_o)
    covers = (D > 0.0) & (dr.gather(mi.Float, before, queries.row * d_o + k0) > 0.0)
    mask = dr.zeros(mi.Bool, queries.n_samples)
    dr.scatter(mask, True, queries.sample, active=covers)
    return mask
