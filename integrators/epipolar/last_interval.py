"""The light-ray interval in which a view ray ends: its exact visibility
where the interval's depth modes are mixed, the sweep's correction for it,
and the samples the sweep cannot resolve (DESIGN §3).
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from rectify.coords import ray_meeting_t

from ..core.capture import CameraCapture
from ..core.light_transport import sample_light, scalar, segment_box, visible_exact
from ..core.opaque import opaque_scalar
from .blockers import BlockerModes, leaf_visibility
from .factor_layout import factor_layout
from .light_rays.directional import LightRays
from .queries import EpipolarQueries


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
    fraction of shadow rays (:func:`~integrators.core.light_transport.visible_exact`)
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
    # ⌈k·f⌉ shadow rays per traced query (the §7 sub-ray density over the
    # covered part); a traced query's V is their sum, added to 0
    count = mi.UInt32(dr.clip(dr.ceil(k * f), 1, k))
    V = dr.select(mixed, 0.0, V_leaf)
    dr.eval(k0, f, V_leaf, mixed, count, V)     # one pass over the modes (memory-bound gathers)
    idx = dr.compress(mixed)
    if dr.width(idx):
        # the shadow rays at the centres of as many equal pieces of the
        # covered part: (traced query, piece) lanes
        lane = dr.arange(mi.UInt32, dr.width(idx) * k)
        owner, piece = lane // k, lane % k
        keep = dr.compress(piece < dr.gather(mi.UInt32, count, dr.gather(mi.UInt32, idx, owner)))
        owner, piece = keep // k, keep % k
        q = dr.gather(mi.UInt32, idx, owner)
        row = dr.gather(mi.UInt32, queries.row, q)
        n_q = mi.Float(dr.gather(mi.UInt32, count, q))
        g = (mi.Float(dr.gather(mi.UInt32, k0, q))
             + (mi.Float(piece) + 0.5) / n_q * dr.gather(mi.Float, f, q))
        gamma = rays.start(row) + g * dr.gather(mi.Float, rays.delta_gamma, row)
        lit = own_ray_visibility(params, cap, queries, q, gamma, LAST_INTERVAL_EPS)
        dr.scatter_reduce(dr.ReduceOp.Add, V, dr.select(lit, 1.0 / n_q, 0.0), q)
    dr.eval(V)
    return LastInterval(k0, f, V_leaf, V, idx)


def own_ray_visibility(params, cap: CameraCapture, queries: EpipolarQueries, q: mi.UInt32,
                       gamma, eps: float, active=True) -> mi.Bool:
    """Ray-traced V at the point of query ``q``'s own camera ray (its own α,
    not its slice's) where its β meets light-ray angle ``gamma``, kept at
    least ``eps`` × scene extent before the ray's end
    (:func:`~integrators.core.light_transport.visible_exact`); per lane."""
    sample = dr.gather(mi.UInt32, queries.sample, q)
    t, _ = ray_meeting_t(queries.frame, dr.gather(mi.Float, queries.beta, q), gamma)
    t_near = dr.gather(mi.Float, queries.t_near, q)
    t_end = t_near + dr.gather(mi.Float, cap.d, sample)
    # the margin opaque: the medium's extent moves in its last bits with the boundary
    t = dr.clip(t, t_near, dr.maximum(t_end - scalar(eps * params.scene_extent), t_near))
    x = (dr.gather(mi.Point3f, cap.o, sample)
         + dr.gather(mi.Vector3f, cap.omega, sample) * (t - t_near))
    wo, dist, _ = sample_light(params, x)
    _, t_in, t_out = segment_box(params, x, wo, dist)
    return visible_exact(params, x, wo, dist, t_in, t_out, active)


def factor_arrays(x, with_n: bool):
    """(flat array, rows ∈ {1, n}, length, channels, N) of an A/B (``with_n``)
    or L tensor (:func:`~integrators.epipolar.factor_layout.factor_layout`)."""
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
    as :func:`~integrators.tree.partial_sum_tree.integrate_slices` takes them."""
    out = dr.zeros(mi.Color3f, queries.count)
    idx = last.idx                      # V = V_leaf elsewhere
    if not dr.width(idx):
        return out
    row = dr.gather(mi.UInt32, queries.row, idx)
    col = dr.gather(mi.UInt32, queries.col, idx)
    slot = row * opaque_scalar(mi.UInt32, queries.r) + col
    k0 = dr.gather(mi.UInt32, last.k0, idx)
    a, nA, d, CA, N = factor_arrays(A, True)
    b, nB, _, CB, _ = factor_arrays(B, True)
    leaf_a = row * d + k0 if nA > 1 else k0
    leaf_b = slot if nB > 1 else col
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


@dataclass(frozen=True)
class SweepSums:
    """The terms A_i L of the sweep without blockers and their exclusive
    prefix sums along each row (:func:`sweep_sums`): ``v``, ``cum`` (of
    ``|v|``: ``cum_abs``) at lane ((s·C + c)·N + i)·w + g of row s, channel
    c, term i, light ray g < w − 1 (lane w − 1 of a block: 0, its sum the
    row's total).  Each block's prefix sums are formed in order (Dr.Jit's
    block prefix sum of blocks up to 2^15 lanes, which ``light_rays``
    < 2^15 keeps): the first w − 1 are bit for bit those of the block
    alone."""
    v: mi.Float
    cum: mi.Float
    cum_abs: mi.Float
    C: int
    N: int
    w: int


