"""Several reference rays per row: transmittance weights that stay right in
thick media (``fourier_filter``, beyond Klehm et al. 2014 §3.2).

Klehm's §3.2 weights every texel of a row by the transmittance kernel of
*one* reference ray, ``K(γ, β_ref)``, and takes the weighted average
visibility V̄ for every view ray of the row.  The weighting is right only
where the query's own kernel ``K(γ, β)`` is proportional to it.  For a
directional light ``K = e^{-c γ}``, ``c = σt tan(β/2)``: two view rays of
one row differ by ``e^{-(c − c_ref) γ}``, which across the row's texels
(``γ ∈ [0, ℓ]``) is ``e^{-Δc ℓ}`` -- order one as soon as the medium is a
few mean free paths thick, and then V̄ is the visibility of the wrong
texels (energy lost or gained by whole factors).

The remedy here: ``K`` reference rays per row at angles β_k spread over the
row's β range, one filter each, and every query interpolates linearly
between the two nearest ones: its weights are

    w(γ) ≈ (1 − f) L K(γ, β_k) + f L K(γ, β_{k+1}),

non-negative (a convex combination of two reference rays' weights, so each
filter is a proper weighted average that the series and its clamp handle
as Klehm's), and the query's weighted sum is the same mix of the two
filters' weighted sums.  The rays are equally spaced in the decay
coordinate ``s(β) = log(1 + σt tan(β/2) ℓ)``: for ``c ℓ ≪ 1`` it is the
optical depth ``c ℓ`` itself (the kernel is nearly flat and one interval
serves), for ``c ℓ ≫ 1`` it is ``log c`` (a fixed *ratio* of decay rates per
interval, which bounds the relative error of the interpolated weights
wherever they matter, within about ``1/c`` of the eye).  The unshadowed
sum U(β) stays the query's own exact one; only the weighting of its
visibility is interpolated.

Point and spot lights (Baran §9): the same coordinate with ``tan(β/2)``
(the decay rate next to the eye, :func:`~integrators.fourier.rectified_map.reference_angle`)
and ``ℓ`` the longest camera path; the interpolated kernel includes the
phase function at the reference rays' scattering angles.

NumPy oracle: :func:`interpolated_kernel_reference`.
"""
from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import Divisor, opaque_scalar, scalar, scalar_u32
from ..epipolar.light_models import light_model
from ..epipolar.queries import frame_memo
from .rectified_map import query_beta_range


#: spacing of the reference rays in s = log(1 + σt tan(β/2) ℓ)
SPACING = 0.3
#: most reference rays per row of the automatic count
MAX_REFERENCE_RAYS = 16


def decay_coordinate(beta, sigma_t: float, length: float):
    """s(β) = log(1 + σt tan(β/2) ℓ) (module doc), Dr.Jit or NumPy; in
    Dr.Jit σt ℓ is a kernel parameter (opaque), not a literal."""
    if isinstance(beta, np.ndarray) or np.isscalar(beta):
        return np.log1p(sigma_t * length * np.tan(0.5 * np.asarray(beta, np.float64)))
    return dr.log(1.0 + scalar(sigma_t * length) * dr.tan(0.5 * beta))


def decay_angle(s, sigma_t: float, length: float):
    """β(s), the inverse of :func:`decay_coordinate`; 1/(σt ℓ) is a kernel
    parameter (opaque), rounded as Dr.Jit rounds a literal divisor (the
    float32 reciprocal of the float32 value)."""
    rate = np.float32(sigma_t * length)
    return 2.0 * dr.atan((dr.exp(s) - 1.0) * scalar(np.float32(1.0) / rate))


def auto_reference_rays(span, spacing: float = SPACING, max_rays: int = MAX_REFERENCE_RAYS):
    """Reference rays of a row whose queries span ``span`` in s: one per
    ``spacing`` plus the end, from 1 (Klehm's single ray) to ``max_rays``
    (NumPy or Dr.Jit, per row)."""
    if isinstance(span, (int, float, np.floating)):
        return int(min(max_rays, max(1, math.ceil(span / spacing) + 1))) if span > 0 else 1
    count = dr.ceil(span / spacing) + 1.0
    return mi.UInt32(dr.select(span > 0.0, dr.clip(count, 1.0, float(max_rays)), 1.0))


@dataclass(eq=False)
class ReferenceRays:
    """Up to ``count`` reference rays per row (row r has ``counts[r]``) and
    every query's place among its row's."""
    count: int            # the most of any row
    counts: mi.UInt32     # (n,) reference rays of every row
    beta: mi.Float        # (count·n) β_k of every row r at k·n + r (k < counts[r])
    node: mi.UInt32       # (Q,) k: the query's lower reference ray
    frac: mi.Float        # (Q,) f ∈ [0, 1]: its position toward ray k + 1
    #: β_k at lanes j = k·n + r (``beta`` made where it is read), or None
    beta_at: object = None


