"""The filtered Fourier basis of a rectified shadow map's rows: prefix
sums of each texel's basis coefficients, region bounds, and the filtered
visibility of a query (Klehm et al. 2014 §3-§4), with NumPy oracles.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import Divisor, opaque_scalar
from .basis import (DEFAULT_M, band_drop_weights, basis_coefficients_reference, check_M,
                    odd_harmonics, reconstruction_weights, reconstruction_weights_reference,
                    transmittance_weights)


# ---------------------------------------------------------------------------
# Prefiltering: weighted running prefix sums (Listings 1-3)
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class FilteredBasis:
    """Filtered-basis textures of a rectified shadow map (§3.3, Appendix A).

    ``B_bar[row, i, m]`` = normalised weighted prefix of basis ``m`` over the
    texels of ``i``'s region up to ``i``; ``W[row, i]`` = the weight sum
    of that prefix; ``z_lo/z_hi[row, r]`` = depth range of region ``r``.
    """
    B_bar: mi.TensorXf   # (n_rows, n, M); mi.TensorXf16 if prefiltered with half=True
    W: mi.TensorXf       # (n_rows, n)
    z_lo: mi.TensorXf    # (n_rows, regions)
    z_hi: mi.TensorXf    # (n_rows, regions)
    M: int
    regions: int = 1
    fit_depth: bool = False
    #: rows of one layer where several filters of the same rows are stacked
    #: (:func:`prefix_filter`'s ``layers``; the depth bounds are the
    #: layers' common ones); 0: one layer
    layer_rows: int = 0

    @property
    def n_rows(self) -> int:
        return self.W.shape[0]

    @property
    def n(self) -> int:
        return self.W.shape[1]

    @property
    def region_length(self) -> int:
        return region_length(self.n, self.regions)


def region_length(n: int, regions: int) -> int:
    """``L = ⌈n/R⌉``; region ``r`` holds texels ``[r L, min((r+1) L, n))``."""
    if isinstance(regions, bool) or int(regions) != regions or regions < 1:
        raise ValueError(f"regions = {regions!r} must be a positive integer.")
    L = -(-n // regions)
    if (regions - 1) * L >= n:
        raise ValueError(f"regions = {regions} leaves an empty region in a row of "
                         f"{n} texels; use fewer regions.")
    return L


def _group_size(M: int) -> int:
    """Bases per prefilter lane (the paper's 'bases per thread', Table 1)."""
    return next(g for g in (16, 8, 4, 2) if M % g == 0)


def _as_rows(z_rows) -> mi.TensorXf:
    z = mi.TensorXf(z_rows)
    if len(z.shape) != 2:
        raise ValueError(f"z_rows must have shape (n_rows, n), got {z.shape}.")
    return z


def _weights_array(weights, n_rows: int, n: int):
    """Flat weights and whether they are shared by all rows (shape (n,));
    a function of (row, texel) is passed through (per row)."""
    if weights is None:
        return None, True
    if callable(weights):
        return weights, False
    w = mi.TensorXf(weights)
    if w.shape == (n,):
        return w.array, True
    if w.shape == (n_rows, n):
        return w.array, False
    raise ValueError(f"weights must have shape ({n},) or ({n_rows}, {n}), got {w.shape}.")


def region_depth_bounds(z: mi.TensorXf, regions: int, depth=None):
    """``(z_lo, z_hi)``: min and max blocker depth of every (row, region);
    ``depth``: None, or a function ``depth(row, i)`` giving ``z[row, i]``
    from evaluated arrays (a ``z`` left unevaluated is then made in the
    bounds' kernel where the widths agree, one region)."""
    n_rows, n = z.shape
    L = region_length(n, regions)
    n_o, RL_o = opaque_scalar(mi.UInt32, n), opaque_scalar(mi.UInt32, regions * L)
    idx = dr.arange(mi.UInt32, n_rows * regions * L)
    row, i = idx // RL_o, idx % RL_o
    valid = i < n_o
    zi = (dr.gather(mi.Float, z.array, row * n_o + i, valid) if depth is None
          else depth(row, dr.select(valid, i, 0)))
    lo_in, hi_in = dr.select(valid, zi, dr.inf), dr.select(valid, zi, -dr.inf)
    dr.eval(lo_in, hi_in)           # one kernel for both reductions' inputs
    z_lo = dr.block_reduce(dr.ReduceOp.Min, lo_in, L)
    z_hi = dr.block_reduce(dr.ReduceOp.Max, hi_in, L)
    return mi.TensorXf(z_lo, shape=(n_rows, regions)), mi.TensorXf(z_hi, shape=(n_rows, regions))


def depth_map(z_lo, z_hi, fit_depth: bool):
    """``(offset, scale)`` with ``z' = (z − offset)·scale`` the depth the basis sees.

    Identity without ``fit_depth``; else shift ``z_lo → 0`` and stretch by
    ``max(1, 1/(2 (z_hi − z_lo)))``: a range narrower than 1/2 maps onto
    ``[0, 1/2]``, a wider one is only shifted (never blunter than Eq. 8).
    """
    if not fit_depth:
        return mi.Float(0.0), mi.Float(1.0)
    span = z_hi - z_lo
    return z_lo, dr.select(span > 0.0, dr.maximum(0.5 / span, 1.0), 1.0)


def prefix_filter(z_rows, weights=None, M: int = DEFAULT_M, regions: int = 1,
                  fit_depth: bool = False, half: bool = False, bounds=None,
                  rows=None, layers: int = 1) -> FilteredBasis:
    """Weighted running prefix sums of the basis along every row (Listings 1–3).

    ``z_rows``: blocker depths ``(n_rows, n)`` in [0, 1]; ``weights``: ``None``
    (uniform = average visibility, §3.1), ``(n,)`` (same for every row),
    ``(n_rows, n)`` (per-row transmittance / angular weights, §3.2) or a
    function ``weights(row, i)`` of (n_rows·R·groups) lanes read in the
    filter's loop (weights made from evaluated arrays: no texel array of
    its own).  ``bounds``: ``(z_lo, z_hi)`` of :func:`region_depth_bounds`
    of these ``z_rows`` and ``regions`` where known (the same rows filtered
    with other weights).  ``rows``: ``None`` (all), an (n_rows,) mask of
    the rows to filter or a function of row indices giving it; the others
    keep ``B̄ = 0`` and ``W = 0`` (a weight sum of 0:
    :func:`filtered_visibility` reads visibility 1 there).  ``layers`` > 1:
    that many filters of the same rows with other weights, stacked (rows
    ``l·n_rows + row``; ``weights`` and ``rows`` then functions of the
    stacked row), in one kernel; each layer bit for bit its own call.

    One Dr.Jit lane per (row, region, group of 16 bases) walks its texels left to
    right in a symbolic loop, computes the bases on the fly from the depth
    (Listing 3) and scatters the running normalised mix (Listing 2).
    ``half=True`` stores ``B̄`` as float16 (half the memory and bandwidth; the
    paper stores 8 bits, Appendix A): visibility changes by < 3e-4 (tested).
    """
    M = check_M(M)
    z = _as_rows(z_rows)
    n_rows, n = z.shape
    L = region_length(n, regions)
    w_flat, shared_w = _weights_array(weights, n_rows, n)
    z_lo, z_hi = region_depth_bounds(z, regions) if bounds is None else bounds

    G = _group_size(M)
    groups = M // G
    if layers > 1 and not (w_flat is None or callable(w_flat)) or layers < 1:
        raise ValueError("several layers need weights as a function of the stacked row.")
    lane = dr.arange(mi.UInt32, layers * n_rows * regions * groups)
    g, rr = lane % groups, lane // groups          # rr = stacked row * regions + r
    row_out, r = rr // regions, rr % regions       # stacked row l·n_rows + row
    if layers > 1:
        row = Divisor(n_rows).divmod(row_out)[1]
        rr = row * regions + r
    else:
        row = row_out
    n_o, L_o = opaque_scalar(mi.UInt32, n), opaque_scalar(mi.UInt32, L)
    start = r * L_o
    end = dr.minimum(start + L_o, n_o)
    if rows is not None:
        end = dr.select(rows(row_out) if callable(rows) else dr.gather(mi.Bool, rows, row_out),
                        end, start)
    offset, scale = depth_map(dr.gather(mi.Float, z_lo.array, rr),
                              dr.gather(mi.Float, z_hi.array, rr), fit_depth)
    # first harmonic of the group: basis index g*G -> k0 = g*G/2 (0-based)
    k0 = mi.Float(g * (G // 2))

    store = mi.Float16 if half else mi.Float
    B_bar = dr.zeros(store, layers * n_rows * n * M)
    W_out = dr.zeros(mi.Float, layers * n_rows * n)

    def cond(i, W, Bb):
        return i < end

    def body(i, W, Bb):
        zi = (dr.gather(mi.Float, z.array, row * n_o + i) - offset) * scale
        texel = row_out * n_o + i
        if w_flat is None:
            w = mi.Float(1.0)
        elif callable(w_flat):
            w = w_flat(row_out, i)
        else:
            w = dr.gather(mi.Float, w_flat, i if shared_w else texel)
        W = W + w
        t = dr.select(W > 0.0, w / W, 0.0)
        B = _group_bases(zi, k0, G)
        Bb = [dr.fma(b - bb, t, bb) for b, bb in zip(B, Bb)]
        base = texel * M + g * G
        for m in range(G):
            dr.scatter(B_bar, store(Bb[m]), base + m)
        dr.scatter(W_out, W, texel, active=g == 0)
        return i + 1, W, Bb

    dr.while_loop((mi.UInt32(start), mi.Float(0.0), [mi.Float(0.0)] * G), cond, body,
                  labels=("i", "W", "B_bar"), label="fourier_prefix_filter")
    tensor = mi.TensorXf16 if half else mi.TensorXf
    return FilteredBasis(tensor(B_bar, shape=(layers * n_rows, n, M)),
                         mi.TensorXf(W_out, shape=(layers * n_rows, n)),
                         z_lo, z_hi, M, regions, fit_depth, n_rows if layers > 1 else 0)


def _group_bases(z, k0, G: int) -> list:
    """Bases ``k0*2 .. k0*2 + G − 1`` (0-based) of depth ``z``; ``k0`` per lane."""
    theta = dr.pi * z
    s, c = dr.sincos(theta * dr.fma(2.0, k0, 1.0))
    s2, c2 = dr.sincos(2.0 * theta)
    B = [s, c]
    for _ in range(1, G // 2):
        s, c = dr.fma(s, c2, c * s2), dr.fma(c, c2, -(s * s2))
        B += [s, c]
    return B


def prefix_filter_reference(z_rows, weights=None, M: int = DEFAULT_M, regions: int = 1,
                            fit_depth: bool = False) -> dict:
    """NumPy oracle of :func:`prefix_filter`: ``cumsum(w·B) / cumsum(w)`` per region.

    Returns ``dict(B_bar=(n_rows, n, M), W=(n_rows, n), z_lo, z_hi=(n_rows, R))``.
    """
    z = np.asarray(z_rows, np.float64)
    n_rows, n = z.shape
    L = region_length(n, regions)
    w = np.ones_like(z) if weights is None else np.broadcast_to(
        np.asarray(weights, np.float64), z.shape)
    out = dict(B_bar=np.zeros((n_rows, n, check_M(M))), W=np.zeros((n_rows, n)),
               z_lo=np.zeros((n_rows, regions)), z_hi=np.zeros((n_rows, regions)))
    for r in range(regions):
        sl = slice(r * L, min((r + 1) * L, n))
        lo, hi = z[:, sl].min(axis=1), z[:, sl].max(axis=1)
        out["z_lo"][:, r], out["z_hi"][:, r] = lo, hi
        zp = _depth_map_reference(z[:, sl], lo[:, None], hi[:, None], fit_depth)
        S = np.cumsum(w[:, sl, None] * basis_coefficients_reference(zp, M), axis=1)
        W = np.cumsum(w[:, sl], axis=1)
        out["W"][:, sl] = W
        with np.errstate(invalid="ignore", divide="ignore"):
            out["B_bar"][:, sl] = np.where(W[..., None] > 0, S / W[..., None], 0.0)
    return out


def _depth_map_reference(z, lo, hi, fit_depth):
    if not fit_depth:
        return z
    span = hi - lo
    return (z - lo) * np.where(span > 0, np.maximum(0.5 / np.where(span > 0, span, 1), 1), 1.0)


# ---------------------------------------------------------------------------
# Per-pixel evaluation (Listing 4)
# ---------------------------------------------------------------------------

def filtered_visibility(fb: FilteredBasis, row, j, z_r, clamp: bool = False,
                        exact_bounds: bool = True, active=True, band: float = 0.0):
    """Filtered (weighted average) visibility ``V̄`` of view rays (Listing 4, Eq. 7).

    ``row`` (mi.UInt32): epipolar slice; ``j`` (mi.Float): continuous texel
    coordinate of the ray's end (clamped to ``[0, n−1]``, see :mod:`integrators.fourier.basis`);
    ``z_r`` (mi.Float): the ray's rectified depth.  Per lookup
    ``v = a(z_r)·B̄ + 0.5`` (clamped to [0, 1] if ``clamp``, Appendix A), combined
    with the weight sums ``W`` so that regions and fractional ``j`` give the
    weighted average over texels ``[0, j]``.  Multiply by ``σ_t ∫_0^s T`` (or the
    weight sum) to get the sum of Eq. 11.  ``exact_bounds`` uses each region's
    depth range (:mod:`integrators.fourier.basis`; ``False`` = the series as published).  Lanes
    with ``active`` false or a zero weight sum return 1.  Cost: ``2·M`` gathers
    (``(R + 1)·M`` with ``R`` regions) and one coefficient set per pixel.

    ``band`` > 0: ``(V̄, drop)``, also the drop of the (unclamped) series
    average from ``z_r − band`` to ``z_r + band``
    (:func:`~integrators.fourier.basis.band_drop_weights`:
    the same gathers, one more dot product; 0 in a region whose depth
    range ``exact_bounds`` decides exactly): about the weighted share of the
    texels whose depth lies within ``band`` of the ray's, where the series
    blurs the step.
    """
    n, R = fb.n, fb.regions
    row = mi.UInt32(row)
    z_r = mi.Float(z_r)
    n_o, L_o = opaque_scalar(mi.UInt32, n), opaque_scalar(mi.UInt32, fb.region_length)
    jc = dr.clip(mi.Float(j), 0.0, opaque_scalar(mi.Float, n - 1))
    j0 = mi.UInt32(jc)
    f = jc - mi.Float(j0)
    j1 = dr.minimum(j0 + 1, n_o - 1)
    if R == 1:                                # same region: shared gathers
        rho0 = rho1 = mi.UInt32(0)
    else:
        rho0, rho1 = j0 // L_o, j1 // L_o
    a_shared = None
    if not fb.fit_depth:
        harmonics = odd_harmonics(z_r, fb.M // 2)
        a_shared = [reconstruction_weights(z_r, fb.M, harmonics)]
        if band > 0.0:
            a_shared.append(band_drop_weights(z_r, band, fb.M, harmonics))

    bound_row = Divisor(fb.layer_rows).divmod(row)[1] if fb.layer_rows else row

    def lookup(q, rho, mask):
        return _lookup(fb, row * n_o + q, bound_row * R + rho, z_r, a_shared, clamp,
                       exact_bounds, mask, band)

    v0, W0 = lookup(j0, rho0, active)
    v1, W1 = lookup(j1, rho1, active)
    num = [(1.0 - f) * W0 * a + f * W1 * b for a, b in zip(v0, v1)]
    den = (1.0 - f) * W0 + f * W1
    for r in range(R - 1):                    # ends of the regions in front (§3.3)
        before1 = rho1 > r
        c = dr.select(rho0 > r, 1.0 - f, 0.0) + dr.select(before1, f, 0.0)
        end_r = dr.minimum((r + 1) * L_o, n_o) - 1
        v_e, W_e = lookup(end_r, mi.UInt32(r), before1 & active)
        num = [x + c * W_e * v for x, v in zip(num, v_e)]
        den += c * W_e
    V = dr.select(den > 0.0, num[0] / den, 1.0)
    if band <= 0.0:
        return V
    return V, dr.select(den > 0.0, num[1] / den, 0.0)


def _lookup(fb, texel, rr, z_r, a_shared, clamp, exact_bounds, active, band=0.0):
    """Regional average visibility ``v`` and weight sum ``W`` at a texel
    (flat index ``row·n + q``) of region ``rr`` (flat ``row·R + ρ``); ``v`` a
    list: ``[v]``, or with ``band`` ``[v, drop]`` (:func:`filtered_visibility`)."""
    z_lo = dr.gather(mi.Float, fb.z_lo.array, rr, active)
    z_hi = dr.gather(mi.Float, fb.z_hi.array, rr, active)
    bounded = exact_bounds or fb.fit_depth
    inside = active & ((z_r > z_lo) & (z_r <= z_hi) if bounded else True)
    if a_shared is None:
        offset, scale = depth_map(z_lo, z_hi, True)
        z_m = (z_r - offset) * scale
        harmonics = odd_harmonics(z_m, fb.M // 2)
        a_sets = [reconstruction_weights(z_m, fb.M, harmonics)]
        if band > 0.0:
            a_sets.append(band_drop_weights(z_m, band * scale, fb.M, harmonics))
    else:
        a_sets = a_shared
    base = texel * fb.M
    source = fb.B_bar.array
    dots = [mi.Float(0.0) for _ in a_sets]
    for m in range(fb.M):
        b = mi.Float(dr.gather(type(source), source, base + m, inside))
        dots = [dr.fma(a[m], b, dot) for a, dot in zip(a_sets, dots)]
    v = dots[0] + 0.5
    if clamp:
        v = dr.clip(v, 0.0, 1.0)
    if bounded:
        v = dr.select(z_r <= z_lo, 1.0, dr.select(z_r > z_hi, 0.0, v))
    values = [v]
    if band > 0.0:
        values.append(dr.select(inside, dots[1], 0.0))
    W = dr.gather(mi.Float, fb.W.array, texel, active)
    return values, W


def filtered_visibility_reference(z_row, weights, j: float, z_r: float, M: int = DEFAULT_M,
                                  clamp: bool = False, exact_bounds: bool = True,
                                  regions: int = 1, fit_depth: bool = False) -> float:
    """NumPy oracle of :func:`filtered_visibility` for one ray of one row.

    Sums ``w_i (0.5 + a(z_r)·B(z_i))`` directly over the texels of each region up
    to ``⌊j⌋`` and ``⌊j⌋ + 1`` (no prefix sums) and combines them exactly as the
    fast path does (per-lookup clamp, lerp of the un-normalised sums).
    """
    z = np.asarray(z_row, np.float64)
    n = z.size
    w = np.ones(n) if weights is None else np.broadcast_to(np.asarray(weights, np.float64), (n,))
    L = region_length(n, regions)
    jc = min(max(float(j), 0.0), n - 1.0)
    j0 = int(jc)
    f, j1 = jc - j0, min(j0 + 1, n - 1)

    def cumulative(q):                       # Σ_{i≤q} w_i v_region(i), Σ_{i≤q} w_i
        num = den = 0.0
        for r in range(q // L + 1):
            sl = np.arange(r * L, min((r + 1) * L, n) if r < q // L else q + 1)
            region = z[r * L:min((r + 1) * L, n)]
            v = _region_average_reference(z[sl], w[sl], region.min(), region.max(), z_r, M,
                                          clamp, exact_bounds, fit_depth)
            num, den = num + w[sl].sum() * v, den + w[sl].sum()
        return num, den

    (n0, d0), (n1, d1) = cumulative(j0), cumulative(j1)
    num, den = (1 - f) * n0 + f * n1, (1 - f) * d0 + f * d1
    return num / den if den > 0 else 1.0


def _region_average_reference(z, w, lo, hi, z_r, M, clamp, exact_bounds, fit_depth):
    """``0.5 + Σ w_i a(z_r')·B(z_i') / Σ w_i`` of one region's texels (Eq. 10)."""
    bounded = exact_bounds or fit_depth
    if bounded and z_r <= lo:
        return 1.0
    if bounded and z_r > hi:
        return 0.0
    zp = _depth_map_reference(z, lo, hi, fit_depth)
    zrp = _depth_map_reference(np.float64(z_r), lo, hi, fit_depth)
    if w.sum() <= 0:
        v = 0.5
    else:
        v = 0.5 + (w[:, None] * basis_coefficients_reference(zp, M)).sum(0) @ \
            reconstruction_weights_reference(zrp, M) / w.sum()
    return float(np.clip(v, 0, 1)) if clamp else float(v)


def average_visibility_reference(z_row, weights, j: float, z_r: float) -> float:
    """Exact weighted average of the step visibility over texels ``[0, j]`` (Eq. 2/5).

    ``V_i = 1`` if ``z_r ≤ z_i`` else 0; texel ``⌊j⌋ + 1`` counts with weight
    fraction ``j − ⌊j⌋`` (same convention as :func:`filtered_visibility`).
    """
    z = np.asarray(z_row, np.float64)
    n = z.size
    w = np.ones(n) if weights is None else np.broadcast_to(np.asarray(weights, np.float64), (n,))
    jc = min(max(float(j), 0.0), n - 1.0)
    j0 = int(jc)
    f = jc - j0
    cover = np.zeros(n)
    cover[:j0 + 1] = 1.0
    if j0 + 1 < n:
        cover[j0 + 1] = f
    ww = w * cover
    return float((ww * (z_r <= z)).sum() / ww.sum()) if ww.sum() > 0 else 1.0


# ---------------------------------------------------------------------------
# Benchmark
# ---------------------------------------------------------------------------

def _timed(fn, reps: int):
    """(first-run seconds incl. compilation, warm median, warm minimum)."""
    times = []
    for _ in range(reps + 1):
        t0 = time.perf_counter()
        out = fn()
        dr.eval(out)
        dr.sync_thread()
        times.append(time.perf_counter() - t0)
    return times[0], statistics.median(times[1:]), min(times[1:])


def bench_filter(n_rows: int = 1024, n: int = 1024, M: int = DEFAULT_M,
                 pixels: int = 1280 * 960, regions: int = 1, fit_depth: bool = False,
                 clamp: bool = True, exact_bounds: bool = True, half: bool = False,
                 reps: int = 3, seed: int = 0) -> dict:
    """Warm median times (s) of the prefilter and of the per-pixel evaluation.

    Also the first run (includes kernel compilation) and the warm minimum
    (useful on a shared machine).  Transmittance weights (Eq. 11), defaults
    ``clamp`` and ``exact_bounds`` as an integrator would use them.

    Random blocker rows (half the texels unblocked) and random rays; the cost
    does not depend on the data except through ``exact_bounds`` skipping gathers.
    """
    rng = np.random.default_rng(seed)
    z = rng.random((n_rows, n), dtype=np.float32)
    z[rng.random((n_rows, n)) < 0.5] = 1.0
    z_rows = mi.TensorXf(z)
    w = transmittance_weights(dr.zeros(mi.Float, n_rows) + 2.0 / n, n)
    dr.eval(z_rows, w)
    def prefilter_once():
        return prefix_filter(z_rows, w, M, regions, fit_depth, half)

    first_pre, prefilter, prefilter_min = _timed(prefilter_once, reps)
    fb = prefilter_once()
    dr.eval(fb)
    row = mi.UInt32(rng.integers(0, n_rows, pixels).astype(np.uint32))
    j = mi.Float((rng.random(pixels) * (n - 1)).astype(np.float32))
    z_r = mi.Float(rng.random(pixels, dtype=np.float32))
    dr.eval(row, j, z_r)
    first_ev, evaluate, evaluate_min = _timed(
        lambda: filtered_visibility(fb, row, j, z_r, clamp, exact_bounds), reps)
    return dict(n_rows=n_rows, n=n, M=M, pixels=pixels, regions=regions,
                fit_depth=fit_depth, half=half, prefilter_s=prefilter, evaluate_s=evaluate,
                prefilter_first_s=first_pre, evaluate_first_s=first_ev,
                prefilter_min_s=prefilter_min, evaluate_min_s=evaluate_min,
                threads=dr.thread_count())