def sweep_sums(queries: EpipolarQueries, A, B, L) -> SweepSums:
    """The :class:`SweepSums` of A (n|1, d, [C,] N) and L (None, (n|1, d)
    or (n|1, d, C)), C the most channels of A, B and L: the terms in one
    kernel, their prefix sums by ``dr.block_prefix_sum``
    (:func:`sweep_magnitude` reads them; so may a caller that needs the
    same sums in another order of reading)."""
    a, nA, d, CA, N = factor_arrays(A, True)
    CB = factor_arrays(B, True)[3]
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
    v_abs = dr.abs(v)
    dr.eval(v, v_abs)                               # both scans' inputs, one kernel
    cum_u = dr.block_prefix_sum(v, w)               # Σ_{γ<g} A_i L
    cum_m = dr.block_prefix_sum(v_abs, w)           # Σ_{γ<g} |A_i L|
    return SweepSums(v, cum_u, cum_m, C, N, w)


def sweep_magnitude(queries: EpipolarQueries, A, B, L, last: "LastInterval",
                    sums: SweepSums | None = None):
    """(M, U) per query: the magnitude M = Σ_{γ<D} Σ_i |A_i L| |B_i| of
    every partial sum the sweep forms for it (the scale of its rounding)
    and the unshadowed sum U = Σ_{γ<D} L Σ_i A_i B_i (the sweep without
    blockers, for :func:`unresolved_samples`), both as the sweep's closed
    form takes the last, partial light ray (cumulative sums lerped at D,
    :mod:`~integrators.tree.partial_sum_tree`; each row's formed in parallel by
    ``dr.block_prefix_sum``).  A (n|1, d, [C,] N), B (n|1, r, [C,] N), L
    None, (n|1, d) or (n|1, d, C); ``last``: each query's last leaf and
    its covered fraction (:func:`last_leaf`, via
    :func:`last_interval_visibility`); ``sums``: their
    :func:`sweep_sums`, made here where None.

    The Fenwick tree removes a shadowed leaf by subtracting w·A·L from node
    sums that added A·L before; a view ray shadowed all along is left with
    the rounding of those cancellations, up to ~ε·M (a prefix sum to D
    reads nodes that hold leaves before D alone; 1e-9…1e-7 of the row's
    light on the terrain), where the exact sum is 0.  Invisible, but HDR
    metrics on mostly black references amplify it (FLIP 0.39 on terrain,
    0.92 on beam); so do the cancellations of the near-plane and
    last-interval corrections.  :func:`~integrators.epipolar.query_terms.assemble_queries`
    returns 0 for a
    query whose result is within ``SWEEP_RESIDUE_EPS`` times the magnitude
    of its parts -- below their own rounding error.  (Counted over the
    whole row, the bound flushed lit queries that end early in a row whose
    far light rays carry e^{20} more light: random stress seed 31.)"""
    sums = sweep_sums(queries, A, B, L) if sums is None else sums
    b, nB, _, CB, _ = factor_arrays(B, True)
    C, N, w = sums.C, sums.N, sums.w
    cum_u, cum_m = sums.cum, sums.cum_abs
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


#: a query whose separated unshadowed sum is off its direct sum by more
#: than this fraction is not resolved either (:func:`unresolved_samples`)
DIRECT_RATIO = 1e-2


def unresolved_samples(queries: EpipolarQueries, U: mi.Color3f, M: mi.Color3f,
                       direct=None) -> mi.Bool:
    """Camera samples with a query whose sum the tree cannot resolve: its
    unshadowed separated sum U below ``UNRESOLVED_RATIO`` of its magnitude
    M (:func:`sweep_magnitude`) in any channel, negative U included (a
    thick fog seen toward the sun, held-out seed 2016 with a box 1.5x as
    large: U = -2.8 % of M, |U| above the ratio, and the pixel black).  The tree's result is then a
    difference of terms ≥ 100× as large: their float32 rounding and the
    separated kernel's absolute error (both ∝ M) are ≥ 1e-5…1e-3 of the
    query's value, and all of it where L grows along the slice by
    e^{20…30} while the view ray's kernel decays as fast (a thick medium
    seen away from a light whose light-side path shrinks along the slice,
    random stress seed 31: 28× the exact sum).  Such samples are ray-marched
    instead (:func:`~integrators.epipolar.ring.remarch_samples`).
    ``direct``: the same sum summed directly where it was checked
    (:class:`~integrators.epipolar.direct_sum.DirectSums`); a checked query
    whose U is off it by more than ``DIRECT_RATIO`` of it is unresolved
    too (a thick fog seen toward the sun, where L grows along the slice as
    K decays: held-out seed 2016 with its box 2x as large, U up to 870x
    the direct sum at U = 6 % of M).  A mask
    of the camera samples, written by the kernel that evaluates ``U`` and
    ``M`` (its caller compresses it after)."""
    mask = dr.zeros(mi.Bool, queries.n_samples)
    if not queries.count:
        return mask
    bad = mi.Bool(False)
    for c in range(3):
        # a negative U (a sum of positive terms) is unresolved whatever its size
        bad |= (M[c] > 0.0) & (U[c] < UNRESOLVED_RATIO * M[c])
        if direct is not None:
            bad |= direct.checked & (dr.abs(U[c] - direct.U[c]) > DIRECT_RATIO * direct.U[c])
    dr.scatter(mask, True, queries.sample, active=bad)
    return mask
