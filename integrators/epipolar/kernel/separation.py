"""The separated kernel (Baran §6, Eq. 4), K(γ, β) ≈ Σ_i a_i(γ) b_i(β), by an
SVD of a 64×64 sample and its exact (Nyström) extension to every light ray
and query.  Shared by ``epipolar_tree`` and ``fourier_filter``.

:func:`separate_kernel` is the one path for every light model: it sets the
SVD tolerance per channel, separates each channel, evaluates the terms in
Dr.Jit and lays them out as the sweep's A (n, d, C, N) and B (n, r, C, N).
What differs by light kind is a *separation* object (the light model's
``separation``) with four stages: ``light_side_path`` (the path length whose
extinction amplifies the tree's errors), ``channel`` (one colour channel's
kernel, separated), ``kernel_points`` (where A is evaluated) and ``to_rows``
(from those points to the rows' light rays).  Here: the directional light's
K = e^{-σt γ tan(β/2)} (:class:`DirectionalSeparation`); the point/spot
light's §9 kernel is :class:`integrators.epipolar.kernel.local.LocalSeparation`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.opaque import Divisor, floats, opaque_scalar, scalar_u32
from ...core.reductions import UNSHARED
from ..light_factor import gray, light_side_extinction, light_side_gains, lowest_light_side
from ..light_rays.directional import LIGHT_SIDE_RANGE
from ..queries import frame_memo, frame_memo_get
from .svd import MAX_RANK, SAMPLES, log1p_grid, separate_sampled_kernel, widen_empty
from .table import nystrom_sums, tabulated_terms, term_table


# --------------------------------------------------------------------------
# The separated kernel (§6, Eq. 4)
# --------------------------------------------------------------------------

def kernel(sigma_t: float):
    """K(γ, β) = e^{-σt γ tan(β/2)}: the camera- and light-side attenuation
    of a directional light joined on light ray γ (DESIGN §1), without the
    per-light-ray factor L(γ) and the per-view-ray factor 1/sin β."""
    def K(gamma, beta):
        return np.exp(-sigma_t * gamma * np.tan(beta / 2))
    return K


def _phi(x):
    """(1 − e^{-x}) / x in float64 (NumPy twin of ``cell_average``)."""
    x = np.asarray(x, np.float64)
    safe = np.where(x < 1e-12, 1.0, x)
    return np.where(x < 1e-12, 1.0, -np.expm1(-safe) / safe)


def separate_channel(sigma_t: float, gamma_max: float, beta_lo: float, beta_hi: float,
                     rank: int, tol: float):
    """Separate K(γ, β) ≈ Σ_i a_i(γ) b_i(β) over γ ∈ [0, γ_max], β ∈ [β_lo, β_hi] (§6)
    with :func:`~integrators.epipolar.kernel.svd.separate_sampled_kernel`.

    Unlike the paper's uniform grid (whose rank-N error is spent where K is
    flat), the grids are uniform in log(1 + c·γ) and log(1 + σt γ_max tan(β/2))
    (c = σt tan(β_hi/2): dense where K decays fastest), and each view ray is
    normalised by its exact s_k = 1 / ∫_0^{γ_max} K(γ, β_k) dγ.  (For
    σt γ_max tan(β/2) ≫ 1, e.g. thick media or view rays near the
    anti-epipole, the uniform grid's sum errors reach 10×; this one keeps
    them at the tolerance.)  The Nyström sums are evaluated in Dr.Jit by
    :func:`exp_kernel_sum`.  Returns ``(γ grid, tan(β grid / 2), WA, WB)``."""
    G = max(float(gamma_max), 1e-30)
    beta_lo, beta_hi = widen_empty(beta_lo, beta_hi)
    x_lo, x_hi = math.tan(0.5 * beta_lo), math.tan(0.5 * beta_hi)
    c = max(sigma_t * x_hi, 1e-6 / G)
    gamma_grid, weight = log1p_grid(c, 0.0, G)
    cb = max(sigma_t * G, 1e-6)
    u = np.linspace(math.log1p(cb * x_lo), math.log1p(cb * x_hi), SAMPLES)
    x_grid = np.expm1(u) / cb

    def scale(beta):
        return 1.0 / (G * _phi(sigma_t * np.tan(0.5 * beta) * G))

    return separate_sampled_kernel(kernel(sigma_t), gamma_grid, weight, x_grid, scale,
                                   (0.0, G), (beta_lo, beta_hi), rank, tol)


def exp_kernel_sum(x: mi.Float, table: np.ndarray, weights: np.ndarray, sigma_t: float):
    """Σ_k e^{-σt x table[k]} weights[k, i] for each term i, per lane of x:
    the Nyström sums of :func:`separate_channel`
    (:func:`~integrators.epipolar.kernel.table.nystrom_sums` of the exponential)."""
    tab = floats(table)
    # float32 range: in extreme optical depths (σt·γ_max ≳ 80) some Nyström
    # weights exceed it; their kernel factor e^{-σt x t} has underflowed to
    # 0 there, and an inf weight would turn 0 into NaN
    finite = np.clip(np.nan_to_num(weights, nan=0.0), -1e30, 1e30)
    st = opaque_scalar(mi.Float, float(sigma_t))
    return nystrom_sums(dr.width(x), finite,
                        lambda k: dr.exp(-st * x * dr.gather(mi.Float, tab, k)))


def directional_ray_kernel(params, queries, rays, sigma_t: float):
    """K(γ_t, β) = e^{-σt γ_t tan(β/2)} as a function of (flat light-ray
    index t, per-lane tan(β/2)), γ_t the light ray's start (equally wide
    rays: φ of the interval's mean is common to a row and cancels in a
    weighted average); the directional light model's ``ray_kernel``."""
    _, gamma = rays.positions(0.0)
    neg_st = opaque_scalar(mi.Float, -float(sigma_t))
    return lambda t, tan: dr.exp(neg_st * dr.gather(mi.Float, gamma, t) * tan)