@dataclass(eq=False)
class ReferenceRows:
    """The rows' arrays of :func:`reference_rays` (n,): the reference rays
    ``counts``, the intervals ``last`` between them (≥ 1), the row's s
    range from ``s_lo`` over ``span`` and its smallest β ``lo``; the
    queries' s ``s_q`` (Q,); whether the kernel ``decays`` (σt ℓ > 0)."""
    decays: bool
    counts: mi.UInt32
    last: mi.Float
    s_lo: mi.Float
    span: mi.Float
    lo: mi.Float
    s_q: mi.Float

    def arrays(self) -> tuple:
        """(counts, last, s_lo, span, lo): what a kernel over the rows makes."""
        return self.counts, self.last, self.s_lo, self.span, self.lo


def reference_rows(queries, sigma_t: float, length: float, count: int = 0,
                   spacing: float = SPACING) -> ReferenceRows:
    """The rows' arrays of :func:`reference_rays` (same arguments), made
    once per frame's queries and arguments and left unevaluated: a caller
    evaluates them with a kernel over the rows of its own (the rectified
    map's filtered rows' mask, :func:`~integrators.fourier.rectified_map.rectified_shadow_map`'s
    ``rows_with``), else :func:`reference_rays` with its read of the most
    rays."""
    def make():
        lo, hi = query_beta_range(queries)
        rate = float(sigma_t) * float(length)
        decays = rate > 1e-6
        if decays:
            s_lo, s_hi = (decay_coordinate(b, sigma_t, length) for b in (lo, hi))
            s_q = decay_coordinate(queries.beta, sigma_t, length)
        else:
            s_lo, s_hi, s_q = lo, hi, queries.beta
        span = dr.select(dr.isfinite(s_hi - s_lo), s_hi - s_lo, 0.0)
        if count == 0:
            counts = auto_reference_rays(span if decays else dr.zeros(mi.Float, dr.width(span)),
                                         spacing)
        else:
            counts = dr.full(mi.UInt32, count, dr.width(span))
        last = mi.Float(dr.maximum(counts, 2) - 1)          # intervals of a row (≥ 1)
        return ReferenceRows(decays, counts, last, s_lo, span, lo, s_q)
    return frame_memo(queries, ("reference_rows", float(sigma_t), float(length), int(count),
                                float(spacing)), make)


def reference_rays(queries, sigma_t: float, length: float, count: int = 0,
                   spacing: float = SPACING) -> ReferenceRays:
    """Reference rays equally spaced in s over each row's β range (module
    doc); ``count`` = 0: :func:`auto_reference_rays` per row, else ``count``
    in every row (1: the bisectrix, Klehm's).  σt ℓ ≈ 0 (no decay): the
    rays are equally spaced in β.  σt, ℓ and ``k`` enter the kernels as
    parameters; the most rays of any row (a read-back) is the Python loop
    count of the filters."""
    rows = reference_rows(queries, sigma_t, length, count, spacing)
    counts, last, s_lo, span, lo = rows.arrays()
    decays, s_q = rows.decays, rows.s_q
    dr.schedule(counts, last, s_lo, span, lo)           # with the read of the most rays
    K = int(dr.max(counts)[0]) if dr.width(counts) else 1
    n = dr.width(counts)
    per = Divisor(n)

    def beta_at(j):
        """β_k of every row, ray-major: (k, row) at lane j = k·n + row."""
        k, r = per.divmod(j)
        at = (lambda x: dr.gather(type(x), x, r))
        s_k = dr.select(at(counts) > 1, at(s_lo) + at(span) * (mi.Float(k) / at(last)),
                        at(s_lo) + 0.5 * at(span))
        b_k = decay_angle(s_k, sigma_t, length) if decays else s_k
        return dr.select(at(span) > 0.0, b_k, at(lo))
    span_q = dr.gather(mi.Float, span, queries.row)
    last_q = dr.gather(mi.Float, last, queries.row)
    u = dr.select(span_q > 0.0,
                  (s_q - dr.gather(mi.Float, s_lo, queries.row)) / span_q * last_q, 0.0)
    u = dr.clip(u, 0.0, last_q)
    node = dr.minimum(mi.UInt32(u), mi.UInt32(last_q) - 1)
    frac = dr.select(dr.gather(mi.UInt32, counts, queries.row) > 1, u - mi.Float(node), 0.0)
    # β_k, node and frac made where they are read (the kernels, the
    # queries' sums) from the rows' evaluated arrays
    return ReferenceRays(K, counts, beta_at(dr.arange(mi.UInt32, K * n)), node, frac, beta_at)


