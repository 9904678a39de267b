"""Rectified epipolar maps shared by the epipolar integrators.

Baran et al. 2010, "A Hierarchical Volumetric Shadow Algorithm for Single
Scattering", §3-§8, written so that every camera sample is evaluated at its
own view ray and its own depth (DESIGN §3, "known trap"): nothing is computed
per (slice, β-sample) and interpolated back to pixels.

Geometry (:mod:`rectify` conventions)
-------------------------------------
``o`` is the pinhole (``params.camera.origin``), ``w_l`` the unit direction
*toward* the light (the frame's ``axis``).  A slice α is a half-plane
bounded by the line ``o + u·w_l``; in it a view ray makes the angle β with
``w_l``, a light ray is the line at distance γ from the axis, and the point
at distance ``t`` from ``o`` on view ray β lies on light ray ``γ = t·sin β``
at the axial coordinate ``u = t·cos β = γ·cot β`` (§3, Fig. 3).

Queries (:func:`assign_queries`)
    Each camera sample whose ray has ``d > 0`` and lies outside the epipole
    ring (§6) is a *query* of its nearest slice (the slice whose α is
    closest to the sample's own α).  Queries are sorted by (slice, β): the
    sweep order of Fig. 6, "from the light away".  Slices without queries
    are dropped; the remaining ones are the *rows* ``0..n-1`` of the
    rectified maps, padded to ``r`` = the largest number of queries of a
    row (``r_count`` per row).  The query keeps its own β and the distance
    ``γ_end = t_end·sin β`` of its end point from the axis
    (``t_end = t_near + d``: the camera ray starts on the near plane,
    ``t_near`` from the pinhole).
Light rays (:func:`light_ray_grid`)
    ``d`` light rays per row spanning ``γ ∈ [0, γ_max]``, ``γ_max`` = the
    largest ``γ_end`` of the row's queries; light ray (leaf) ``g`` covers
    ``[g, g+1)·Δγ``, ``Δγ = γ_max / d``.  A query's depth is the fractional
    light-ray index ``D = γ_end / Δγ`` (§5).
Blocker map (:func:`trace_blocker_angles`, :func:`shadow_map_blocker_angles`)
    Light ray γ of slice α is first blocked (coming from the light) at the
    axial coordinate ``u_b``; its points with ``u < u_b`` are in shadow, so
    view ray β is shadowed on it iff ``β > S := atan2(γ, u_b)`` (``S = π``
    when nothing blocks it).  ``traced``: the light rays are ray-traced with
    Mitsuba from outside the scene along ``-w_l`` (exact, no resampling,
    DESIGN §3).  ``resampled``: ``u_b`` is read from a classic orthographic
    :class:`~integrators.capture.ShadowMap` (nearest texel), as in the paper.
    Prefiltering (§7, Fig. 7): ``k`` stratified jittered sub-rays per
    light-ray interval give up to ``k`` depth modes of weight ``1/k``.
    :func:`blocker_modes` converts blocker angles to the sweep's view-ray
    index units: the number of the row's queries with ``β_q ≤ S`` (a mode
    at index ``m`` acts on queries ``m, m+1, ...``, i.e. exactly those with
    ``β_q > S``), merging sub-rays that land on the same index.
Light side (:func:`light_ray_grid`, :func:`light_side_factor`)
    With the medium box, the light-side path length of a point is
    ``τ = h(α, γ) − u``, ``h`` the axial coordinate where light ray γ leaves
    the box toward the light (DESIGN §1).  Hence

        e^{-σt τ} e^{-σt t} dt = L(γ) · K(γ, β) dγ / sin β,
        L(γ) = e^{-σt h(α, γ)},   K(γ, β) = e^{-σt γ tan(β/2)},

    a per-light-ray factor (the tree's ``L``, "textured light" of §6) times
    a kernel of (γ, β).  ``L`` is sampled at the light ray's centre and
    stored relative to the row's smallest ``h`` (``h_ref``: keeps thick
    media inside float32's range); ``K`` is averaged exactly over the
    light-ray interval: ``K(γ_g, β)·φ(σt tan(β/2) Δγ)``, ``γ_g`` the
    interval's start, ``φ(x) = (1 − e^{-x})/x`` (:func:`cell_average`).
Per-query terms (:func:`directional_query_terms`, :func:`assemble_queries`)
    ``L_scat = e^{σt (t_near − h_ref)} σs f_p E [Δγ φ/sin β · Σ_γ L K V cover − N]``:
    Mitsuba's phase function ``f_p`` (``phase_eval``, per query at its own
    ω) and delivered irradiance ``E`` (``sample_light``), the factor
    ``Δγ / sin β`` (``ds/dγ``, §4 Eq. 3), ``N`` the closed-form integral
    over ``[0, t_near]`` between pinhole and near plane (lit as the first
    light ray of the map says, :func:`first_leaf_visibility`), which the
    rectified sum includes but the camera ray does not, and
    ``e^{σt t_near}``, which re-bases the camera-side transmittance to the
    ray origin.  The light-ray interval in which the view ray ends counts
    the exact visibility of its covered part where its depth modes are
    mixed (:func:`last_interval_visibility`, :func:`last_interval_correction`).
Ring (§6; :func:`in_ring`, :func:`march_ring`)
    Samples whose view ray is within ``ring_deg`` of ``±w_l`` (rectify's
    :func:`~rectify.ring_mask` definition, evaluated at the sample's own
    direction) are ray-marched by brute force with exact (ray-traced)
    visibility, reusing :func:`integrators.marching.march`.  View rays
    within ``MIN_RING_RAD`` of the axis are always marched (``sin β → 0``).

Point and spot lights (§9): :func:`epipolar_frame_of`,
:func:`assign_queries`, the light-ray offset ``γ_lo`` of :class:`LightRays`,
:func:`rectified_depth` and the sub-ray and blocker-mode functions serve
them too, with γ the angle at the light (``rectify`` conventions); the
rest of the local-light maths (blockers traced from the light, intensity,
kernel, per-query terms) is in :mod:`integrators.epipolar_local_light`.
All Dr.Jit on the active variant; NumPy only for small
host-side tables.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import drjit as dr
import mitsuba as mi
import numpy as np

# submodules, not the package: ``rectify/__init__`` imports ``integrators``
# (which loads this module) before its own names exist
from rectify.coords import (direction_to_alpha_beta, light_coords_to_world, ray_meeting_t,
                            view_to_light)
from rectify.epipole import EpipolarFrame, directional_frame, point_frame
from rectify.slices import Slices, alpha_to_slice, make_slices

from .capture import CameraCapture, sample_rng, seed_offset
from .light_transport import (slabs, color, first_blocker, phase_eval, point, sample_light,
                              scalar, segment_box, segment_weight, vector, visible_exact)
from .partial_sum_tree import BlockerModes, factor_layout
from .marching import lit_spacing, march, march_bisected
from .opaque import Divisor, floats, scalar_u32

#: view rays closer than this to ±w_l [rad] are always ray-marched (sin β → 0)
MIN_RING_RAD = 1e-5
#: β of padded query slots: above every real β ∈ [0, π]
PAD_BETA = 4.0


# --------------------------------------------------------------------------
# Frame and slices (§3, §8)
# --------------------------------------------------------------------------

def epipolar_frame_of(params) -> EpipolarFrame:
    """The epipolar frame of the camera and the light: directional (§3), or
    point/spot at ``params.light.position`` (§9, axis = eye -> light)."""
    light = params.light
    if light.kind == "directional":
        return directional_frame(params.camera, light.direction)
    return point_frame(params.camera, light.position, kind=light.kind)


#: automatic slices: an image narrower than this many pixels is sliced as if
#: it were this wide (a pixel's half-width is then a wide angle, and a sample
#: that far from its slice sees other blockers)
MIN_SLICE_PIXELS = 256


def choose_slices(frame: EpipolarFrame, count: int = 0, spacing: float = 1.0) -> Slices:
    """``count = 0``: Baran's sinh distribution (§8), lines at most
    ``spacing`` px apart (1: every pixel within half a pixel of a slice),
    the spacing scaled down on images narrower than ``MIN_SLICE_PIXELS``;
    otherwise about ``count`` slices with end points equally spaced along the
    image edges the slices leave through."""
    if count <= 0:
        size = max(frame.width, frame.height)
        return make_slices(frame, "sinh", spacing=spacing * min(1.0, size / MIN_SLICE_PIXELS))
    border = make_slices(frame, "uniform", spacing=1.0).count   # ≈ exit-edge length [px]
    return make_slices(frame, "uniform", spacing=max(border, 1) / count)


def in_ring(beta, ring_deg: float) -> mi.Bool:
    """View ray within ``ring_deg`` of ±w_l (rectify.ring's definition)."""
    limit = max(math.radians(ring_deg), MIN_RING_RAD)
    return dr.minimum(beta, math.pi - beta) < limit


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


# --------------------------------------------------------------------------
# Queries: camera samples sorted into the slices' sweeps (§4)
# --------------------------------------------------------------------------

@dataclass(eq=False)
class EpipolarQueries:
    """Camera samples as queries of their nearest slice's sweep (module doc).

    Row arrays have ``n`` entries, query arrays ``Q`` (sorted by row, then β);
    ``ring_sample`` lists the camera samples to ray-march instead."""
    frame: EpipolarFrame
    slices: Slices
    n: int                     # rows = slices with queries
    r: int                     # padded queries per row
    slice_index: mi.UInt32     # (n,) index into ``slices``
    alpha: mi.Float            # (n,) α of each row's slice
    r_count: mi.UInt32         # (n,) queries per row
    sample: mi.UInt32          # (Q,) camera sample of each query
    row: mi.UInt32             # (Q,)
    col: mi.UInt32             # (Q,) position in the row's sweep
    beta: mi.Float             # (Q,) the query's own β
    gamma_end: mi.Float        # (Q,) γ of the end point: t_end·sin β (point/spot: angle)
    t_near: mi.Float           # (Q,) pinhole -> camera ray origin
    ring_sample: mi.UInt32     # (R,) camera samples inside the ring
    n_samples: int
    weight: mi.Float | None = None   # (Q,) share of its sample (slice interpolation); None: 1
    shares: float = 1.0        # queries per (non-ring) sample: 1, up to 2 with interpolation

    @property
    def count(self) -> int:
        return dr.width(self.sample) if self.n else 0

    @property
    def whole_frame(self) -> "EpipolarQueries":
        """The queries of the whole frame these belong to, on which frame-wide
        choices are made: themselves (a partial render's
        :class:`~integrators.row_subset.RowSubset`: the frame's)."""
        return self

    @property
    def slot(self) -> mi.UInt32:
        """Flat index ``row·r + col`` of each query in (n, r) maps."""
        return self.row * dr.opaque(mi.UInt32, self.r) + self.col

    def padded(self, values, fill: float) -> mi.Float:
        """(n·r,) map with the queries' ``values`` in their slots, ``fill`` elsewhere."""
        out = dr.full(mi.Float, fill, self.n * self.r)
        dr.scatter(out, values, self.slot)
        return out


def _nearest_slice(slices: Slices, alpha) -> mi.UInt32:
    k0, k1, f = alpha_to_slice(slices, alpha)
    return dr.select(f < 0.5, k0, k1)


#: slice interpolation: a sample within this fraction of the spacing of a
#: slice is a query of that slice alone
SNAP = 1e-3


def _slice_shares(slices: Slices, alpha, idx: mi.UInt32):
    """(sample, slice, weight) of the queries of samples ``idx`` when each
    is shared between its two neighbouring slices, weights 1 − f and f
    (:func:`~rectify.slices.alpha_to_slice`).  Only slices that are some
    sample's nearest (*used* slices) take shares: where the sinh placement
    (§8) puts slices closer than the pixels (toward the epipole) the others
    would add rows of their own for little, and the nearest slice is there
    well within half a pixel.  So a sample one of whose neighbours is
    nobody's nearest, or within ``SNAP`` of a slice, takes its nearest
    slice's answer alone (weight 1).  Such a *lone* sample (not snapped)
    also asks the used slice on its far side, with weight 0, so that
    :func:`disagreeing_samples` sees a shadow edge passing between the
    sample and its nearest slice (the beam's edge 0.05 px from a pixel
    centre at 24×18, where the nearest slice was lit and the pixel centre's
    ray is not)."""
    a = dr.gather(mi.Float, alpha, idx)
    k0, k1, f = alpha_to_slice(slices, a)
    nearest = dr.select(f < 0.5, k0, k1)
    used = dr.zeros(mi.Bool, slices.count)
    dr.scatter(used, True, nearest)
    both = dr.gather(mi.Bool, used, k0) & dr.gather(mi.Bool, used, k1)
    f = dr.select(both, f, dr.select(f < 0.5, 0.0, 1.0))
    f = dr.select(f < SNAP, 0.0, dr.select(f > 1.0 - SNAP, 1.0, f))
    first = f < 1.0                      # k0 takes a share
    second = f > 0.0                     # k1 takes a share
    i0, i1 = dr.compress(first), dr.compress(second)
    parts = [(i0, dr.gather(mi.UInt32, k0, i0), dr.gather(mi.Float, 1.0 - f, i0)),
             (i1, dr.gather(mi.UInt32, k1, i1), dr.gather(mi.Float, f, i1))]
    used_idx = dr.compress(used)
    if dr.width(used_idx) >= 2:
        u = np.asarray(used_idx, np.int64)
        sub = Slices(slices.alpha[u], slices.points[u], slices.wraps, "custom")
        j0, j1, fu = alpha_to_slice(sub, a)
        u0, u1 = dr.gather(mi.UInt32, used_idx, j0), dr.gather(mi.UInt32, used_idx, j1)
        far = dr.select(u0 == nearest, u1, u0)
        ip = dr.compress(~both & (far != nearest) & (fu > SNAP) & (fu < 1.0 - SNAP))
        parts.append((ip, dr.gather(mi.UInt32, far, ip), dr.zeros(mi.Float, dr.width(ip))))
    sample = _concat([dr.gather(mi.UInt32, idx, i) for i, _, _ in parts])
    k = _concat([kk for _, kk, _ in parts])
    weight = _concat([w for _, _, w in parts])
    return sample, k, weight


def _concat(parts):
    """``dr.concat`` of the non-empty ``parts`` (it refuses empty arrays,
    e.g. when no sample of a 1-pixel image falls between two slices)."""
    parts = [p for p in parts if dr.width(p)]
    if len(parts) == 1:
        return parts[0]
    out = dr.empty(type(parts[0]), sum(dr.width(p) for p in parts))
    offset = 0
    for p in parts:           # dr.concat would write each offset into its kernel
        dr.scatter(out, p, dr.arange(mi.UInt32, dr.width(p)) + dr.opaque(mi.UInt32, offset))
        offset += dr.width(p)
    return out


#: fewest bits of β in the one-key sort of :func:`_sweep_order`
MIN_BETA_BITS = 20


def _sweep_order(k: mi.UInt32, beta: mi.Float, slice_count: int) -> mi.UInt32:
    """Permutation sorting by (slice k, β) (Fig. 6's sweep order within each
    slice): one sort of the 32-bit key k·2^B + ⌊β/π·(2^B − 1)⌋, B = the bits
    the slice count leaves (≥ ``MIN_BETA_BITS``: β to π/2^20 ≈ 3e-6 rad,
    1/300 of a pixel at 1280×960; queries closer than that may swap, which
    moves a blocker edge by as much); else two stable sorts, exact."""
    bits = 32 - max(int(slice_count) - 1, 1).bit_length()
    if bits < MIN_BETA_BITS:
        order = dr.argsort(beta)
        return dr.gather(mi.UInt32, order, dr.argsort(dr.gather(mi.UInt32, k, order)))
    scale = float((1 << bits) - 1) / math.pi
    q = mi.UInt32(dr.clip(beta * scale, 0.0, float((1 << bits) - 1)))
    return dr.argsort((k << bits) | q)


def _rows(slices: Slices, k: mi.UInt32):
    """(slice_index, r_count, row, col) of queries already sorted by slice
    ``k``: the non-empty slices become rows 0..n-1, col = rank in the row."""
    counts = dr.zeros(mi.UInt32, slices.count)
    dr.scatter_reduce(dr.ReduceOp.Add, counts, mi.UInt32(1), k)
    used = counts > 0
    row_of_slice = dr.prefix_sum(dr.select(used, mi.UInt32(1), mi.UInt32(0)))  # exclusive
    slice_index = dr.compress(used)
    r_count = dr.gather(mi.UInt32, counts, slice_index)
    begin = dr.prefix_sum(r_count)
    row = dr.gather(mi.UInt32, row_of_slice, k)
    col = dr.arange(mi.UInt32, dr.width(k)) - dr.gather(mi.UInt32, begin, row)
    return slice_index, r_count, row, col


def _no_queries(frame, slices, ring_sample, n_samples) -> EpipolarQueries:
    u, f = dr.zeros(mi.UInt32, 0), dr.zeros(mi.Float, 0)
    return EpipolarQueries(frame, slices, 0, 0, u, f, u, u, u, u, f, f, f, ring_sample,
                           n_samples)


def end_gamma(frame: EpipolarFrame, beta, t_end) -> mi.Float:
    """γ of the point at distance ``t_end`` on view ray β: ``t_end·sin β``
    (directional, the distance from the axis, §3), or the angle at the light
    between the light ray through it and the direction light -> eye
    (point/spot, §9)."""
    if frame.is_directional:
        return t_end * dr.sin(beta)
    return view_to_light(frame, 0.0, beta, t_end)[0]


def assign_queries(params, frame: EpipolarFrame, slices: Slices, cap: CameraCapture,
                   ring_deg: float, interpolate: bool = False) -> EpipolarQueries:
    """Sort the camera samples of ``cap`` into the sweeps of their nearest
    slices (module doc), or with ``interpolate`` into both neighbouring
    slices, weighted by the sample's position between them
    (:func:`_slice_shares`; ``weight``); ring samples are listed apart,
    samples with ``d = 0`` are dropped (they scatter nothing).  ``γ_end``:
    :func:`end_gamma` of the light kind of ``frame``."""
    n_samples = dr.width(cap.d)
    alpha, beta = direction_to_alpha_beta(frame, cap.omega)
    ring = in_ring(beta, ring_deg) & (cap.d > 0)
    ring_sample = dr.compress(ring)
    idx = dr.compress((cap.d > 0) & ~ring)
    if dr.width(idx) == 0:
        return _no_queries(frame, slices, ring_sample, n_samples)
    weight, n_idx = None, dr.width(idx)
    if interpolate:
        idx, k, weight = _slice_shares(slices, alpha, idx)
    else:
        k = dr.gather(mi.UInt32, _nearest_slice(slices, alpha), idx)
    b = dr.gather(mi.Float, beta, idx)
    order = _sweep_order(k, b, slices.count)
    sample = dr.gather(mi.UInt32, idx, order)
    k, b = dr.gather(mi.UInt32, k, order), dr.gather(mi.Float, b, order)
    if weight is not None:
        weight = dr.gather(mi.Float, weight, order)
    slice_index, r_count, row, col = _rows(slices, k)
    pinhole = mi.Point3f(point(params.camera.origin))
    t_near = dr.norm(mi.Vector3f(dr.gather(mi.Point3f, cap.o, sample) - pinhole))
    gamma_end = end_gamma(frame, b, t_near + dr.gather(mi.Float, cap.d, sample))
    alpha_rows = dr.gather(mi.Float, floats(slices.alpha), slice_index)
    q = EpipolarQueries(frame, slices, dr.width(slice_index), int(dr.max(r_count)[0]),
                        slice_index, alpha_rows, r_count, sample, row, col, b, gamma_end,
                        t_near, ring_sample, n_samples, weight, dr.width(idx) / n_idx)
    dr.eval(q.slice_index, q.alpha, q.r_count, q.sample, q.row, q.col, q.beta,
            q.gamma_end, q.t_near, q.ring_sample, *([] if weight is None else [weight]))
    return q


# --------------------------------------------------------------------------
# Light rays (§3, §5)
# --------------------------------------------------------------------------

class LightRayLayout:
    """The light-ray layout protocol: what every stage after the light rays
    (blockers, light factor, kernel, sweep, query terms) may read.

    Every layout is a frozen dataclass with the fields ``d`` (light rays per
    row, the sweep's leaves), ``gamma_max`` (n,) (each row's last γ) and
    ``delta_gamma`` (n,) (each row's light-ray width; the mean width where
    they are unequal), and the methods :meth:`lanes`, :meth:`positions` and
    :meth:`row_counts`.  Layouts: :class:`LightRays` (directional),
    :class:`~integrators.epipolar_local_light.LocalLightRays` (point/spot),
    :class:`~integrators.fourier_setup.ProjectiveLightRays` (Klehm §4.2)."""

    def lanes(self, per_ray: int = 1):
        """(row s, light ray g, sub-ray m) of ``n·d·per_ray`` lanes."""
        n = dr.width(self.delta_gamma)
        j = dr.arange(mi.UInt32, n * self.d * per_ray)
        return (Divisor(self.d * per_ray).div(j), Divisor(self.d).divmod(j // per_ray)[1],
                j % per_ray)

    def positions(self, offset: float = 0.5):
        """(row, γ) of every light ray at ``offset`` ∈ [0, 1] across its
        interval (0.5: its centre, 0: its start), (n·d,) lanes."""
        raise NotImplementedError

    def row_counts(self):
        """(n,) light rays that exist per row, or None: all ``d``."""
        return None


class EqualLightRays(LightRayLayout):
    """Equally wide light rays from each row's ``γ_lo``: leaf ``g`` covers
    ``γ_lo + [g, g+1)·Δγ``.  Adds the field ``gamma_lo`` ((n,) or None: 0)
    and :meth:`start`; what the sub-ray, rectified-depth and blocker-mode
    functions need."""

    def start(self, s) -> mi.Float:
        """γ_lo of rows ``s`` (0 when the rows start at the axis)."""
        if self.gamma_lo is None:
            return dr.zeros(mi.Float, dr.width(s))
        return dr.gather(mi.Float, self.gamma_lo, s)

    def positions(self, offset: float = 0.5):
        s, g, _ = self.lanes()
        return s, self.start(s) + (mi.Float(g) + offset) * dr.gather(mi.Float, self.delta_gamma, s)


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
    #: rows (a partial render, :mod:`integrators.row_subset`); None: 0..n-1
    row_id: mi.UInt32 | None = None


def row_gamma_end(queries: EpipolarQueries, floor: float) -> mi.Float:
    """(n,) the largest γ_end of each row's queries, at least ``floor``: how
    far the row's light rays must reach (both light kinds)."""
    gamma_max = dr.zeros(mi.Float, queries.n)
    dr.scatter_reduce(dr.ReduceOp.Max, gamma_max, queries.gamma_end, queries.row)
    return dr.maximum(gamma_max, floor)


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
    (:func:`~integrators.epipolar_local_light.local_light_ray_grid`)."""
    gamma_max = row_gamma_end(queries, 1e-6 * params.scene_extent)
    auto = not d
    d = light_ray_count(params, d, float(dr.max(gamma_max)[0]))
    rays = with_box_exits(params, queries, LightRays(int(d), gamma_max, gamma_max / d))
    if auto:
        step = light_side_step(params, rays)
        if step > LIGHT_SIDE_STEP and d < MAX_AUTO_LIGHT_RAYS:
            d = min(MAX_AUTO_LIGHT_RAYS, math.ceil(d * step / LIGHT_SIDE_STEP))
            rays = with_box_exits(params, queries, LightRays(int(d), gamma_max, gamma_max / d))
    dr.eval(rays.gamma_max, rays.delta_gamma)
    return rays


#: the automatic light rays: largest change σt·|Δh| of the light-side
#: optical depth from one light ray to the next where the light arrives
#: (:func:`light_side_step`)
LIGHT_SIDE_STEP = 0.25
#: ... where it arrives: σt·(h − h_ref) below this on both light rays
LIGHT_SIDE_ARRIVES = 10.0


def light_side_step(params, rays: LightRays) -> float:
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
    below ``LIGHT_SIDE_STEP``."""
    d = rays.d
    if d < 2:
        return 0.0
    sigma_t = scalar(np.max(params.medium.sigma_t))
    s, g, _ = rays.lanes()
    d = dr.opaque(mi.UInt32, d)
    nxt = s * d + dr.minimum(g + 1, d - 1)
    h, h_n = rays.h, dr.gather(mi.Float, rays.h, nxt)
    h_ref = dr.gather(mi.Float, rays.h_ref, s)
    arrives = sigma_t * (dr.maximum(h, h_n) - h_ref) <= LIGHT_SIDE_ARRIVES
    ok = (g + 1 < d) & dr.isfinite(h) & dr.isfinite(h_n) & arrives
    step = dr.select(ok, sigma_t * dr.abs(h_n - h), 0.0)
    return float(dr.max(step)[0])


def with_box_exits(params, queries: EpipolarQueries, rays):
    """``rays`` (a directional layout: :class:`LightRays` or
    :class:`~integrators.fourier_setup.ProjectiveLightRays`) with ``h``
    (where the light ray through each centre, ``rays.positions(0.5)``,
    leaves the medium box toward the light; +inf if it misses the box) and
    the rows' ``h_ref`` (:func:`row_reference`)."""
    frame = queries.frame
    s, gamma = rays.positions(0.5)
    base = light_coords_to_world(frame, _row_alpha(queries, s), gamma, 0.0)
    h, hits = axial_exit(params, base, vector(frame.axis))
    h = dr.select(hits, h, dr.inf)
    h_ref = row_reference(params, h, s, queries.n)
    dr.eval(h, h_ref)
    return replace(rays, h=h, h_ref=h_ref)


#: light-side range c: a light ray leaving the box toward the light at
#: σt·h < −c (more than c mean free paths *behind* the eye, along the
#: light) is dropped, and no row's reference h_ref lies below −c/σt
LIGHT_SIDE_RANGE = 7.0


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
    it, worth at most e^{-c} ≈ 1e-3 of full scale, are dropped by
    :func:`light_side_factor`, and the automatic SVD rank tightens its
    tolerance by the row's e^{σt h_ref} (:func:`light_side_gains`)."""
    h_ref = dr.full(mi.Float, dr.inf, n)
    dr.scatter_reduce(dr.ReduceOp.Min, h_ref, h, s)
    h_ref = dr.select(dr.isfinite(h_ref), h_ref, 0.0)
    sigma_t_max = float(np.max(params.medium.sigma_t))
    if sigma_t_max > 0.0:
        h_ref = dr.maximum(h_ref, scalar(-LIGHT_SIDE_RANGE / sigma_t_max))
    return h_ref


def light_side_gains(sigma_t, path: mi.Float) -> list[float]:
    """Per channel of extinction ``sigma_t``: e^{-σt·min(lowest, 0)}, at
    most e^{c}, ``lowest`` the smallest finite light-side path length of
    ``path`` (a directional light's h, :func:`row_reference`; a point
    light's L − r_in): how much the light-side factor (e^{-σt h_ref}·L of
    the kept light rays) amplifies the tree's absolute errors.  The
    automatic SVD rank divides its tolerance by it."""
    lowest = min(float(dr.min(dr.select(dr.isfinite(path), path, 0.0))[0]), 0.0)
    return [math.exp(min(LIGHT_SIDE_RANGE, -float(st) * lowest))
            for st in np.atleast_1d(np.asarray(sigma_t, np.float64))]


def rectified_depth(queries: EpipolarQueries, rays: LightRays) -> mi.TensorXf:
    """D (n, r): each query's depth as a fractional light-ray index (§5),
    ``(γ_end − γ_lo) / Δγ`` (clipped to [0, d] by the sweep)."""
    D = ((queries.gamma_end - rays.start(queries.row))
         / dr.gather(mi.Float, rays.delta_gamma, queries.row))
    return mi.TensorXf(queries.padded(D, 0.0), shape=(queries.n, queries.r))


def sub_ray_gamma(rays: LightRays, k: int, seed: int):
    """(row, γ) of ``k`` stratified jittered sub-rays per light ray (§7),
    (n·d·k,) lanes in (row, light ray, sub-ray) order; ``k = 1``: the light
    ray's centre.  A sub-ray's random numbers are keyed by its lane in the
    whole frame (``rays.row_id``), so a subset of the rows draws the full
    render's."""
    s, g, m = rays.lanes(k)
    if k == 1:
        xi = mi.Float(0.5)
    else:
        n = dr.width(s)
        row_id = getattr(rays, "row_id", None)
        lane = (dr.arange(mi.UInt32, n) if row_id is None else
                (dr.gather(mi.UInt32, row_id, s) * rays.d + g) * k + m)
        rng = sample_rng(lane, seed_offset(seed, 0x2545F4914F6CDD1D))
        xi = (mi.Float(m) + rng.next_float32()) / k
    return s, rays.start(s) + (mi.Float(g) + xi) * dr.gather(mi.Float, rays.delta_gamma, s)


def _row_alpha(queries, s):
    return dr.gather(mi.Float, queries.alpha, s)


# --------------------------------------------------------------------------
# Blocker maps S[α, γ] (§3, §7)
# --------------------------------------------------------------------------

def _light_top(params, frame: EpipolarFrame) -> float:
    """Axial coordinate u beyond every scene object (rays start there)."""
    bb = params.scene.bbox()
    corners = np.array([[x, y, z] for x in (bb.min[0], bb.max[0])
                        for y in (bb.min[1], bb.max[1]) for z in (bb.min[2], bb.max[2])])
    u = (corners - params.camera.origin) @ frame.axis
    return float(np.max(u)) + 1e-2 * params.scene_extent


#: |second difference| of the blocker indices at neighbouring light-ray
#: boundaries above which an interval traces its §7 sub-rays (in queries;
#: doubled where slice interpolation shares samples between two slices)
EDGE_INDEX_JUMP = 1
#: intervals on either side of a non-smooth boundary that trace their sub-rays too
DILATE = 2
#: rows with more than this fraction of non-smooth intervals trace all sub-rays
DENSE_ROW = 0.15


def _blocker_depth(params, queries: EpipolarQueries, s, gamma):
    """(hit, u_b) of the light rays (row s, γ), traced from above the scene
    along -w_l (:func:`first_blocker`): whether a blocker is met and its
    axial coordinate."""
    frame = queries.frame
    U = scalar(_light_top(params, frame))
    origin = light_coords_to_world(frame, _row_alpha(queries, s), gamma, U)
    w = vector(frame.axis)
    hit, p = first_blocker(params, origin, -w)
    u_b = dr.dot(mi.Vector3f(p - point(params.camera.origin)), w)
    return hit, u_b


def _blocker_angle(params, queries: EpipolarQueries, s, gamma) -> mi.Float:
    """atan2(γ, u_b) of the light rays (row s, γ) (:func:`_blocker_depth`);
    π where nothing blocks."""
    hit, u_b = _blocker_depth(params, queries, s, gamma)
    return dr.select(hit, dr.atan2(gamma, u_b), math.pi)


def _smooth_intervals(queries: EpipolarQueries, rays: LightRays, s_b, gamma_b, hit, u_b):
    """(smooth, e): per light-ray interval (n·d lanes) whether the blockers traced at the
    d + 1 interval boundaries of its row vary smoothly enough around it for
    a linear interpolation of u_b to place every sub-ray in its depth mode.

    A boundary is *calm* when its hit status equals its neighbours' and the
    |second difference| of the boundary blocker indices (in queries) is ≤
    ``EDGE_INDEX_JUMP``: a plane (a floor, a roof, at any light angle: u_b
    linear in γ) is calm, a blocker edge, a thin occluder crossing a
    boundary or a staircase of leaves is not.  An interval is smooth when
    its two boundaries and ``DILATE`` more on either side are calm (thin
    blockers cluster near edges), and its row is not dense with edges
    (> ``DENSE_ROW`` of the row's intervals rough: foliage, where the
    leaves between boundaries are what the sub-rays are for).  Measured at
    640×480: 2-8 % of the intervals traced on the nave and terrain (same
    relMSE as tracing all), 82 % on the grove (relMSE 4.7e-5 → 5.1e-5).
    ``e``: the blocker index of every boundary (n·(d + 1) lanes)."""
    nb = Divisor(rays.d + 1)       # boundaries per row (the frame's: opaque)
    d = dr.opaque(mi.Int32, rays.d)
    e = mi.Int32(searchsorted_rows(queries, s_b, dr.select(hit, dr.atan2(gamma_b, u_b),
                                                           math.pi)))
    g_b = mi.Int32(nb.divmod(dr.arange(mi.UInt32, dr.width(s_b)))[1])

    def at(values, tp, s, g, offset):
        return dr.gather(tp, values, s * nb.d + mi.UInt32(dr.clip(g + offset, 0, d)))

    # in samples, not queries: a sample shared by two slices (interpolation)
    # makes up to two queries of a row
    jump = EDGE_INDEX_JUMP * math.ceil(queries.shares - 1e-6)
    calm = ((mi.Float(dr.abs(at(e, mi.Int32, s_b, g_b, -1) - 2 * e + at(e, mi.Int32, s_b, g_b, 1)))
             <= jump)
            & ~(hit ^ at(hit, mi.Bool, s_b, g_b, -1)) & ~(hit ^ at(hit, mi.Bool, s_b, g_b, 1)))
    s, g, _ = rays.lanes()
    smooth = mi.Bool(True)
    for offset in range(-DILATE, DILATE + 2):
        smooth &= at(calm, mi.Bool, s, mi.Int32(g), offset)
    rough = dr.zeros(mi.UInt32, dr.width(rays.delta_gamma))
    dr.scatter_reduce(dr.ReduceOp.Add, rough, dr.select(smooth, mi.UInt32(0), mi.UInt32(1)), s)
    dense = mi.Float(rough) > scalar(DENSE_ROW * rays.d)
    return smooth & ~dr.gather(mi.Bool, dense, s), e


class SubRayBlockers(NamedTuple):
    """Blocker angles of the sub-rays (n·d·k lanes) and, where known, the
    range [lo, hi] their row index (:func:`searchsorted_rows`) lies in."""
    angle: mi.Float
    lo: mi.UInt32 | None = None
    hi: mi.UInt32 | None = None


def trace_blocker_angles(params, queries: EpipolarQueries, rays: LightRays, k: int = 1,
                         seed: int = 0, adaptive: bool = False) -> mi.Float:
    """S = atan2(γ, u_b) of ``k`` sub-rays per light ray, (n·d·k,) lanes in
    (row, light ray, sub-ray) order; π where nothing blocks the sub-ray
    (:func:`trace_sub_ray_blockers` without the index bounds)."""
    return trace_sub_ray_blockers(params, queries, rays, k, seed, adaptive).angle


def adaptive_sub_ray_gamma(rays: LightRays, k: int, seed: int = 0):
    """(row, γ) of the sub-rays of ``trace_sub_ray_blockers(adaptive=True)``:
    :func:`sub_ray_gamma`'s, but sub-ray 0 at the centre of the first
    stratum, where the interval's boundary ray is traced."""
    s, gamma = sub_ray_gamma(rays, k, seed)
    _, g, m = rays.lanes(k)
    first = rays.start(s) + (mi.Float(g) + 0.5 / k) * dr.gather(mi.Float, rays.delta_gamma, s)
    return s, dr.select(m == 0, first, gamma)


def trace_sub_ray_blockers(params, queries: EpipolarQueries, rays: LightRays, k: int = 1,
                           seed: int = 0, adaptive: bool = False) -> SubRayBlockers:
    """S = atan2(γ, u_b) of ``k`` sub-rays per light ray (:func:`trace_blocker_angles`).

    Each sub-ray is traced with Mitsuba from outside the scene along -w_l.
    With ``adaptive`` (§7's sub-rays only where they matter), the d + 1
    boundaries of each row's light-ray intervals are traced first; in the
    intervals where the blockers vary smoothly (:func:`_smooth_intervals`)
    the sub-rays' u_b is interpolated linearly between the two boundaries
    (exact for planar blockers), elsewhere the k sub-rays are traced.  The
    boundaries sit at the centres of the intervals' first strata and serve
    as their sub-ray 0 (so a rough interval traces k − 1 more rays); the
    other sub-rays are jittered in their strata as without ``adaptive``.  Away from
    edges this traces one ray per light ray instead of ``k``; a blocker
    thinner than a light-ray interval that crosses no boundary is missed
    (the sub-rays would have found it with probability < 1).  An
    interpolated sub-ray's point (u, γ) moves on the straight segment
    between the boundaries' blocker points, so its angle -- and its row
    index -- lies between theirs: the result carries those index bounds,
    which make :func:`blocker_modes` nearly free where both are equal."""
    s, gamma = sub_ray_gamma(rays, k, seed)
    if k == 1 or not adaptive:
        out = _blocker_angle(params, queries, s, gamma)
        dr.eval(out)
        return SubRayBlockers(out)
    nb = Divisor(rays.d + 1)       # boundaries per row
    n = dr.width(rays.delta_gamma)
    j = dr.arange(mi.UInt32, n * nb.value)
    s_b, j_b = nb.divmod(j)
    c0 = 0.5 / k          # the boundaries sit at the centres of the first strata
    gamma_b = (rays.start(s_b)
               + (mi.Float(j_b) + c0) * dr.gather(mi.Float, rays.delta_gamma, s_b))
    hit, u_b = _blocker_depth(params, queries, s_b, gamma_b)
    dr.eval(hit, u_b)
    smooth, e = _smooth_intervals(queries, rays, s_b, gamma_b, hit, u_b)
    dr.eval(smooth, e)
    # every sub-ray interpolated: u_b lerped at its place between the
    # boundaries; sub-ray 0 *is* its interval's boundary (f = 0, exact)
    lane = dr.arange(mi.UInt32, dr.width(s))
    owner, m = lane // k, lane % k                        # its interval (n·d lanes)
    g = Divisor(rays.d).divmod(owner)[1]
    b = s * nb.d + g
    dg = dr.gather(mi.Float, rays.delta_gamma, s)
    gamma = adaptive_sub_ray_gamma(rays, k, seed)[1]
    f = dr.select(m == 0, 0.0, (gamma - rays.start(s)) / dg - mi.Float(g) - c0)
    u = dr.lerp(dr.gather(mi.Float, u_b, b), dr.gather(mi.Float, u_b, b + 1), f)
    out = dr.select(dr.gather(mi.Bool, hit, b), dr.atan2(gamma, u), math.pi)
    e0, e1 = dr.gather(mi.Int32, e, b), dr.gather(mi.Int32, e, b + 1)
    lo, hi = mi.UInt32(dr.minimum(e0, e1)), mi.UInt32(dr.maximum(e0, e1))
    dr.eval(out, lo, hi)
    # ... and traced (but sub-ray 0, traced already), with the whole row as
    # index range, where not smooth
    sel = dr.compress(~dr.gather(mi.Bool, smooth, owner) & (m != 0))
    if dr.width(sel):
        sub = _blocker_angle(params, queries, dr.gather(mi.UInt32, s, sel),
                             dr.gather(mi.Float, gamma, sel))
        dr.scatter(out, sub, sel)
        dr.scatter(lo, 0, sel)
        dr.scatter(hi, dr.opaque(mi.UInt32, queries.r), sel)
    dr.eval(out, lo, hi)
    return SubRayBlockers(out, lo, hi)


def shadow_map_blocker_angles(params, queries: EpipolarQueries, rays, shadow_map, light,
                              k: int = 1, seed: int = 0) -> mi.Float:
    """Like :func:`trace_blocker_angles`, but each sub-ray's blocker read from
    a classic :class:`~integrators.capture.ShadowMap` (nearest texel, the
    paper's "rectify the shadow map", §3), for either light kind: a light ray
    of either kind is one of the map's own rays (parallel to an orthographic
    map's, through a perspective or cube map's centre), so it meets one
    texel.  ``light`` (the light model) names the maps it reads
    (``shadow_maps``), where a light ray meets its map (``map_point``) and
    the eye's angle of the blocker at the texel's depth
    (``map_blocker_beta``); π where the map records no blocker."""
    if shadow_map.kind not in light.shadow_maps:
        raise ValueError(f"a {params.light.kind} light needs a shadow map of kind "
                         f"{' or '.join(light.shadow_maps)}, not {shadow_map.kind!r}")
    frame = queries.frame
    s, gamma = sub_ray_gamma(rays, k, seed)
    alpha = _row_alpha(queries, s)
    z_b = shadow_map.nearest_depth(light.map_point(frame, alpha, gamma))
    beta_b = dr.select(dr.isfinite(z_b),
                       light.map_blocker_beta(params, frame, shadow_map, alpha, gamma, z_b),
                       math.pi)
    dr.eval(beta_b)
    return beta_b


def axial_map_point(frame: EpipolarFrame, alpha, gamma) -> mi.Point3f:
    """Directional light: the point u = 0 of light ray (α, γ)."""
    return light_coords_to_world(frame, alpha, gamma, 0.0)


def axial_blocker_beta(params, frame: EpipolarFrame, shadow_map, alpha, gamma, z_b) -> mi.Float:
    """Directional light: β_b = atan2(γ, u_b) of the blocker at depth z_b of
    an orthographic map.  A point x at depth z = s0 − x·w is shadowed iff
    z > z_b + bias ⟺ u < s0 − o·w − z_b − bias (o: the eye)."""
    w = np.asarray(shadow_map.frames[0][2], np.float64)
    top = shadow_map.s0 - float(params.camera.origin @ w) - shadow_map.bias
    return dr.atan2(gamma, top - z_b)


def searchsorted_rows(queries: EpipolarQueries, s, x, lo=None, hi=None) -> mi.UInt32:
    """Number of queries of row ``s`` with β ≤ ``x`` (per lane); with
    ``lo``/``hi``: known to lie in [lo, hi] (a per-lane bisection that ends
    at once where lo = hi)."""
    beta_pad = queries.padded(queries.beta, PAD_BETA)
    r = dr.opaque(mi.UInt32, queries.r)
    base = s * r

    def pred(i):
        inside = i < r
        return inside & (dr.gather(mi.Float, beta_pad, base + dr.minimum(i, r - 1)) <= x)

    if lo is None:      # a bisection over [0, r] (r opaque: dr.binary_search unrolls it)
        lo, hi = dr.zeros(mi.UInt32, dr.width(x)), dr.zeros(mi.UInt32, dr.width(x)) + r

    def body(a, b):
        mid = (a + b) >> 1
        left = pred(mid)
        return dr.select(left, mid + 1, a), dr.select(left, b, mid)

    a, _ = dr.while_loop(state=(mi.UInt32(lo), mi.UInt32(hi)), cond=lambda a, b: a < b,
                         body=body)
    return a


def merge_modes(index: mi.UInt32, k: int):
    """(β index, weight) of the k sub-rays of each light ray, equal indices
    merged into one mode of weight count/k (§7, Fig. 7); merged-away slots
    get weight 0 (no update).  One lane per sub-ray slot, compared with the
    k slots of its light ray."""
    j = dr.arange(mi.UInt32, dr.width(index))
    m, base = j % k, j - j % k
    own = mi.Float(index)
    first, same = mi.Bool(True), mi.Float(0.0)
    for i in range(k):
        v = dr.gather(mi.UInt32, index, base + i)
        equal = v == index
        first &= ~(equal & (i < m))
        same += dr.select(equal, 1.0, 0.0)
    return own, dr.select(first, same / k, 0.0)


def blocker_modes(queries: EpipolarQueries, rays: LightRays, beta_b, k: int) -> BlockerModes:
    """Blocker angles of k sub-rays per light ray (a Float, or
    :class:`SubRayBlockers` with index bounds) -> depth modes in the
    sweep's index units (module doc), (n, d, k) tensors."""
    s, _, _ = rays.lanes(k)
    if not isinstance(beta_b, SubRayBlockers):
        beta_b = SubRayBlockers(beta_b)
    index = searchsorted_rows(queries, s, beta_b.angle, beta_b.lo, beta_b.hi)
    b, w = merge_modes(index, k)
    shape = (queries.n, rays.d, k)
    modes = BlockerModes(mi.TensorXf(b, shape=shape), mi.TensorXf(w, shape=shape))
    dr.eval(modes.beta, modes.weight)
    return modes


# --------------------------------------------------------------------------
# Light side (DESIGN §1, Baran §6 "textured light")
# --------------------------------------------------------------------------

def gray(sigma_t) -> bool:
    s = np.asarray(sigma_t, np.float64)
    return bool(np.all(s == s[0]))


def axial_exit(params, x, w):
    """(h, hits): axial coordinate where the line x + u·w leaves the medium
    box toward the light, and whether the line meets the box at all."""
    t_near, t_far = slabs(x, w, point(params.medium.bounds_min), point(params.medium.bounds_max))
    return t_far, t_far >= t_near


def light_side_extinction(sigma_t: float, path, ref=None):
    """e^{-σt (path − ref)} per light ray (``ref`` None: 0) -- the light
    side of the per-light-ray factor of both light kinds (directional:
    path = h, ref = the row's h_ref; point/spot: path = L − r_in) -- and 0
    where the path is not finite (the light ray misses the box: +inf, NaN)
    or σt·path < −c (c = ``LIGHT_SIDE_RANGE``).  A light ray whose path is
    negative (it leaves the box toward the light *behind* the eye) has a
    factor above 1, but each of its points is at least |path| from the eye,
    so it contributes at most e^{-σt |path|} of the unattenuated single
    scattering: dropping those beyond c keeps every factor ≤ e^{c}
    (:func:`row_reference`)."""
    rel = path if ref is None else path - ref
    st = scalar(sigma_t)
    return dr.select(dr.isfinite(rel) & (-st * path <= LIGHT_SIDE_RANGE), dr.exp(-st * rel), 0.0)


def light_ray_channels(values: list, n: int, d: int) -> mi.TensorXf:
    """The per-light-ray factor as the sweep takes it: (n, d) for one
    channel, (n, d, C) for C, from C Floats of n·d light rays."""
    if len(values) == 1:
        return mi.TensorXf(values[0], shape=(n, d))
    C = len(values)
    out = dr.zeros(mi.Float, n * d * C)
    lane = dr.arange(mi.UInt32, n * d)
    for c, v in enumerate(values):
        dr.scatter(out, v, lane * C + c)
    return mi.TensorXf(out, shape=(n, d, C))


def light_side_factor(params, queries: EpipolarQueries, rays: LightRays) -> mi.TensorXf:
    """L(γ) = e^{-σt (h(α, γ) − h_ref(α))} at every light ray's centre:
    (n, d) if σt is grey, else (n, d, 3).  Relative to the row's h_ref so
    that thick media stay inside float32's range; the factor e^{-σt h_ref}
    is applied per query (:func:`directional_query_terms`).  Light rays
    with σt·h < −c are 0 (:func:`light_side_extinction`); so
    e^{-σt h_ref}·L ≤ e^{c} everywhere."""
    s, _, _ = rays.lanes()
    h_ref = dr.gather(mi.Float, rays.h_ref, s)
    sigma_t = params.medium.sigma_t
    channels = [0] if gray(sigma_t) else [0, 1, 2]
    return light_ray_channels([light_side_extinction(sigma_t[c], rays.h, h_ref)
                               for c in channels], queries.n, rays.d)


# --------------------------------------------------------------------------
# Per-query terms and the way back to camera samples
# --------------------------------------------------------------------------

@dataclass(eq=False)
class QueryTerms:
    """Per-query factors of the directional-light formulation (module doc);
    ``last``: the change of the rectified integral when the last, partial
    light-ray interval takes the visibility of :func:`last_interval_visibility`
    instead of its leaf's (:func:`last_interval_correction`; 0: none)."""
    radiance: mi.Color3f    # σs · f_p · E · e^{-σt h_ref} · e^{σt t_near}
    view: mi.Color3f        # Δγ / sin β · φ(σt tan(β/2) Δγ)
    near: mi.Color3f        # V · ∫ over [0, t_near] of e^{-σt (h(0) − h_ref)} e^{-σt t(1−cos β)} dt
    last: object = 0.0      # f · (V_last − V_leaf) · Σ_i B_i(β) A_i(k0) L(k0), integral units
    magnitude: object = None  # Σ_{γ<D} Σ_i |A_i L| |B_i(β)| (sweep_magnitude); None: no flush


def leaf_visibility(queries: EpipolarQueries, modes: BlockerModes, leaf=0) -> mi.Float:
    """V(γ ∈ leaf, β_q) per query from the blocker modes, with the sweep's
    semantics (:mod:`~integrators.partial_sum_tree`: a mode at index m
    removes its weight from the row's queries m, m+1, ...); ``leaf``: one
    light-ray index for all queries, or one per query."""
    return mode_visibility(modes, queries.row, queries.col, leaf)


def mode_visibility(modes: BlockerModes, row, col, leaf) -> mi.Float:
    """:func:`leaf_visibility` of arbitrary (row, view-ray index ``col``,
    leaf) lanes."""
    k = modes.beta.shape[2]
    d = modes.beta.shape[1]
    beta, weight = mi.Float(modes.beta.array), mi.Float(modes.weight.array)
    base = (row * d + mi.UInt32(leaf)) * k
    col = mi.Float(col)
    V = mi.Float(1.0)
    for m in range(k):
        acts = dr.gather(mi.Float, beta, base + m) <= col
        V -= dr.select(acts, dr.gather(mi.Float, weight, base + m), 0.0)
    return V


def first_leaf_visibility(queries: EpipolarQueries, modes: BlockerModes,
                          last: "LastInterval | None" = None) -> mi.Float:
    """V(γ ∈ leaf 0, β_q) per query from the blocker modes: the visibility of
    the rectified map next to the eye, which the sweep applies to the part
    of the view ray in front of the near plane.  With ``last``
    (:func:`last_interval_visibility`), queries whose view ray ends in leaf
    0 take the last interval's visibility instead: the near segment is part
    of that interval and must be removed with the visibility it was counted
    with."""
    V = leaf_visibility(queries, modes, 0)
    if last is not None:
        V = dr.select(last.k0 == 0, last.V, V)
    return V


# -- the last, partial light-ray interval of each query (§5 lerp, §7 modes) --

#: a leaf's depth-mode visibility counts as mixed (0 < V < 1), or as
#: different from the previous leaf's, beyond this margin (float sums of
#: the §7 weights count/k)
MIXED_MARGIN = 1e-3
#: the shadow ray of a last interval starts at least this far [× scene
#: extent] before the surface the view ray ends on
LAST_INTERVAL_EPS = 1e-5


@dataclass(eq=False)
class LastInterval:
    """The light-ray interval in which each query's view ray ends and its
    visibility (:func:`last_interval_visibility`); (Q,) arrays."""
    k0: mi.UInt32       # the leaf ⌊D⌋ of the sweep's lerp (clamped as the sweep clamps D)
    f: mi.Float         # the fraction D − k0 of it the view ray covers
    V_leaf: mi.Float    # its visibility from the leaf's depth modes: what the sweep counted
    V: mi.Float         # the visibility of the covered part [k0, D] of the query's own ray
    idx: mi.UInt32      # the queries whose V was ray-traced (elsewhere V = V_leaf)

    @property
    def traced(self) -> int:
        return dr.width(self.idx)


def last_leaf(queries: EpipolarQueries, rays, D: mi.TensorXf) -> tuple[mi.UInt32, mi.Float]:
    """(k0, f) per query: the leaf k0 = ⌊D⌋ of the sweep's lerp in which its
    view ray ends and the fraction f = D − k0 of it the ray covers, with the
    sweep's (n, r) depths ``D`` clamped to ``[0, d_count]`` as the sweep
    clamps them (per row where the layout has ``row_counts()``)."""
    d_count = rays.row_counts()
    d_s = (dr.zeros(mi.Float, queries.count) + scalar(rays.d) if d_count is None
           else mi.Float(dr.gather(mi.UInt32, d_count, queries.row)))
    Dq = dr.gather(mi.Float, mi.Float(D.array), queries.slot)
    Dq = dr.clip(dr.select(dr.isnan(Dq), 0.0, Dq), 0.0, d_s)
    k0 = dr.maximum(dr.minimum(dr.floor(Dq), d_s - 1.0), 0.0)
    return mi.UInt32(k0), Dq - k0


def last_interval_visibility(params, cap: CameraCapture, queries: EpipolarQueries,
                             rays: LightRays, modes: BlockerModes,
                             D: mi.TensorXf, k: int = 1) -> LastInterval:
    """Visibility of the last, partial light-ray interval of every query.

    The sweep lerps two prefix sums (Baran §5, Fig. 6): the interval
    ``[k0, D]`` (k0 = ⌊D⌋, in light rays) in which the view ray ends counts
    as the fraction f = D − k0 of leaf k0, lit as that leaf's §7 depth
    modes say at the query's β.  Those modes prefilter the *whole* interval
    ``[k0, k0 + 1)``, but only its part in front of the end point lies on
    the view ray; the sub-rays beyond it sample the ray's continuation
    behind the surface it ends on.  At that surface the blocker map S(γ)
    crosses β (the end point is, or lies behind, the first blocker of its
    light ray), so the continuation's visibility is typically the opposite
    of the covered part's: a lit surface seen through lit medium darkens
    the end of the ray; a thin or open surface seen from its shadowed side
    -- a plate, the single-sheet terrain whose faces turned away from a
    grazing sun are lit from behind through the height field's open edge --
    puts light into a ray that is in shadow all along (the leak of
    results/tree_accuracy on ``terrain``: up to 0.019 at 640×480 where the
    exact reference is 0).  Finer light rays shrink the interval; finer
    slices barely change it.

    Hence, where the last interval's visibility is uncertain -- its modes
    are mixed at the query's β (0 < V < 1), or differ from the previous
    leaf's (all sub-rays may lie beyond the end when f is below the first
    stratum; with ``prefilter`` = 1 this is the only sign) -- V is
    ray-traced exactly on the query's own camera ray (its own α, not its
    slice's): the covered part is cut into ⌈k·f⌉ equal pieces (``k``: the
    §7 sub-rays per interval, so the same density) and V is the lit
    fraction of shadow rays (:func:`~integrators.light_transport.visible_exact`)
    from their centres, as a ray marcher with those steps would count it.
    (One ray from the middle was tried first: it removes the leak as well,
    but turns a shadow edge inside an almost fully covered interval next to
    the epipole, which the modes resolve, into an error of up to half the
    interval.)  Elsewhere all sub-rays of the interval and of the previous
    one agree and the leaf's visibility is kept, so only the queries whose
    last interval holds a shadow edge are traced (a few percent on an
    open nave, most of them on a point light's lit walls).  The correction
    of the sweep's sum is :func:`last_interval_correction`.

    ``D``: the sweep's (n, r) depths (:func:`last_leaf`)."""
    k0, f = last_leaf(queries, rays, D)
    V_leaf = leaf_visibility(queries, modes, k0)
    V_prev = leaf_visibility(queries, modes, dr.maximum(k0, 1) - 1)
    mixed = (V_leaf > MIXED_MARGIN) & (V_leaf < 1.0 - MIXED_MARGIN)
    mixed |= (k0 > 0) & (dr.abs(V_leaf - V_prev) > MIXED_MARGIN)
    mixed &= f > 0.0
    dr.eval(k0, f, V_leaf, mixed)     # one pass over the modes (memory-bound gathers)
    V = mi.Float(V_leaf)
    idx = dr.compress(mixed)
    if dr.width(idx):
        # ⌈k·f⌉ shadow rays per traced query (the §7 sub-ray density over
        # the covered part), at the centres of as many equal pieces of it:
        # (traced query, piece) lanes
        f_t = dr.gather(mi.Float, f, idx)
        count = mi.UInt32(dr.clip(dr.ceil(k * f_t), 1, k))
        lane = dr.arange(mi.UInt32, dr.width(idx) * k)
        keep = dr.compress(lane % k < dr.gather(mi.UInt32, count, lane // k))
        owner, piece = lane // k, lane % k
        owner, piece = dr.gather(mi.UInt32, owner, keep), dr.gather(mi.UInt32, piece, keep)
        q = dr.gather(mi.UInt32, idx, owner)
        row = dr.gather(mi.UInt32, queries.row, q)
        n_q = mi.Float(dr.gather(mi.UInt32, count, owner))
        g = (mi.Float(dr.gather(mi.UInt32, k0, q))
             + (mi.Float(piece) + 0.5) / n_q * dr.gather(mi.Float, f_t, owner))
        gamma = rays.start(row) + g * dr.gather(mi.Float, rays.delta_gamma, row)
        lit = own_ray_visibility(params, cap, queries, q, gamma, LAST_INTERVAL_EPS)
        V_t = dr.zeros(mi.Float, dr.width(idx))
        dr.scatter_reduce(dr.ReduceOp.Add, V_t, dr.select(lit, 1.0 / n_q, 0.0), owner)
        dr.scatter(V, V_t, idx)
    dr.eval(V)
    return LastInterval(k0, f, V_leaf, V, idx)


def own_ray_visibility(params, cap: CameraCapture, queries: EpipolarQueries, q: mi.UInt32,
                       gamma, eps: float, active=True) -> mi.Bool:
    """Ray-traced V at the point of query ``q``'s own camera ray (its own α,
    not its slice's) where its β meets light-ray angle ``gamma``, kept at
    least ``eps`` × scene extent before the ray's end
    (:func:`~integrators.light_transport.visible_exact`); per lane."""
    sample = dr.gather(mi.UInt32, queries.sample, q)
    t, _ = ray_meeting_t(queries.frame, dr.gather(mi.Float, queries.beta, q), gamma)
    t_near = dr.gather(mi.Float, queries.t_near, q)
    t_end = t_near + dr.gather(mi.Float, cap.d, sample)
    t = dr.clip(t, t_near, dr.maximum(t_end - eps * params.scene_extent, t_near))
    x = (dr.gather(mi.Point3f, cap.o, sample)
         + dr.gather(mi.Vector3f, cap.omega, sample) * (t - t_near))
    wo, dist, _ = sample_light(params, x)
    _, t_in, t_out = segment_box(params, x, wo, dist)
    return visible_exact(params, x, wo, dist, t_in, t_out, active)


def factor_arrays(x, with_n: bool):
    """(flat array, rows ∈ {1, n}, length, channels, N) of an A/B (``with_n``)
    or L tensor (:func:`~integrators.partial_sum_tree.factor_layout`)."""
    rows, length, C, _ = factor_layout(tuple(x.shape), 1 if with_n else 0)
    return mi.Float(x.array), rows, length, C, x.shape[-1] if with_n else 1


def last_interval_correction(queries: EpipolarQueries, A, B, L,
                             last: LastInterval) -> mi.Color3f:
    """``f · (V − V_leaf) · Σ_i B_i(β_q) A_i(k0) L(k0)`` per query (zero where V
    equals V_leaf): added to the sweep's integral, the last interval counts
    the visibility of :func:`last_interval_visibility` instead of its
    leaf's -- the sweep itself is unchanged (Σ_i B_i A_i L is the leaf's
    value before visibility, the ``b[k0]`` of Fig. 6's second query).
    A (n|1, d, [C,] N), B (n|1, r, [C,] N), L None, (n|1, d) or (n|1, d, C)
    as :func:`~integrators.partial_sum_tree.integrate_slices` takes them."""
    out = dr.zeros(mi.Color3f, queries.count)
    idx = last.idx                      # V = V_leaf elsewhere
    if not dr.width(idx):
        return out
    row = dr.gather(mi.UInt32, queries.row, idx)
    slot = dr.gather(mi.UInt32, queries.slot, idx)
    k0 = dr.gather(mi.UInt32, last.k0, idx)
    a, nA, d, CA, N = factor_arrays(A, True)
    b, nB, _, CB, _ = factor_arrays(B, True)
    leaf_a = row * d + k0 if nA > 1 else k0
    leaf_b = slot if nB > 1 else dr.gather(mi.UInt32, queries.col, idx)
    if L is not None:
        l, nL, _, CL, _ = factor_arrays(L, False)
        leaf_l = row * d + k0 if nL > 1 else k0
    weight = (dr.gather(mi.Float, last.f, idx)
              * (dr.gather(mi.Float, last.V, idx) - dr.gather(mi.Float, last.V_leaf, idx)))
    C = max(CA, CB, CL if L is not None else 1)
    per_channel = []
    for c in range(C):
        v = mi.Float(0.0)
        for i in range(N):
            v += (dr.gather(mi.Float, a, (leaf_a * CA + c % CA) * N + i)
                  * dr.gather(mi.Float, b, (leaf_b * CB + c % CB) * N + i))
        if L is not None:
            v *= dr.gather(mi.Float, l, leaf_l * CL + c % CL)
        per_channel.append(weight * v)
    value = (mi.Color3f(per_channel[0], per_channel[0], per_channel[0]) if C == 1
             else mi.Color3f(*per_channel))
    dr.scatter(out, value, idx)
    return out


#: float32 error of the sweep: a query's Σ_γ L K V below this multiple of
#: float32's ε times its row's Σ_γ |L K| is indistinguishable from 0
SWEEP_RESIDUE_EPS = 16 * 2.0 ** -23


def sweep_magnitude(queries: EpipolarQueries, A, B, L, last: "LastInterval"):
    """(M, U) per query: the magnitude M = Σ_{γ<D} Σ_i |A_i L| |B_i| of
    every partial sum the sweep forms for it (the scale of its rounding)
    and the unshadowed sum U = Σ_{γ<D} L Σ_i A_i B_i (the sweep without
    blockers, for :func:`unresolved_samples`), both as the sweep's closed
    form takes the last, partial light ray (cumulative sums lerped at D,
    :mod:`~integrators.partial_sum_tree`; each row's formed in parallel by
    ``dr.block_prefix_sum``).  A (n|1, d, [C,] N), B (n|1, r, [C,] N), L
    None, (n|1, d) or (n|1, d, C); ``last``: each query's last leaf and
    its covered fraction (:func:`last_leaf`, via
    :func:`last_interval_visibility`).

    The Fenwick tree removes a shadowed leaf by subtracting w·A·L from node
    sums that added A·L before; a view ray shadowed all along is left with
    the rounding of those cancellations, up to ~ε·M (a prefix sum to D
    reads nodes that hold leaves before D alone; 1e-9…1e-7 of the row's
    light on the terrain), where the exact sum is 0.  Invisible, but HDR
    metrics on mostly black references amplify it (FLIP 0.39 on terrain,
    0.92 on beam); so do the cancellations of the near-plane and
    last-interval corrections.  :func:`assemble_queries` returns 0 for a
    query whose result is within ``SWEEP_RESIDUE_EPS`` times the magnitude
    of its parts -- below their own rounding error.  (Counted over the
    whole row, the bound flushed lit queries that end early in a row whose
    far light rays carry e^{20} more light: random stress seed 31.)"""
    a, nA, d, CA, N = factor_arrays(A, True)
    b, nB, _, CB, _ = factor_arrays(B, True)
    C = max(CA, CB, 1 if L is None else factor_arrays(L, False)[3])
    n, w = queries.n, d + 1
    # lanes (s, c, i, g), g ∈ [0, d] innermost: one block of d + 1 per (row, channel, term)
    j = dr.arange(mi.UInt32, n * C * N * w)
    g, i, c, s = j % w, (j // w) % N, (j // (w * N)) % C, j // (w * N * C)
    gl = dr.minimum(g, d - 1)
    v = dr.gather(mi.Float, a, ((s * d + gl if nA > 1 else gl) * CA + c % CA) * N + i)
    if L is not None:
        l, nL, _, CL, _ = factor_arrays(L, False)
        v *= dr.gather(mi.Float, l, (s * d + gl if nL > 1 else gl) * CL + c % CL)
    v = dr.select(g < d, v, 0.0)
    cum_u = dr.block_prefix_sum(v, w)               # Σ_{γ<g} A_i L
    cum_m = dr.block_prefix_sum(dr.abs(v), w)       # Σ_{γ<g} |A_i L|
    k0, f = last.k0, last.f
    row = queries.slot if nB > 1 else queries.col
    U, M = [], []
    for ch in range(C):
        u, m = mi.Float(0.0), mi.Float(0.0)
        for k in range(N):
            base = ((queries.row * C + ch) * N + k) * w + k0
            bk = dr.gather(mi.Float, b, (row * CB + ch % CB) * N + k)
            u += bk * dr.lerp(dr.gather(mi.Float, cum_u, base),
                              dr.gather(mi.Float, cum_u, base + 1), f)
            m += dr.abs(bk) * dr.lerp(dr.gather(mi.Float, cum_m, base),
                                      dr.gather(mi.Float, cum_m, base + 1), f)
        U.append(u)
        M.append(m)
    if C == 1:
        U, M = U * 3, M * 3
    return mi.Color3f(*M), mi.Color3f(*U)


#: a query whose unshadowed sum is below this fraction of its magnitude
#: is not resolved by the separated kernel (:func:`unresolved_samples`)
UNRESOLVED_RATIO = 1e-2


def unresolved_samples(queries: EpipolarQueries, U: mi.Color3f, M: mi.Color3f) -> mi.UInt32:
    """Camera samples with a query whose sum the tree cannot resolve: its
    unshadowed separated sum U below ``UNRESOLVED_RATIO`` of its magnitude
    M (:func:`sweep_magnitude`) in any channel.  The tree's result is then a
    difference of terms ≥ 100× as large: their float32 rounding and the
    separated kernel's absolute error (both ∝ M) are ≥ 1e-5…1e-3 of the
    query's value, and all of it where L grows along the slice by
    e^{20…30} while the view ray's kernel decays as fast (a thick medium
    seen away from a light whose light-side path shrinks along the slice,
    random stress seed 31: 28× the exact sum).  Such samples are ray-marched
    instead (:func:`remarch_samples`)."""
    if not queries.count:
        return dr.zeros(mi.UInt32, 0)
    bad = mi.Bool(False)
    for c in range(3):
        bad |= (M[c] > 0.0) & (dr.abs(U[c]) < UNRESOLVED_RATIO * M[c])
    mask = dr.zeros(mi.Bool, queries.n_samples)
    dr.scatter(mask, True, queries.sample, active=bad)
    return dr.compress(mask)


def cell_average(x):
    """φ(x) = (1 − e^{-x}) / x (φ(0) = 1), stable for every x ≥ 0: the mean
    of e^{-c(γ − γ_g)} over a light-ray interval [γ_g, γ_g + Δγ], x = c·Δγ."""
    small = x < 1e-2
    xs = dr.select(small, 1.0, x)
    series = 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0)))
    return dr.select(small, series, (1.0 - dr.exp(-xs)) / xs)


def directional_query_terms(params, cap: CameraCapture, queries: EpipolarQueries,
                            rays: LightRays, V_near=1.0) -> QueryTerms:
    """Per-query factors (module doc); ``V_near``: visibility of the segment
    between pinhole and near plane (:func:`first_leaf_visibility`)."""
    sigma_t = color(params.medium.sigma_t)
    omega = dr.gather(mi.Vector3f, cap.omega, queries.sample)
    o = dr.gather(mi.Point3f, cap.o, queries.sample)
    wo, _, E = sample_light(params, o)
    f_p = phase_eval(params, omega, wo)
    h_ref = dr.gather(mi.Float, rays.h_ref, queries.row)
    # e^{-σt h_ref}: L's reference (light_side_factor); e^{σt t_near}: the
    # camera-side transmittance counted from the ray origin, not the pinhole
    radiance = color(params.medium.sigma_s) * f_p * E * dr.exp(sigma_t * (queries.t_near - h_ref))
    dg = dr.gather(mi.Float, rays.delta_gamma, queries.row)
    view = dg / dr.sin(queries.beta) * cell_average(sigma_t * dr.tan(0.5 * queries.beta) * dg)
    h0, _ = axial_exit(params, mi.Point3f(point(params.camera.origin)),
                        vector(queries.frame.axis))
    one_minus_cos = 1.0 - dr.dot(omega, wo)
    near = V_near * dr.exp(-sigma_t * (h0 - h_ref)) * segment_weight(sigma_t * one_minus_cos,
                                                                       0.0, queries.t_near)
    return QueryTerms(radiance, view, near)


def assemble_queries(terms: QueryTerms, integral: mi.Color3f) -> mi.Color3f:
    """L_scat per query from the rectified integral Σ_γ L K V cover (plus
    ``terms.last``, the last-interval correction)."""
    bracket = terms.view * (integral + terms.last) - terms.near
    if terms.magnitude is not None:
        # below the rounding error of its own parts: a fully shadowed ray's
        # float32 residue (sweep_magnitude), exactly 0
        scale = terms.view * (terms.magnitude + dr.abs(terms.last)) + dr.abs(terms.near)
        bracket = dr.select(dr.abs(bracket) <= SWEEP_RESIDUE_EPS * scale, 0.0, bracket)
    value = terms.radiance * bracket
    # e^{-σt h_ref} ≤ e^{c} (row_reference), but e^{σt t_near} overflows
    # when the near clip plane lies more than 88 mean free paths from the
    # eye; the sum it multiplies has underflowed to 0 by then, and the
    # query is returned as 0, not NaN (results/stability, scale 1e4).
    return dr.select(dr.isfinite(terms.radiance), dr.maximum(value, 0.0), 0.0)


def gather_queries(queries: EpipolarQueries, result: mi.TensorXf) -> mi.Color3f:
    """Each query's entry of an (n, r) or (n, r, C) result as a Color3f."""
    flat = mi.Float(result.array)
    C = result.shape[2] if len(result.shape) == 3 else 1
    slot = queries.slot
    if C == 1:
        v = dr.gather(mi.Float, flat, slot)
        return mi.Color3f(v, v, v)
    return mi.Color3f(*(dr.gather(mi.Float, flat, slot * C + c) for c in range(C)))


#: the ring samples within a pixel of a point/spot light take this many
#: times ``ring_steps``
PEAK_STEP_FACTOR = 8


#: default bisections of the ring's and re-marched samples' shadow and cone
#: edges (``ring_bisections``; :func:`brute_force`)
RING_BISECTIONS = 4


def brute_force(params, cap: CameraCapture, steps: int, bisections: int = 0) -> mi.Color3f:
    """L_scat of every sample of ``cap`` by the exact marcher the ring and
    the re-marched samples use: ``steps`` segments (the light's spacing)
    with ray-traced visibility, their shadow and cone edges located by
    ``bisections`` bisections (:func:`~integrators.marching.march_bisected`;
    0: the midpoint rule of :func:`~integrators.marching.march`).  The
    re-marched samples sit on shaft edges by construction, where the
    midpoint rule's error is of one segment over the lit length."""
    spacing = lit_spacing(params)
    if bisections:
        return march_bisected(params, cap, steps, bisections, spacing=spacing)
    return march(params, cap, steps, shadow_map=None, spacing=spacing)


def march_ring(params, cap: CameraCapture, queries: EpipolarQueries, steps: int,
               bisections: int = 0) -> mi.Color3f:
    """Brute-force L_scat of the ring samples (§6):
    :func:`peak_marched`."""
    return peak_marched(params, cap.subset(queries.ring_sample), queries.frame, steps,
                        bisections)


def peak_marched(params, cap: CameraCapture, frame, steps: int,
                 bisections: int = 0) -> mi.Color3f:
    """L_scat of every sample of ``cap`` by :func:`brute_force`.  For a
    point or spot light, the samples whose view ray passes within one
    pixel's angle of the light (a light on or next to a pixel centre: the
    1/r² peak is steep there, and such a pixel can hold much of the image's
    energy) take ``PEAK_STEP_FACTOR`` × the steps; they are a handful, the
    rest keep ``steps``.  ``frame``: the epipolar frame of the light."""
    if params.light.kind == "directional" or not cap.count:
        return brute_force(params, cap, steps, bisections)
    cam = params.camera
    pixel = 2.0 * max(float(np.linalg.norm(cam.x_axis)) / cam.width,
                      float(np.linalg.norm(cam.y_axis)) / cam.height)
    beta = direction_to_alpha_beta(frame, cap.omega)[1]
    # the pixel's angle opaque: it moves in the last bits with the camera
    peak = dr.minimum(beta, math.pi - beta) < scalar(pixel)
    # one march, the steps per ray (marching.step_count)
    lane_steps = dr.select(peak, scalar_u32(PEAK_STEP_FACTOR * steps), scalar_u32(steps))
    return brute_force(params, cap, lane_steps, bisections)


def disagreeing_samples(queries: EpipolarQueries, values, tolerance: float) -> mi.UInt32:
    """Camera samples whose two neighbouring slices disagree: the samples
    shared between two slices (slice interpolation) whose queries'
    ``values`` (unweighted L_scat per query) differ by more than
    ``tolerance`` times the larger of the two (channel sums) and by more
    than ``tolerance``·1e-2 of the largest query value of the frame.  A
    shaft edge or a narrow spot beam running along the slices lies between
    such a pair, so the blend of the two is no estimate of either side;
    :func:`remarch_samples` marches them instead.  ``tolerance >= 1``:
    none."""
    if not queries.count or queries.weight is None or tolerance >= 1.0:
        return dr.zeros(mi.UInt32, 0)
    return disagreeing(queries.sample, queries.n_samples, values, tolerance)


def disagreeing(sample: mi.UInt32, n: int, values, tolerance: float, peak=None) -> mi.UInt32:
    """The test of :func:`disagreeing_samples` on plain arrays: of the ``n``
    samples, those given exactly two of the answers ``values`` (answer i
    belongs to sample ``sample[i]``) that differ by more than ``tolerance``
    times the larger (channel sums) and by more than ``tolerance``·1e-2 of
    the largest answer, or of ``peak`` where that is larger (a frame-wide
    largest channel sum, for answers that are part of a frame)."""
    y = values[0] + values[1] + values[2]
    hi = dr.full(mi.Float, -dr.inf, n)
    lo = dr.full(mi.Float, dr.inf, n)
    shares = dr.zeros(mi.UInt32, n)
    dr.scatter_reduce(dr.ReduceOp.Max, hi, y, sample)
    dr.scatter_reduce(dr.ReduceOp.Min, lo, y, sample)
    dr.scatter_reduce(dr.ReduceOp.Add, shares, mi.UInt32(1), sample)
    peak = dr.max(y) if peak is None else dr.maximum(dr.max(y), peak)
    spread = hi - lo
    return dr.compress((shares == 2) & (spread > tolerance * hi)
                       & (spread > tolerance * 1e-2 * peak))


def union_samples(n: int, *parts: mi.UInt32) -> mi.UInt32:
    """The sorted union of sample index lists ``parts`` (indices < ``n``)."""
    parts = [p for p in parts if dr.width(p)]
    if len(parts) <= 1:
        return parts[0] if parts else dr.zeros(mi.UInt32, 0)
    mask = dr.zeros(mi.Bool, n)
    for p in parts:
        dr.scatter(mask, True, p)
    return dr.compress(mask)


def remarch_samples(params, cap: CameraCapture, queries: EpipolarQueries, values,
                    samples: mi.UInt32, steps: int, bisections: int = 0):
    """``values`` with the queries of camera ``samples`` replaced by the
    brute-force L_scat of their ray (the ring's marcher,
    :func:`brute_force`): both queries of such a sample then carry it, so
    their weighted sum is the marched value."""
    if not dr.width(samples):
        return values
    marched = brute_force(params, cap.subset(samples), steps, bisections)
    fixed = dr.zeros(mi.Bool, queries.n_samples)
    dr.scatter(fixed, True, samples)
    per_sample = dr.zeros(mi.Color3f, queries.n_samples)
    dr.scatter(per_sample, marched, samples)
    mine = dr.gather(mi.Bool, fixed, queries.sample)
    return dr.select(mine, dr.gather(mi.Color3f, per_sample, queries.sample), values)


def to_samples(queries: EpipolarQueries, parts) -> mi.Color3f:
    """Per camera sample: the ``(sample indices, values)`` pairs added
    into zeros (samples in no part scatter nothing; a sample shared by two
    slices sums its weighted queries)."""
    out = dr.zeros(mi.Color3f, queries.n_samples)
    for idx, values in parts:
        if dr.width(idx):
            dr.scatter_reduce(dr.ReduceOp.Add, out, values, idx)
    return out