def beta_span(queries) -> tuple:
    """(smallest, largest) β of all queries."""
    return float(dr.min(queries.beta)[0]), float(dr.max(queries.beta)[0])


def separate_kernel(separation, params, queries, rays, rank: int, tol: float, points=None,
                    frame_rays=None):
    """A (n, d, C, N) at the light rays and B (n, r, C, N) at the queries'
    own β (padded slots: 0) of any light model's kernel (module doc);
    C = 1 for grey σt.  The automatic rank meets ``tol`` after the light
    side's largest amplification (:func:`~integrators.epipolar.light_factor.light_side_gains`
    of ``separation.light_side_path``), per channel, and -- for a
    separation with ``sum_errors`` (the directional light's) -- after the
    rows' actual sums are checked (:func:`checked_tolerances`).
    ``points``: (count, points) at which A is evaluated instead of the
    separation's own ``kernel_points`` (e.g. the Gauss nodes of a
    projective map's texels, :func:`~integrators.fourier.projective_rays.gauss_nodes`):
    A is then (n, count / n, C, N), in the points' order.

    Some rows of a frame (a partial render: ``queries`` a
    :class:`~integrators.partial.row_subset.RowSubset`, ``rays`` its rows' light
    rays, ``frame_rays`` the whole frame's): the kernel is separated (and
    checked) on the whole frame (``queries.whole_frame``, ``frame_rays``)
    and its terms are evaluated at these rows alone (tabulated as the whole
    frame's would be), equal to the whole frame's A and B at these rows."""
    sigma_t = np.asarray(params.medium.sigma_t, np.float64)
    channels = [0] if gray(sigma_t) else [0, 1, 2]
    whole, whole_rays = queries.whole_frame, rays if frame_rays is None else frame_rays
    gains = light_side_gains(sigma_t, lowest_light_side(
        whole, whole_rays, separation.light_side_path(whole, whole_rays)),
        separation.light_side_range)
    tols = [tol / gains[c] for c in channels]
    kernels = [separation.channel(params, whole, whole_rays, float(sigma_t[c]), rank, t)
               for c, t in zip(channels, tols)]
    if not rank and hasattr(separation, "sum_errors"):
        kernels = checked_tolerances(separation, params, whole, whole_rays, channels, kernels,
                                     tols)
    N = max(k.N for k in kernels)
    C = len(kernels)
    own = points is None
    count, points = separation.kernel_points(queries, rays) if own else points
    lanes_a = separation.kernel_points(whole, whole_rays)[0] if own else count
    tan_half = dr.tan(0.5 * queries.beta)   # only at the queries; padded slots stay 0
    A = dr.zeros(mi.Float, count * C * N)
    B = dr.zeros(mi.Float, queries.n * queries.r * C * N)
    used = dr.zeros(mi.UInt32, C * N)
    CN = scalar_u32(C * N)          # the rank is the frame's: not a literal
    lane_a = dr.arange(mi.UInt32, count) * CN
    lane_b = queries.slot * CN
    terms = [(kern.a_terms(points, count, lanes=lanes_a),
              kern.b_terms(tan_half, lanes=whole.count)) for kern in kernels]
    # every channel's N terms: one pass of the Nyström loop, in the kernel
    # that adds them into A (below)
    # each entry written once: an add to the zeros (a plain scatter would
    # launch the pending one to the same array first, a kernel per term),
    # without atomics (no two lanes share an entry)
    for c, (kern, (a_terms, b_terms)) in enumerate(zip(kernels, terms)):
        for i in range(kern.N):
            term = scalar_u32(c * N + i)
            dr.scatter_reduce(dr.ReduceOp.Add, A, a_terms[i], lane_a + term, mode=UNSHARED)
            dr.scatter_reduce(dr.ReduceOp.Add, B, b_terms[i], lane_b + term, mode=UNSHARED)
            # whether some query's b_i is not 0, in the kernel that writes B
            dr.scatter_reduce(dr.ReduceOp.Max, used, mi.UInt32(b_terms[i] != 0.0), term)
    d = rays.d
    if own:
        A = separation.to_rows(A, queries, rays, C * N)
    else:
        d = count // queries.n
    B = mi.TensorXf(B, shape=(queries.n, queries.r, C, N))
    frame_memo(queries, (NONZERO_TERMS, B), lambda: used)
    return mi.TensorXf(A, shape=(queries.n, d, C, N)), B