def row_kernel(params, queries, rays, sigma_t: float, beta_ref, count: int = 1) -> mi.Float:
    """K(γ, β_ref) per light ray (n·d) for one reference angle per row
    ``beta_ref`` (n,), the light side included (Klehm §3.2, Eq. 11);
    ``count`` angles per row (``beta_ref`` (count·n), ray-major as
    :attr:`ReferenceRays.beta`, or the :class:`ReferenceRays`, whose β_k
    are then made where read): their kernels (count·n·d) one after
    another, in one kernel.
    Directional: e^{-σt γ_g tan(β_ref/2)} at the light ray's start γ_g
    (equal light rays: the factor of the interval's mean is common to the
    row).  Projective texels: the integral of that kernel over the texel,
    Eq. 12 (:func:`~integrators.fourier.rectified_map.texel_integral`).
    Point/spot: the mean over the light ray's interval of
    e^{-σt (t + r − L)} f_p(β_ref + γ)
    (:func:`~integrators.epipolar.kernel.local.local_kernel`): the phase
    function of the reference ray at each light ray is the "angular
    dependency" of §3.2, next to the light's own (intensity, fall-off,
    texture) in L."""
    s, gamma = rays.positions(0.0)
    size = dr.width(gamma)
    kernel = (rays.own_kernel(sigma_t)
              or light_model(params).ray_kernel(params, queries, rays, sigma_t))
    if count == 1:
        if isinstance(beta_ref, ReferenceRays):
            beta_ref = beta_ref.beta
        return kernel(dr.arange(mi.UInt32, size), dr.tan(0.5 * dr.gather(mi.Float, beta_ref, s)))
    k, t = Divisor(size).divmod(dr.arange(mi.UInt32, count * size))
    # the light ray's row at every ray's lanes, as ``positions`` numbers it
    refs = beta_ref if isinstance(beta_ref, ReferenceRays) else None
    n = dr.width(refs.counts) if refs is not None else dr.width(beta_ref) // count
    row = k * scalar_u32(n) + Divisor(rays.d).div(t)
    return kernel(t, dr.tan(0.5 * (refs.beta_at(row) if refs is not None
                                   else dr.gather(mi.Float, beta_ref, row))))


def interpolated_sum(refs: ReferenceRays, batches: list, layer_sums, evaluate=None,
                     channels: int = 1):
    """Per query Σ_k share_k X_k for every sum X of the tuple (S_k, P_k, ...)
    of its two nearest reference rays k (the others' shares are 0): the
    shadowed and the unshadowed weighted sums of ray k and any further
    sums of its weights.  ``batches``: (first ray, rays) of the rays made
    together; ``layer_sums(first, rays)`` makes a batch's filters and
    returns ``sums(k, active)``, the tuple X_k of each query's ray ``k``
    (where ``active``).  One kernel per batch whatever the number of rays;
    the sums added in the order of k (bit for bit one ray at a time).
    ``channels`` > 1: the rays of that many colour channels laid one after
    another (channel c's ray k is ``c·refs.count + k``): a list of the
    tuples, one per channel, each bit for bit its channel's alone.
    The sums of every batch but the last are evaluated (``evaluate``: a
    context manager whose yielded list is evaluated at its exit, a timed
    stage; ``None``: plainly); the last batch's are left to the caller's
    kernel."""
    outs = [None] * channels
    for i, (first, count) in enumerate(batches):
        sums_of = layer_sums(first, count)
        lo, hi = opaque_scalar(mi.UInt32, first), opaque_scalar(mi.UInt32, first + count)
        for c in range(channels):
            base = mi.UInt32(0) if c == 0 else scalar_u32(c * refs.count)
            out = outs[c]
            for k, share in ((refs.node, 1.0 - refs.frac), (refs.node + 1, refs.frac)):
                k = k if c == 0 else k + base
                use = (share > 0.0) & (k >= lo) & (k < hi)
                sums = sums_of(k, use)
                if out is None:
                    out = [dr.zeros(mi.Float, dr.width(refs.frac)) for _ in sums]
                out = [x + dr.select(use, share * x_k, 0.0) for x, x_k in zip(out, sums)]
            outs[c] = out
        if i + 1 < len(batches):
            every = [x for out in outs for x in out]
            with (evaluate() if evaluate is not None else contextlib.nullcontext([])) as keep:
                keep.extend(every)
            dr.eval(every)
    return tuple(outs[0]) if channels == 1 else [tuple(out) for out in outs]


def interpolated_kernel_reference(gamma, beta, beta_lo, beta_hi, sigma_t: float,
                                  length: float, count: int) -> np.ndarray:
    """NumPy oracle (float64) of the weights one query of a directional
    row sees: the mix of the two nearest of ``count`` reference rays'
    kernels e^{-σt γ tan(β_k/2)}, equally spaced in s over [β_lo, β_hi].
    Returns the weights at ``gamma``."""
    s_lo, s_hi = (decay_coordinate(b, sigma_t, length) for b in (beta_lo, beta_hi))
    if count == 1:
        return np.exp(-sigma_t * np.asarray(gamma) * np.tan(0.25 * (beta_lo + beta_hi)))
    s_k = np.linspace(s_lo, s_hi, count)
    b_k = 2.0 * np.arctan(np.expm1(s_k) / (sigma_t * length))
    u = np.clip((decay_coordinate(beta, sigma_t, length) - s_lo) / (s_hi - s_lo) * (count - 1),
                0.0, count - 1)
    k = min(int(u), count - 2)
    f = u - k
    K = [np.exp(-sigma_t * np.asarray(gamma, np.float64) * np.tan(0.5 * b)) for b in b_k[k:k + 2]]
    return (1.0 - f) * K[0] + f * K[1]
