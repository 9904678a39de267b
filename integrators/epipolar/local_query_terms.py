"""Per-query terms of a point or spot light: the near segment, the
asymptote band where the kernel is steep, and the assembly of the local
light's query terms (Baran et al. 2010 §9; DESIGN §1).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.light_transport import (color, phase_eval, point, sample_light, scalar, segment_box,
                                    segment_weight)
from .blockers import mode_visibility
from .kernel.local import Angles, LocalKernel, interval_bounds, lit_domain, query_x, query_x_max
from .last_interval import factor_arrays
from .light_rays.local import LocalLightRays
from .queries import EpipolarQueries, frame_memo
from .query_terms import QueryTerms


# --------------------------------------------------------------------------
# Per-query terms
# --------------------------------------------------------------------------

#: Gauss-Legendre nodes and weights on [0, 1] of :func:`near_segment`
#: :func:`near_segment` takes its nodes where t_near exceeds this fraction of L
NEAR_RATIO = 0.05
NEAR_NODES = tuple((0.5 * (1.0 + x), 0.5 * w) for x, w in zip(*np.polynomial.legendre.leggauss(4)))


def near_segment(params, cap, queries: EpipolarQueries) -> mi.Color3f:
    """∫ over [0, t_near] (pinhole -> camera ray origin) of the unshadowed
    integrand σs f_p I/r² e^{-σt τ} e^{-σt t} dt, by Gauss-Legendre nodes
    in the angle θ the segment subtends at the light (equiangular, Kulla &
    Fajardo 2012: dt/r² = dθ/b, b the ray's distance from the light), so
    that 1/r² is integrated exactly: with the light a few near-plane
    distances from the eye, 1/r² changes by ~2× along the segment and one
    midpoint sample missed ~2 % of it (random stress seed 79: +0.5 % on the
    image).  Where t_near ≤ NEAR_RATIO·L (the suite), or the ray passes
    through the light (b ≈ 0), one midpoint sample."""
    sigma_t = color(params.medium.sigma_t)
    sigma_s = color(params.medium.sigma_s)
    omega = dr.gather(mi.Vector3f, cap.omega, queries.sample)
    o = mi.Point3f(point(params.camera.origin))
    q = mi.Vector3f(point(params.light.position)) - mi.Vector3f(o) \
        if params.light.position is not None else None
    t_near = queries.t_near

    def light_term(t):
        x = o + omega * t
        wo, dist, E = sample_light(params, x)
        tau, _, _ = segment_box(params, x, wo, dist)
        return sigma_s * phase_eval(params, omega, wo, x) * E * dr.exp(-sigma_t * tau), dist

    mid, _ = light_term(0.5 * t_near)
    value = mid * segment_weight(sigma_t, 0.0, t_near)
    # the nodes only where the segment is not short against the light's
    # distance (there the midpoint's error is below ~1e-4 of the segment)
    t0 = dr.dot(q, omega)
    b = dr.norm(q - omega * t0)
    idx = dr.compress(near_nodes(params, cap, queries))
    if not dr.width(idx):
        return value
    omega = dr.gather(mi.Vector3f, omega, idx)
    t0, b, tn = dr.gather(mi.Float, t0, idx), dr.gather(mi.Float, b, idx), dr.gather(mi.Float, t_near, idx)
    th_a, th_b = dr.atan2(-t0, b), dr.atan2(tn - t0, b)
    total = dr.zeros(mi.Color3f, dr.width(idx))
    for u, w in NEAR_NODES:
        t = t0 + b * dr.tan(th_a + (th_b - th_a) * u)
        term, dist = light_term(t)
        total += term * dr.square(dist) * dr.exp(-sigma_t * t) * w
    dr.scatter(value, total * ((th_b - th_a) / b), idx)
    return value


def near_nodes(params, cap, queries: EpipolarQueries) -> mi.Bool:
    """(Q,) the queries whose near segment :func:`near_segment` integrates
    with its nodes (t_near > NEAR_RATIO·L, the ray not through the light),
    made once per frame's queries and scheduled: evaluated by the next
    kernel over the queries (a method asks for it before one, e.g. its
    coverage's), or where :func:`near_segment` compresses it."""
    def make():
        omega = dr.gather(mi.Vector3f, cap.omega, queries.sample)
        o = mi.Point3f(point(params.camera.origin))
        q = mi.Vector3f(point(params.light.position)) - mi.Vector3f(o)
        t0 = dr.dot(q, omega)
        b = dr.norm(q - omega * t0)
        mask = (queries.t_near > NEAR_RATIO * dr.norm(q)) & (b > 1e-4 * dr.norm(q))
        dr.schedule(mask)
        return mask
    # keyed by the frame's parameters alone (its capture is theirs): a kept
    # frame state holds no capture through it
    return frame_memo(queries, ("near_nodes", params), make)


def reaches_asymptote_band(params, queries: EpipolarQueries, rays: LocalLightRays,
                           band_cells: int) -> bool:
    """Whether any query's view ray reaches the asymptote band of
    ``band_cells`` lattice cells before its limit angle π − β (with a
    margin of one cell on each side: γ_end ≥ π − β − (band_cells + 2)·Δγ),
    i.e. whether the banded kernel and :func:`asymptote_band_correction`
    can change any query's sum.  Far from the light every view ray ends
    well before its limit angle, and the plain kernel is used.  The test
    is evaluated with the other reads of the frame's queries that the
    separated kernel makes (its :func:`~integrators.epipolar.kernel.local.query_x`
    and :func:`~integrators.epipolar.kernel.local.lit_domain`): one kernel."""
    if not band_cells or not queries.count:
        return False
    query_x(queries.whole_frame)
    delta = dr.gather(mi.Float, rays.delta_gamma, mi.UInt32(0))
    near = (queries.gamma_end >= (math.pi - queries.beta) - (band_cells + 2) * delta) \
        & (queries.beta < math.pi)
    dr.schedule(near)
    lit_domain(params, queries, rays)
    return bool(dr.any(near)[0])


def band_queries(queries: EpipolarQueries, rays: LocalLightRays, last, band_cells: int):
    """(g_a, k0, reaches) per query: the first cell of its asymptote band
    (row-local, at least k0 − band_cells − 1), its last covered cell
    ``last.k0`` (both as floats) and whether it reaches the band
    (:func:`asymptote_band_correction`), made once per frame's queries and
    ``last`` and scheduled, with the frame's x (read by the kernel's
    domain): evaluated by the next kernel over the queries (a method asks
    for them before one, e.g. its traced runs' mask), or where
    :func:`asymptote_band_correction` compresses the mask."""
    def make():
        delta32 = np.float32(rays.delta_gamma[0])
        m_s = mi.Float(dr.gather(mi.UInt32, rays.offset, queries.row))
        k0 = mi.Float(last.k0)
        # ÷Δγ as Dr.Jit compiles a division by a literal: × its float32 reciprocal
        j_a = dr.floor((math.pi - queries.beta) * scalar(np.float32(1.0) / delta32) - band_cells)
        g_a = dr.maximum(dr.maximum(j_a - m_s, k0 - (band_cells + 1)), 0.0)
        reaches = (g_a <= k0) & (queries.beta < math.pi)
        dr.schedule(g_a, k0, last.k0, reaches)
        query_x(queries.whole_frame)
        return g_a, k0, reaches
    return frame_memo(queries, ("band_queries", rays, last, band_cells), make)


def asymptote_band_correction(params, queries: EpipolarQueries, rays: LocalLightRays, A, B, L,
                               modes, last, band_cells: int) -> mi.Color3f:
    """Per query, the change of the sweep's sum when its light-ray cells in
    the asymptote band (:class:`~integrators.epipolar.kernel.local.LocalSeparation` with
    ``band_cells``: the
    lattice cells from ⌊(π − β)/Δγ⌋ − band_cells on) take the exact mean
    of K over their covered part instead of the banded kernel's Σ_i A_i B_i
    (added to ``terms.last``, integral units: Σ_g L_g V_g (K̄_g − K̃_g) cover_g).

    At most band_cells + 2 cells per query; only queries whose view ray
    reaches the band (farther than ~L sin β/(band_cells·Δγ) from the eye).
    Visibility: the cells' depth modes, the last cell's that of
    :func:`~integrators.epipolar.last_interval.last_interval_visibility` (``last``;
    :func:`~integrators.epipolar.last_interval.last_interval_correction` has already
    turned the sweep's V_leaf into it); ``modes`` None: every cell before
    the last is lit (``fourier_filter``'s unshadowed sum U); the exact mean
    is :meth:`~integrators.epipolar.kernel.local.LocalKernel.cell_mean` over the covered part."""
    out = dr.zeros(mi.Color3f, queries.count)
    if not band_cells or not queries.count:
        return out
    delta = scalar(np.float32(rays.delta_gamma[0]))
    g_a, k0, reaches = band_queries(queries, rays, last, band_cells)
    idx = dr.compress(reaches)
    if not dr.width(idx):
        return out
    per = band_cells + 2
    lane = dr.arange(mi.UInt32, dr.width(idx) * per)
    owner, c = lane // per, lane % per
    q = dr.gather(mi.UInt32, idx, owner)
    g = dr.gather(mi.Float, g_a, q) + mi.Float(c)
    dr.schedule(q, g)               # read below: with the compression's mask
    keep = dr.compress(g <= dr.gather(mi.Float, k0, q))
    q, g = dr.gather(mi.UInt32, q, keep), mi.UInt32(dr.gather(mi.Float, g, keep))
    row = dr.gather(mi.UInt32, queries.row, q)
    is_last = g == dr.gather(mi.UInt32, last.k0, q)
    cover = dr.select(is_last, dr.gather(mi.Float, last.f, q), 1.0)
    V_cells = (1.0 if modes is None else
               mode_visibility(modes, row, dr.gather(mi.UInt32, queries.col, q), g))
    V = dr.select(is_last, dr.gather(mi.Float, last.V, q), V_cells)
    beta = dr.gather(mi.Float, queries.beta, q)
    b = Angles.of(beta)
    gamma = rays.start(row) + mi.Float(g) * delta
    width = cover * delta
    bounds = interval_bounds(gamma, width)
    a, nA, d, CA, N = factor_arrays(A, True)
    bb, nB, _, CB, _ = factor_arrays(B, True)
    leaf = row * d + g
    slot = queries.slot_of(q)
    if L is not None:
        l, nL, _, CL, _ = factor_arrays(L, False)
    sigma_t = np.asarray(params.medium.sigma_t, np.float64)
    dist, x_max = float(queries.frame.light_distance), query_x_max(queries)
    kernels = [LocalKernel.of(params, float(sigma_t[ch]), dist, x_max) for ch in range(CA)]
    C = max(CA, CB, CL if L is not None else 1)
    exact = [cover * kern.cell_mean(b, bounds, width) for kern in kernels]
    per_channel = []
    for ch in range(C):
        sweep = mi.Float(0.0)
        for i in range(N):
            sweep += (dr.gather(mi.Float, a, (leaf * CA + ch % CA) * N + i)
                      * dr.gather(mi.Float, bb, (slot * CB + ch % CB) * N + i))
        v = V * (exact[ch % CA] - cover * sweep)
        if L is not None:
            v *= dr.gather(mi.Float, l, leaf * CL + ch % CL)
        acc = dr.zeros(mi.Float, queries.count)
        dr.scatter_reduce(dr.ReduceOp.Add, acc, v, q)
        per_channel.append(acc)
    return (mi.Color3f(per_channel[0], per_channel[0], per_channel[0]) if C == 1
            else mi.Color3f(*per_channel))


def local_query_terms(params, cap, queries: EpipolarQueries, rays: LocalLightRays, colour,
                      V_near=1.0) -> QueryTerms:
    """Per-query factors (:mod:`integrators.epipolar`, "Per query") for
    :func:`~integrators.epipolar.query_terms.assemble_queries`:
    ``radiance = e^{σt t_near}``, ``view = σs·colour·Δγ / (L sin β)``,
    ``near = V_near ·`` :func:`near_segment`."""
    sigma_t = color(params.medium.sigma_t)
    L = scalar(queries.frame.light_distance)
    dg = dr.gather(mi.Float, rays.delta_gamma, queries.row)
    view = color(params.medium.sigma_s) * colour * (dg / (L * dr.sin(queries.beta)))
    near = V_near * near_segment(params, cap, queries)
    return QueryTerms(dr.exp(sigma_t * queries.t_near), view, near)