#: :func:`~integrators.epipolar.queries.frame_memo` key of :func:`nonzero_terms`
NONZERO_TERMS = "nonzero_terms"


def nonzero_terms(queries, B) -> mi.UInt32 | None:
    """(C·N) 1 where some query's B of channel c, term i (at c·N + i) is not
    0, else 0: written by the kernel that writes B
    (:func:`separate_kernel`; a host copy reads it without a kernel of its
    own); None for a B that :func:`separate_kernel` did not make for these
    queries."""
    return frame_memo_get(queries, (NONZERO_TERMS, B))


#: re-separations :func:`checked_tolerances` may make
CHECK_ROUNDS = 2
#: the tightened tolerance's margin below the measured error
CHECK_MARGIN = 2.0
#: light rays per row the sum check evaluates (every k-th)
SUM_CHECK_RAYS = 128


def checked_tolerances(separation, params, queries, rays, channels, kernels, tols):
    """The channels' separated kernels, re-separated at a tighter tolerance
    where the rows' sums would be off by more than their tolerance.

    The automatic rank bounds each view ray's error relative to ∫K dγ.
    The sweep sums K·L·V, and where the light factor L grows along γ as
    fast as K decays (a view ray toward the light in a thick medium: the
    camera-side path grows as the light-side path shrinks) the sum is
    e^{-10…-20} of ∫K dγ and all error (random stress seeds 72, 86).  Here
    ``separation.sum_errors`` measures, for each row's first and last query
    and every light ray, Σ |K̃ − K|·L against the frame's largest
    unshadowed sum; a channel whose ratio exceeds its tolerance is
    separated again at tolerance / (ratio · CHECK_MARGIN), at most
    CHECK_ROUNDS times (and at most MAX_RANK terms)."""
    kernels = list(kernels)
    tols = list(tols)
    for _ in range(CHECK_ROUNDS):
        redo = False
        checked = [k for k in range(len(channels)) if kernels[k].N < MAX_RANK]
        errors = separation.sum_errors(params, queries, rays, [kernels[k] for k in checked])
        for k, err in zip(checked, errors):
            c = channels[k]
            if err > tols[k]:
                tols[k] = tols[k] * tols[k] / (err * CHECK_MARGIN)
                kernels[k] = separation.channel(params, queries, rays,
                                                float(np.asarray(params.medium.sigma_t)[c]),
                                                0, tols[k])
                redo = True
        if not redo:
            break
    return kernels


@dataclass(frozen=True)
class SeparatedChannel:
    """One colour channel of a light model's kernel as
    :func:`~integrators.epipolar.kernel.svd.separate_sampled_kernel` returns it
    (its grids and Nyström weights) and the queries' tan(β/2) range; the
    light model's subclass adds ``a_terms(points, count, lanes)`` and
    ``b_terms(tan_half, lanes)``, the N terms in Dr.Jit (``lanes``: the
    whole frame's count, :func:`~integrators.epipolar.kernel.table.tabulated_terms`)."""
    x_lo: float             # tan(β_lo/2) of the queries
    x_hi: float
    gamma_grid: np.ndarray
    x_grid: np.ndarray      # tan(β/2) of the β grid
    WA: np.ndarray
    WB: np.ndarray

    @property
    def N(self) -> int:
        return self.WA.shape[1]


