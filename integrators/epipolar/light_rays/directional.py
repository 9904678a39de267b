"""Light rays of a directional light: ``d`` rays per row, parallel to the
axis, spanning ``γ ∈ [0, γ_max]`` (Baran et al. 2010 §5).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify.coords import light_coords_to_world

from ...core.host_reads import host_reductions
from ...core.light_transport import medium_interval, scalar, vector
from ...core.opaque import opaque_scalar
from ..queries import EpipolarQueries, frame_memo, row_alpha
from .layout import EqualLightRays, finite_or_inf, keep_lowest_light_side


#: most light rays per slice the automatic choice takes
MAX_AUTO_LIGHT_RAYS = 4096


#: fewest light rays per slice the automatic choice takes: a 1-sample pixel
#: samples the blockers along one view ray however small the image is, so
#: the light rays must resolve them at any image size
MIN_AUTO_LIGHT_RAYS = 256


def auto_light_rays(width: int, height: int, sigma_t: float = 0.0,
                    gamma_max: float = 0.0) -> int:
    """Default ``d``: the image diagonal in pixels (at least
    ``MIN_AUTO_LIGHT_RAYS``), or more if four light rays per mean free path
    1/σt over the widest row's ``γ_max`` need more (thick media: the
    scattering then comes from a few light rays next to the eye), at most
    ``MAX_AUTO_LIGHT_RAYS``."""
    d = max(MIN_AUTO_LIGHT_RAYS, math.ceil(math.hypot(width, height)),
            math.ceil(4 * sigma_t * gamma_max))
    return int(min(d, MAX_AUTO_LIGHT_RAYS))


@dataclass(frozen=True, eq=False)
class LightRays(EqualLightRays):
    """A directional light's ``d`` parallel light rays per row over
    ``[γ_lo, γ_max]`` (module doc; ``γ_lo`` = 0 unless given) and where
    each leaves the medium box toward the light (:func:`box_exits`)."""
    d: int
    gamma_max: mi.Float     # (n,)
    delta_gamma: mi.Float   # (n,)
    h: mi.Float | None = None       # (n·d,) axial exit coordinate h(α, γ) at each centre
    h_ref: mi.Float | None = None   # (n,) smallest h of the row's rays that meet the box
    gamma_lo: mi.Float | None = None   # (n,) start of the rows' light rays; None: 0
    #: (n,) the rows' numbers in the whole frame when these are some of its
    #: rows (a partial render, :mod:`integrators.partial.row_subset`); None: 0..n-1
    row_id: mi.UInt32 | None = None


def row_gamma_end(queries: EpipolarQueries, floor=None) -> mi.Float:
    """(n,) the largest γ_end of each row's queries, at least ``floor``: how
    far the row's light rays must reach (both light kinds); evaluated
    (without a floor) with the queries."""
    def make():
        gamma_max = dr.zeros(mi.Float, queries.n)
        dr.scatter_reduce(dr.ReduceOp.Max, gamma_max, queries.gamma_end, queries.row)
        return gamma_max
    # assign_queries finds it with the queries
    gamma_max = frame_memo(queries, ("row_gamma_end",), make)
    return gamma_max if floor is None else dr.maximum(gamma_max, floor)


def light_ray_count(params, d: int, length: float) -> int:
    """``d``, or when 0 the automatic count (:func:`auto_light_rays`) for the
    image and ``length`` (the light model's ``light_length``)."""
    if d:
        return d
    cam = params.camera
    return auto_light_rays(cam.width, cam.height, float(np.max(params.medium.sigma_t)), length)


def light_ray_grid(params, queries: EpipolarQueries, d: int = 0) -> LightRays:
    """The rows' ``d`` light rays (0: :func:`auto_light_rays`) and where each
    leaves the medium box toward the light (h; +inf if it misses the box).

    Directional light rays are parallel, so γ (the distance from the
    camera–light axis) spaces each row's rays uniformly over its own
    ``[0, max γ_end]`` and h is each ray's own box exit; a point/spot
    light's rays share one lattice of angles instead
    (:func:`~integrators.epipolar.light_rays.local.local_light_ray_grid`)."""
    floor = scalar(1e-6 * params.scene_extent)
    gamma_max = row_gamma_end(queries, floor)
    auto = not d
    # the longest row: the rows' evaluated maxima against the floor (no kernel)
    d = light_ray_count(params, d, max(float(dr.max(row_gamma_end(queries))[0]),
                                       float(floor[0])))
    def grid(d):
        rays = LightRays(int(d), gamma_max, gamma_max / d)
        dr.eval(rays.gamma_max, rays.delta_gamma)    # the rows' arrays, before any gather
        return with_box_exits(params, queries, rays)
    rays = grid(d)
    if auto:
        step = light_side_step(params, queries, rays)
        if step > LIGHT_SIDE_STEP and d < MAX_AUTO_LIGHT_RAYS:
            d = min(MAX_AUTO_LIGHT_RAYS, math.ceil(d * step / LIGHT_SIDE_STEP))
            rays = grid(d)
    return rays


#: the automatic light rays: largest change σt·|Δh| of the light-side
#: optical depth from one light ray to the next where the light arrives
#: (:func:`light_side_step`)
LIGHT_SIDE_STEP = 0.25
#: ... where it arrives: σt·(h − h_ref) below this on both light rays
LIGHT_SIDE_ARRIVES = 10.0


def light_side_step(params, queries: EpipolarQueries, rays: LightRays) -> float:
    """max σt·|h_{g+1} − h_g| over neighbouring light rays of a row that
    both meet the box and carry light (σt·(h − h_ref) ≤ ``LIGHT_SIDE_ARRIVES``):
    how much L(γ) = e^{-σt (h − h_ref)} changes across one light ray.

    The sweep takes one value of L per light-ray interval times the exact
    mean of the kernel over it.  ``auto_light_rays`` spaces the light rays
    by the mean free path along γ, but where a grazing light's rays leave
    the box through a face nearly parallel to them, h changes by
    cot(grazing angle) per unit γ: σt·|Δh| ≈ 0.6 per light ray made the
    midpoint value of L, and its covariance with the kernel over the
    interval, 2.5 % low (random stress seed 206; converging as 1/d²).
    :func:`light_ray_grid` takes as many more light rays as bring this
    below ``LIGHT_SIDE_STEP``.

    The same kernel finds the smallest finite h of ``rays`` and keeps it
    for the frame's ``queries`` and these rays (what
    :func:`~integrators.epipolar.light_factor.lowest_light_side` reads of
    h)."""
    if rays.d < 2:
        return 0.0
    sigma_t = scalar(np.max(params.medium.sigma_t))
    s, g, _ = rays.lanes()
    d = opaque_scalar(mi.UInt32, rays.d)
    nxt = s * d + dr.minimum(g + 1, d - 1)
    h, h_n = rays.h, dr.gather(mi.Float, rays.h, nxt)
    h_ref = dr.gather(mi.Float, rays.h_ref, s)
    arrives = sigma_t * (dr.maximum(h, h_n) - h_ref) <= LIGHT_SIDE_ARRIVES
    ok = (g + 1 < d) & dr.isfinite(h) & dr.isfinite(h_n) & arrives
    step, lowest = host_reductions((dr.max, dr.select(ok, sigma_t * dr.abs(h_n - h), 0.0)),
                                   (dr.min, finite_or_inf(h)))
    keep_lowest_light_side(queries, rays, lowest)
    return step


def with_box_exits(params, queries: EpipolarQueries, rays):
    """``rays`` (a directional layout: :class:`LightRays` or
    :class:`~integrators.fourier.projective_rays.ProjectiveLightRays`) with ``h``
    (where the light ray through each centre, ``rays.positions(0.5)``,
    leaves the medium box toward the light; +inf if it misses the box) and
    the rows' ``h_ref`` (:func:`row_reference`)."""
    frame = queries.frame
    s, gamma = rays.positions(0.5)
    base = light_coords_to_world(frame, row_alpha(queries, s), gamma, 0.0)
    h, hits = axial_exit(params, base, vector(frame.axis))
    h = dr.select(hits, h, dr.inf)
    dr.schedule(h)      # with the rows' minimum (reading it launches that kernel)
    h_ref = row_reference(params, h, s, queries.n)
    dr.eval(h, h_ref)
    return replace(rays, h=h, h_ref=h_ref)


#: light-side range c: a light ray leaving the box toward the light at
#: σt·h < −c (more than c mean free paths *behind* the eye, along the
#: light) is left out of the sums (the samples that meet it are marched:
#: :func:`~integrators.epipolar.light_factor.samples_over_dropped`), and no
#: row's reference h_ref lies below −c/σt.  The rows' amplification e^{c}
#: divides the separated kernel's tolerance (1e-3 by default): at c = 7
#: (1e-3 / 1096, float32's own resolution) the tree's sums were up to 29 %
#: dark on the far light rays of a thick fog seen toward the sun (held-out
#: seed 2016 without occluders: 124 pixels at c = 7, 65 at 6, 1 at 5, none
#: at 4 -- where 58 % of its samples are marched instead)
LIGHT_SIDE_RANGE = 4.0


def row_reference(params, h: mi.Float, s: mi.UInt32, n: int) -> mi.Float:
    """h_ref per row: the smallest finite ``h`` of its light rays (``s``:
    their rows), but not below −c/σt_max (c = ``LIGHT_SIDE_RANGE``).

    The sum is split as e^{-σt h_ref} (per query) times L(γ) K(γ, β) (in
    the tree), and float32 and the separated kernel resolve that sum only
    to a fixed fraction of its largest terms.  Where a row's light rays
    leave the box behind the eye (h < 0: a grazing light under the box's
    top, a wall beside the camera), e^{-σt h} grows without bound while the
    kernel those light rays meet, at β > π/2, shrinks as fast: every point
    of such a light ray is at t ≥ |u| ≥ |h| from the eye, so it contributes
    at most e^{-σt |h|} of the unattenuated single scattering.  Bounding
    the reference bounds the amplification to e^{c}; the light rays beyond
    it are left out by
    :func:`~integrators.epipolar.light_factor.light_side_factor` and the
    camera samples that meet them ray-marched
    (:func:`~integrators.epipolar.light_factor.samples_over_dropped`: in a
    thick fog seen toward the light they carry much of the pixel), and the
    automatic SVD rank tightens its tolerance by the row's e^{σt h_ref}
    (:func:`~integrators.epipolar.light_factor.light_side_gains`)."""
    h_ref = dr.full(mi.Float, dr.inf, n)
    dr.scatter_reduce(dr.ReduceOp.Min, h_ref, h, s)
    h_ref = dr.select(dr.isfinite(h_ref), h_ref, 0.0)
    sigma_t_max = float(np.max(params.medium.sigma_t))
    if sigma_t_max > 0.0:
        h_ref = dr.maximum(h_ref, scalar(-LIGHT_SIDE_RANGE / sigma_t_max))
    return h_ref


def axial_exit(params, x, w):
    """(h, hits): axial coordinate where the line x + u·w leaves the medium
    box toward the light, and whether the line meets the box at all."""
    t_near, t_far = medium_interval(params, x, w)
    return t_far, t_far >= t_near
