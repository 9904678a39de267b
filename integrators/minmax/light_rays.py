"""The 1-D height map of every slice (Yusov 2013, "1D min/max binary trees:
1D height map"): the blocker depth along the slice's light rays.

All camera rays of a slice lie in one half-plane, which meets the light's
rays in a 1-D family: the light rays ``γ`` of the slice (:mod:`rectify.coords`;
directional: distance from the camera–light axis, point/spot: angle at the
light from the direction light → eye).  Slice ``k`` gets ``n`` texels (a
power of two, the tree's leaves) at ``γ_i = γ_lo + (i + ½) Δ`` covering the
``γ`` its samples' rays reach (spot: clipped to the cone,
:func:`~integrators.epipolar.light_rays.local.cone_interval`).

Per texel: the depth ``z_b`` of the first blocker along the light ray
(directional: from a plane beyond the scene, ``u_top − u``; point/spot: the
distance from the light) and the light's colour along it (directional: 1;
point/spot: Mitsuba's intensity × spot falloff × projected texture at unit
distance, and the light-side entry factor of a light outside the box,
:func:`texel_colour`).  Sources:

* ``traced``: each texel's light ray traced with Mitsuba (exact blockers);
* ``resampled``: read from the classic shadow map; each texel stores the
  min and max depth of the shadow-map texels any point of its cell may filter
  (:meth:`~integrators.core.capture.ShadowMap.depth_bounds`), so a min/max test never disagrees
  with
  the per-texel PCF march, which reads the shadow map itself at the leaves.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify import EpipolarFrame, light_coords_to_world, view_to_light

from ..core.light_transport import color, first_blocker, sample_light, segment_box
from ..core.opaque import Divisor, floats, point, scalar, vector
from ..epipolar.light_rays.local import cone_interval
from .slices_and_samples import EpipolarSamples


SOURCES = ("traced", "resampled")
#: shadow-test bias relative to the scene size (as the shadow map's):
#: directional light and resampled blockers
BIAS = 1e-4
#: traced point/spot blockers: bias relative to the depths' own scale (the
#: blocker depth plus the light's distance from the eye, the magnitudes the
#: depths are computed from; ~100 float ulps).  A scene-size bias lit a
#: shell ``1e-4·extent`` deep behind every blocker, which near a light
#: inside a small closed box (enclosed lights) is a visible leak.
DEPTH_BIAS = 1e-5


@dataclass(frozen=True, eq=False)
class SliceLightRays:
    """Texel layout of the slices' 1-D height maps and their contents."""
    n: int                                  # texels per slice (power of two)
    gamma_lo: np.ndarray                    # (S,)
    delta: np.ndarray                       # (S,) texel width in γ
    u_top: float                            # directional: axial coordinate of the depth origin
    bias: float
    z_min: mi.Float = field(repr=False)     # (S·n,) blocker depth (lower bound)
    z_max: mi.Float = field(repr=False)     # (S·n,) blocker depth (upper bound; = z_min if traced)
    colour: mi.Color3f = field(repr=False)  # (S·n,) light colour along the texel's light ray
    source: str = "traced"

    @property
    def slices(self) -> int:
        return int(self.gamma_lo.shape[0])


def light_top(params, frame: EpipolarFrame) -> float:
    """Axial coordinate ``u`` beyond every scene object: directional depths
    are measured from there (``z = u_top − u``)."""
    bb = params.scene.bbox()
    corners = np.array([[x, y, z] for x in (bb.min[0], bb.max[0])
                        for y in (bb.min[1], bb.max[1]) for z in (bb.min[2], bb.max[2])])
    return float(np.max((corners - params.camera.origin) @ frame.axis)) + 1e-2 * params.scene_extent