@dataclass(frozen=True)
class DirectionalChannel(SeparatedChannel):
    """One colour channel of K = e^{-σt γ tan(β/2)}, separated
    (:func:`separate_channel`), with its Dr.Jit terms (:func:`exp_kernel_sum`,
    tabulated: both tables made together, once per channel)."""
    sigma_t: float
    gamma_max: float
    _tables: dict = field(default_factory=dict, compare=False, repr=False)

    def _a_sums(self, x):
        return exp_kernel_sum(x, self.x_grid, self.WA, self.sigma_t)

    def _b_sums(self, x):
        return exp_kernel_sum(x, self.gamma_grid, self.WB, self.sigma_t)

    def _table_args(self, which: str) -> tuple:
        """(lo, hi, c, terms_at) of the a or b table
        (:func:`~integrators.epipolar.kernel.table.term_table`)."""
        st = self.sigma_t
        if which == "a":
            return 0.0, self.gamma_max, st * float(np.max(self.x_grid)), self._a_sums
        return self.x_lo, self.x_hi, st * self.gamma_max, self._b_sums

    def tables(self) -> dict:
        """The a and b tables, evaluated together when the first is asked for."""
        if not self._tables:
            tabs = {which: term_table(*self._table_args(which)) for which in "ab"}
            dr.eval(*tabs["a"].values, *tabs["b"].values)
            self._tables.update(tabs)
        return self._tables

    def a_terms(self, gamma, count: int, lanes: int | None = None) -> list:
        """a_i at light-ray coordinates ``gamma``."""
        return tabulated_terms(gamma, *self._table_args("a"), lanes,
                               table=lambda: self.tables()["a"])

    def b_terms(self, tan_half, lanes: int | None = None) -> list:
        """b_i at the queries' tan(β/2)."""
        return tabulated_terms(tan_half, *self._table_args("b"), lanes,
                               table=lambda: self.tables()["b"])