def sample_gamma_range(samples: EpipolarSamples):
    """(S,) largest γ any used sample's ray reaches in each slice."""
    frame = samples.frame
    alpha = dr.gather(mi.Float, floats(samples.slices.alpha), samples.slice)
    g_end, _ = view_to_light(frame, alpha, samples.beta, samples.t_near + samples.d)
    g_end = dr.select(samples.used, g_end, 0.0)
    out = dr.zeros(mi.Float, samples.slices.count)
    # Local, not Auto: the LLVM backend's expanded reduction would bake the
    # slice count into the kernel
    dr.scatter_reduce(dr.ReduceOp.Max, out, g_end, samples.slice, mode=dr.ReduceMode.Local)
    return np.asarray(out, dtype=np.float64)


def texel_layout(params, samples: EpipolarSamples, n: int):
    """(gamma_lo, delta) per slice: ``n`` texels over ``[0, γ_max]`` (spot:
    intersected with the cone's γ interval)."""
    g_max = sample_gamma_range(samples) * (1 + 1e-5) + 1e-9
    lo = np.zeros_like(g_max)
    hi = g_max
    if params.light.kind == "spot":
        c_lo, c_hi, lit = cone_interval(params, samples.frame,
                                        floats(samples.slices.alpha))
        c_lo, c_hi = np.asarray(c_lo, np.float64), np.asarray(c_hi, np.float64)
        lit = np.asarray(lit, bool)
        lo = np.where(lit, np.clip(c_lo, 0.0, hi), 0.0)
        hi = np.where(lit, np.clip(c_hi, lo, hi), 0.0)
    delta = np.maximum(hi - lo, 1e-9) / n
    return lo, delta


def texel_gammas(layout_lo, delta, n: int):
    """(slice, γ) of every texel, flat ``k·n + i``."""
    S = len(layout_lo)
    idx = dr.arange(mi.UInt32, S * n)
    k, i = Divisor(n).divmod(idx)
    lo = dr.gather(mi.Float, floats(layout_lo), k)
    dg = dr.gather(mi.Float, floats(delta), k)
    return k, lo + (mi.Float(i) + 0.5) * dg


def texel_rays(frame: EpipolarFrame, alpha, gamma, u_top: float):
    """Origin and unit direction of texel light rays (from the depth origin
    toward the scene)."""
    if frame.is_directional:
        o = light_coords_to_world(frame, alpha, gamma, scalar(u_top))
        w = vector(-np.asarray(frame.axis, dtype=np.float64))
        return o, dr.zeros(mi.Vector3f, dr.width(o.x)) + w
    p_l = point(frame.light_position)
    w = dr.normalize(mi.Vector3f(light_coords_to_world(frame, alpha, gamma, 1.0) - p_l))
    return dr.zeros(mi.Point3f, dr.width(w.x)) + p_l, w


#: largest light-side exponent σt·r_in a texel's colour may carry (the
#: section integral's e^{-σt r} then makes the product ~e^{-80} or smaller)
MAX_ENTRY_EXPONENT = 80.0


def texel_colour(params, frame: EpipolarFrame, origin, w):
    """Light colour along texel light rays (see the module docstring).

    Point/spot: Mitsuba's intensity·falloff·texture at unit distance, times
    ``e^{σt r_in}`` for a light outside the medium box (``r_in``: distance
    from the light to where its ray enters the box), so that with the
    section integral's ``e^{−σt r}`` the light-side transmittance is
    ``e^{−σt (r − r_in)}``, the path inside the box."""
    if frame.is_directional:
        return dr.full(mi.Color3f, 1.0, dr.width(origin.x))
    _, _, L = sample_light(params, origin + w)
    _, t_in, _ = segment_box(params, origin, w, dr.full(mi.Float, dr.inf, dr.width(w.x)))
    sigma_t = color(params.medium.sigma_t)
    return L * dr.exp(dr.minimum(sigma_t * t_in, MAX_ENTRY_EXPONENT))


def slice_light_rays(params, samples: EpipolarSamples, n: int, source: str = "traced",
                     shadow_map=None) -> SliceLightRays:
    """Stage "blockers": the per-slice 1-D height maps (module docstring)."""
    if n < 1 or n & (n - 1):
        raise ValueError(f"Property 'light_rays' = {n} must be a power of two.")
    if source not in SOURCES:
        raise ValueError(f"Property 'source' = '{source}' is not one of {list(SOURCES)}.")
    frame = samples.frame
    lo, delta = texel_layout(params, samples, n)
    u_top = light_top(params, frame) if frame.is_directional else 0.0
    k, gamma = texel_gammas(lo, delta, n)
    alpha = dr.gather(mi.Float, floats(samples.slices.alpha), k)
    o, w = texel_rays(frame, alpha, gamma, u_top)
    colour = texel_colour(params, frame, o, w)
    bias = BIAS * params.scene_extent
    if source == "traced":
        hit, p = first_blocker(params, o, w)
        z = dr.select(hit, dr.norm(p - o), dr.inf)
        if not frame.is_directional:
            # the bias scales with the depth (DEPTH_BIAS), baked into the
            # blocker depth: the march's own bias is then 0
            z = z + traced_bias(frame, z)
            bias = 0.0
        z_min = z_max = z
    else:
        if shadow_map is None:
            raise ValueError("source='resampled' needs the shadow map.")
        # every point whose γ lies in the texel's cell, at any depth: bound the
        # PCF taps over the cell (its centre ± half a texel along the slice)
        z_min, z_max = cell_depth_bounds(frame, shadow_map, alpha, gamma, delta, k, u_top, o, w)
    out = SliceLightRays(n=n, gamma_lo=lo, delta=delta, u_top=u_top, bias=bias,
                         z_min=z_min, z_max=z_max, colour=colour, source=source)
    dr.eval(out.z_min, out.z_max, out.colour)
    return out


def traced_bias(frame: EpipolarFrame, z):
    """Shadow-test bias of traced point/spot blocker depths ``z``
    (:data:`DEPTH_BIAS`; inf stays inf)."""
    return scalar(DEPTH_BIAS) * (z + scalar(frame.light_distance))


#: points along each texel's cell probed for the shadow-map bounds
CELL_PROBES = 3


def cell_depth_bounds(frame, shadow_map, alpha, gamma, delta, k, u_top, o, w):
    """Conservative (min, max) blocker depth of the shadow-map texels that
    PCF may read for any point of a texel cell (probes along the cell,
    each bounding the taps within half a shadow-map texel,
    :meth:`~integrators.core.capture.ShadowMap.depth_bounds`; conservative while a cell spans
    at most
    two shadow-map texels, which the default ``light_rays`` ensures)."""
    dg = dr.gather(mi.Float, floats(delta), k)
    z_lo = dr.full(mi.Float, dr.inf, dr.width(gamma))
    z_hi = dr.full(mi.Float, -dr.inf, dr.width(gamma))
    for q in range(CELL_PROBES):
        g = gamma + dg * ((q / (CELL_PROBES - 1)) - 0.5)
        oq, wq = texel_rays(frame, alpha, g, u_top)
        lo, hi = shadow_map.depth_bounds(oq + wq * 1.0)
        z_lo, z_hi = dr.minimum(z_lo, lo), dr.maximum(z_hi, hi)
    if frame.is_directional:
        # the shadow map measures depth from its own plane s0 - x·w_l: shift
        # to ours (u_top − u); both grow along −w_l
        shift = scalar(shadow_map.s0 - (float(np.dot(frame.camera.origin, frame.axis)) + u_top))
        z_lo, z_hi = z_lo - shift, z_hi - shift
    return z_lo, z_hi


#: fewest default texels per slice: a height map samples its light rays at
#: one point per texel, so a blocker edge is placed to a texel and a gap
#: thinner than a texel may be missed; on images under about 400×300
#: pixels one texel per pixel is too coarse for a window's mullions or a
#: slot in a ceiling (results/minmax_bounded)
MIN_TEXELS = 1024


def texel_count(width: int, height: int) -> int:
    """Default texels per slice: the next power of two above the image
    diagonal (about one light ray per pixel along the longest slice), at
    least ``MIN_TEXELS``."""
    return max(MIN_TEXELS, 1 << max(5, math.ceil(math.log2(math.hypot(width, height)))))