class DirectionalSeparation:
    """The directional light's stages of :func:`separate_kernel`: A at the
    start γ_g of every light-ray interval (any layout with ``positions``,
    ``gamma_max`` and ``h``); K(γ_g, β)·φ(σt tan(β/2) Δγ) is the exact mean
    of K over the interval (φ: :func:`~integrators.epipolar.query_terms.cell_average`,
    a per-query factor)."""
    #: the light-side range c of its light rays
    #: (:data:`~integrators.epipolar.light_rays.directional.LIGHT_SIDE_RANGE`)
    light_side_range = LIGHT_SIDE_RANGE

    def light_side_path(self, queries, rays):
        """h: the per-query factor e^{-σt h_ref} multiplies the kernel's
        errors (:func:`~integrators.epipolar.light_rays.directional.row_reference`)."""
        return rays.h

    def channel(self, params, queries, rays, sigma_t: float, rank: int,
                tol: float) -> DirectionalChannel:
        gamma_max = float(dr.max(rays.gamma_max)[0])
        beta_lo, beta_hi = beta_span(queries)
        g_grid, x_grid, WA, WB = separate_channel(sigma_t, gamma_max, beta_lo, beta_hi, rank, tol)
        return DirectionalChannel(math.tan(0.5 * beta_lo), math.tan(0.5 * beta_hi), g_grid,
                                  x_grid, WA, WB, sigma_t=sigma_t, gamma_max=gamma_max)

    def kernel_points(self, queries, rays):
        _, gamma = rays.positions(0.0)   # cell starts: φ in the query terms averages K
        return dr.width(gamma), gamma

    def sum_errors(self, params, queries, rays, kernels: list) -> list[float]:
        """For each channel's kernel: max over rows of Σ_γ |K̃ − K|·L (K̃:
        the separated kernel; every k-th light ray, at most SUM_CHECK_RAYS
        per row) at the row's first and last query (smallest, largest β),
        over the largest Σ_γ K·L of any of them; each weighted by its row's
        e^{-σt h_ref} Δγ / sin β (:func:`checked_tolerances`).  Every
        channel's per-row sums are read back together, once."""
        n = queries.n
        if not n or not kernels or getattr(rays, "h", None) is None:
            return [0.0] * len(kernels)
        r_count = mi.UInt32(queries.r_count)
        # the rows' first and last queries (queries are sorted by row, then β)
        begin = dr.prefix_sum(r_count)
        d = rays.d
        # every stride-th light ray of each row (at most SUM_CHECK_RAYS): an
        # estimate of the sums at a fraction of the cost
        stride = max(1, -(-d // SUM_CHECK_RAYS))
        m = -(-d // stride)
        lane = dr.arange(mi.UInt32, n * m)
        d_o, stride_o = (opaque_scalar(mi.UInt32, v) for v in (d, stride))
        s, piece = Divisor(m).divmod(lane)
        g = dr.minimum(piece * stride_o, d_o - 1)
        ray = s * d_o + g
        gamma = rays.position(s, g, 0.0)
        h_ref = rays.h_ref
        h_lo = dr.min(h_ref)
        # the rows' side at each lane of its row, b_i as the sweep evaluates
        # them (``lanes``: the frame's queries: tabulated where the sweep's
        # are, not a Nyström sum per lane), so that the checked light rays
        # are one kernel; each row's weights are written to the buffer with
        # its sums (the same value from every lane of the row: Max keeps it
        # exactly)
        r_s = dr.gather(mi.UInt32, r_count, s)
        used = r_s > 0
        b_s = dr.gather(mi.UInt32, begin, s)
        betas = [dr.gather(mi.Float, queries.beta, q, used)
                 for q in (b_s, b_s + dr.maximum(r_s, 1) - 1)]
        tans = [dr.tan(0.5 * beta) for beta in betas]
        h_ref_s = dr.gather(mi.Float, h_ref, s)
        delta_s = dr.gather(mi.Float, rays.delta_gamma, s)
        # per channel and column: (Σ |K̃ − K| L, Σ K L) per row in one buffer,
        # the weights in another (one kind of reduction per buffer)
        sums = dr.zeros(mi.Float, 4 * n * len(kernels))
        weights = dr.zeros(mi.Float, 2 * n * len(kernels))
        n_o = opaque_scalar(mi.UInt32, n)
        for k, kern in enumerate(kernels):
            neg_st = opaque_scalar(mi.Float, -float(kern.sigma_t))
            L = light_side_extinction(kern.sigma_t, dr.gather(mi.Float, rays.h, ray), h_ref_s)
            a_terms = kern.a_terms(gamma, dr.width(gamma))
            for j, (beta, tan_s) in enumerate(zip(betas, tans)):
                b_terms = kern.b_terms(tan_s, lanes=queries.count)
                approx = dr.zeros(mi.Float, dr.width(gamma))
                for i in range(kern.N):
                    approx += a_terms[i] * b_terms[i]
                exact = dr.exp(neg_st * gamma * tan_s)
                weight = (dr.exp(neg_st * (h_ref_s - h_lo)) * delta_s
                          * mi.Float(stride_o) / dr.maximum(dr.sin(beta), 1e-6))
                base = opaque_scalar(mi.UInt32, (4 * k + 2 * j) * n)
                dr.scatter_reduce(dr.ReduceOp.Add, sums, dr.abs(approx - exact) * L, base + s)
                dr.scatter_reduce(dr.ReduceOp.Add, sums, exact * L, base + n_o + s)
                dr.scatter_reduce(dr.ReduceOp.Max, weights,
                                  weight, opaque_scalar(mi.UInt32, (2 * k + j) * n) + s)
        dr.eval(sums, weights)                  # the checked light rays, one kernel
        # host reads of evaluated arrays (copies, no kernels): the sums, weights
        host = np.asarray(sums).reshape(len(kernels), 2, 2, n)
        w_host = np.asarray(weights).reshape(len(kernels), 2, n)
        use = np.asarray(queries.r_count) > 0
        out = []
        for k in range(len(kernels)):
            worst, scale = 0.0, 0.0
            for j in range(2):
                w = w_host[k, j]
                # fmax: a NaN lane is skipped, as dr.max skips it
                worst = max(worst, float(np.fmax.reduce(np.where(use, host[k, j, 0] * w, 0.0))))
                scale = max(scale, float(np.fmax.reduce(np.where(use, host[k, j, 1] * w, 0.0))))
            out.append(worst / scale if scale > 0.0 else 0.0)
        return out

    def to_rows(self, A, queries, rays, CN: int):
        return A
