"""Stage "refinement": which samples are integrated, and from which the rest
are interpolated (Yusov 2013, "Sample classification", "Interpolation source
texture").

* Initial integration samples every ``initial_step`` samples along each
  slice, plus the first and last sample of the slice's used run, and denser
  near the epipole (the talk: "denser near the epipole"): there the
  in-scattering of a light in view grows like ``1/ρ`` (``ρ`` the pixel
  distance to the epipole, where every slice starts), which linear
  interpolation over ``initial_step`` samples overshoots many times over.
  Within the band where ``initial_step`` samples span more than
  ``epipole_spacing · ρ`` pixels the step is the largest power of two whose
  span stays below it (:func:`initial_samples`), so neighbouring
  integration samples are at most that fraction of their distance to the
  epipole apart; slices far from an off-screen epipole are unchanged.
* Criteria that add samples directly before and after a break between
  neighbours ``j, j+1`` of one slice:

  - ``depth`` (the talk): ``|d_j − d_{j+1}| > threshold`` (``absolute``) or
    ``> threshold · min(d_j, d_{j+1})`` (``relative``), ``d`` the in-medium
    distance of the sample's camera ray;
  - ``inscattering`` (a later port of the method): the coarse *unshadowed*
    in-scattering of the two samples differs by more than ``threshold``
    relative to the larger one; it sees depth breaks that matter for the
    light (not those in the dark) and the spot cone's edges;
  - ``visibility`` (beyond the talk): ``depth`` plus, after integrating,
    every interval between two neighbouring integration samples whose
    *shadowed* results differ by more than ``threshold`` (relative) gets its
    midpoint integrated, repeatedly until the results agree or the interval
    has no inner sample — the case of a tight beam on a flat floor, where no
    depth break marks the beam's edges (Baran 2010, Fig. 13).

* Interpolation sources: each sample's nearest integration samples ``lo ≤ j
  ≤ hi`` on its slice (integration samples are their own source) and the
  linear weight between them (:func:`interpolation_sources`;
  :func:`interpolation_sources_reference` is the direct scan).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import mean, scalar_i32, scalar_u32, two_or_more
from .slices_and_samples import EpipolarSamples


CRITERIA = ("depth", "inscattering", "visibility")
THRESHOLD_MODES = ("relative", "absolute")


@dataclass(frozen=True, eq=False)
class Sources:
    """Per sample: interpolation sources ``lo``, ``hi`` (flat sample indices)
    and weight ``f`` of ``hi``."""
    lo: mi.UInt32 = field(repr=False)
    hi: mi.UInt32 = field(repr=False)
    f: mi.Float = field(repr=False)


def row_index(samples: EpipolarSamples):
    idx = dr.arange(mi.UInt32, samples.size)
    return idx, idx - samples.slice * samples.count


def _neighbour(samples: EpipolarSamples, values, offset: int, Type=mi.Float):
    """values[s + offset] (clamped into the array; callers mask row ends)."""
    idx = dr.arange(mi.UInt32, samples.size)
    j = mi.Int32(idx) + offset
    j = mi.UInt32(dr.clip(j, 0, scalar_i32(samples.size - 1)))
    return dr.gather(Type, values, j)


def run_ends(samples: EpipolarSamples):
    """(first, last): used samples whose row neighbour before / after is not used."""
    _, j = row_index(samples)
    M = samples.count
    prev_used = _neighbour(samples, samples.used, -1, mi.Bool) & (j > 0)
    next_used = _neighbour(samples, samples.used, +1, mi.Bool) & (j < M - 1)
    return samples.used & ~prev_used, samples.used & ~next_used


def local_step(samples: EpipolarSamples, initial_step: int, epipole_spacing: float) -> mi.UInt32:
    """Per sample: the integration step in samples, ``initial_step`` or, where
    ``initial_step`` samples span more than ``epipole_spacing · ρ`` pixels,
    the largest power of two (≥ 1) whose span does not (module docstring)."""
    step = dr.full(mi.UInt32, initial_step, samples.size)
    if epipole_spacing <= 0 or samples.rho is None:
        return step
    _, j = row_index(samples)
    rho = samples.rho
    nxt = _neighbour(samples, rho, +1)
    prv = _neighbour(samples, rho, -1)
    # pixel spacing of the samples along the slice (the run's last sample: the one before)
    has_next = (j < samples.count - 1) & dr.isfinite(nxt)
    gap = dr.abs(dr.select(has_next, nxt - rho, rho - prv))
    fit = epipole_spacing * rho / dr.maximum(gap, 1e-6)       # samples within the spacing
    pow2 = mi.UInt32(1) << mi.UInt32(dr.clip(dr.floor(dr.log2(dr.maximum(fit, 1.0))), 0, 30))
    near = dr.isfinite(fit) & (fit < initial_step)
    return dr.select(near, dr.minimum(pow2, initial_step), step)


def initial_samples(samples: EpipolarSamples, initial_step: int,
                    epipole_spacing: float = 0.0) -> mi.Bool:
    """Every ``local_step``-th sample of each slice (``initial_step`` away
    from the epipole) plus its run's ends."""
    _, j = row_index(samples)
    first, last = run_ends(samples)
    step = local_step(samples, initial_step, epipole_spacing)
    return samples.used & ((j % step == 0) | first | last)


def breaks(samples: EpipolarSamples, value, threshold: float, mode: str = "relative",
           scale=None) -> mi.Bool:
    """Samples on either side of a break ``|v_j − v_{j+1}| > threshold``
    (``absolute``), ``> threshold · min(v_j, v_{j+1})`` (``relative``) or
    ``> threshold · scale_j`` when a per-pair ``scale`` is given."""
    nxt = _neighbour(samples, value, +1)
    _, j = row_index(samples)
    pair = samples.used & _neighbour(samples, samples.used, +1, mi.Bool) & (j < samples.count - 1)
    diff = dr.abs(value - nxt)
    if scale is not None:
        limit = threshold * scale
    elif mode == "absolute":
        limit = mi.Float(threshold)
    else:
        limit = threshold * dr.minimum(value, nxt)
    brk = pair & (diff > limit)
    before = _neighbour(samples, brk, -1, mi.Bool) & (j > 0)
    return brk | before


def depth_breaks(samples: EpipolarSamples, threshold: float, mode: str) -> mi.Bool:
    return breaks(samples, samples.d, threshold, mode)


def luminance(L: mi.Color3f) -> mi.Float:
    return (L.x + L.y + L.z) * (1.0 / 3.0)


def inscattering_breaks(samples: EpipolarSamples, unshadowed: mi.Color3f,
                        threshold: float) -> mi.Bool:
    """Breaks of the coarse unshadowed in-scattering (relative to the larger
    of the pair, floored at 1e-3 of the mean so darkness does not refine)."""
    v = luminance(unshadowed)
    floor = 1e-3 * mean(dr.select(samples.used, v, 0.0))
    scale = dr.maximum(dr.maximum(v, _neighbour(samples, v, +1)), floor)
    return breaks(samples, v, threshold, scale=scale)


def interpolation_sources(samples: EpipolarSamples, flags: mi.Bool) -> Sources:
    """Nearest integration samples around every sample of its slice: the
    inclusive prefix count ``c`` of ``flags`` picks ``pos[c−1]`` (the last
    integration sample ≤ s) and ``pos[c]`` (the next one); run ends are
    integration samples, so sources never cross slices."""
    ones = dr.select(flags, mi.UInt32(1), mi.UInt32(0))
    c = dr.cumsum(ones)
    pos = dr.compress(flags)
    n = dr.width(pos)
    s = dr.arange(mi.UInt32, samples.size)
    if n == 0:
        return Sources(lo=s, hi=s, f=dr.zeros(mi.Float, samples.size))
    lo = dr.gather(mi.UInt32, pos, mi.UInt32(dr.clip(mi.Int32(c) - 1, 0, scalar_i32(n - 1))))
    hi = dr.gather(mi.UInt32, pos, dr.minimum(c, scalar_u32(n - 1)))
    hi = dr.select(flags | (hi < s), lo, hi)
    lo = dr.select(samples.used, lo, s)
    hi = dr.select(samples.used, hi, s)
    span = mi.Float(hi) - mi.Float(lo)
    f = dr.select(span > 0, (mi.Float(s) - mi.Float(lo)) / dr.maximum(span, 1.0), 0.0)
    return Sources(lo=lo, hi=hi, f=f)


def interpolation_sources_reference(used: np.ndarray, flags: np.ndarray):
    """Direct scan per row: (lo, hi, f) arrays of the (S, M) flags."""
    S, M = flags.shape
    lo = np.tile(np.arange(M), (S, 1))
    hi = lo.copy()
    f = np.zeros((S, M))
    for k in range(S):
        for j in range(M):
            if not used[k, j] or flags[k, j]:
                continue
            a = j
            while a > 0 and not flags[k, a]:
                a -= 1
            b = j
            while b < M - 1 and not flags[k, b]:
                b += 1
            if flags[k, a] and flags[k, b]:
                lo[k, j], hi[k, j], f[k, j] = a, b, (j - a) / (b - a)
    base = (np.arange(S) * M)[:, None]
    return lo + base, hi + base, f


def interpolate(sources: Sources, values: mi.Color3f, used: mi.Bool) -> mi.Color3f:
    """Linear interpolation between the two sources of every sample."""
    a = dr.gather(mi.Color3f, values, sources.lo)
    b = dr.gather(mi.Color3f, values, sources.hi)
    return dr.select(used, dr.lerp(a, b, sources.f), 0.0)


@dataclass(frozen=True, eq=False)
class Integration:
    """The integration samples after refinement: ``values`` (L_scat of every
    integration sample, 0 elsewhere), ``flags`` (which samples are), their
    ``count`` and the march steps they took (``steps``: a one-entry array
    on the device, read once by the caller), and the rounds it took."""
    values: mi.Color3f = field(repr=False)
    flags: mi.Bool = field(repr=False)
    count: int
    steps: mi.UInt32 = field(repr=False)
    rounds: int


def neighbour_intervals(samples: EpipolarSamples, index: mi.UInt32):
    """``(lo, hi, inner)`` of the sorted integration samples ``index``: each
    pair of neighbours, and whether the interval between them has inner
    samples of one run (``hi > lo + 1`` and ``lo + 1`` used: run ends are
    integration samples, so such a pair never crosses a slice or a gap)."""
    n = dr.width(index)
    if n < 2:
        empty = dr.zeros(mi.UInt32, 0)
        return empty, empty, dr.zeros(mi.Bool, 0)
    i = dr.arange(mi.UInt32, n - 1)
    lo = dr.gather(mi.UInt32, index, i)
    hi = dr.gather(mi.UInt32, index, i + 1)
    return lo, hi, _has_inner(samples, lo, hi)


def _has_inner(samples: EpipolarSamples, lo, hi) -> mi.Bool:
    return (hi > lo + 1) & dr.gather(mi.Bool, samples.used, lo + 1)


def split_intervals(samples: EpipolarSamples, lo, hi, inner, values: mi.Color3f,
                    peak: mi.Float, threshold: float) -> mi.Bool:
    """Which intervals ``(lo, hi)`` get their midpoint integrated: those with
    inner samples whose end results differ by more than ``threshold``
    relative to the larger, floored at 1e-3 of ``peak``, the brightest
    integration sample of the slice so far (module docstring)."""
    va = luminance(dr.gather(mi.Color3f, values, lo))
    vb = luminance(dr.gather(mi.Color3f, values, hi))
    vmax = dr.maximum(va, vb)
    floor = 1e-3 * dr.gather(mi.Float, peak, dr.gather(mi.UInt32, samples.slice, lo))
    return inner & (dr.abs(va - vb) > threshold * dr.maximum(vmax, floor))


def halves(lo, hi, split: mi.UInt32):
    """The intervals ``split`` of ``(lo, hi)`` (evaluated), their midpoints
    and their two halves ``(lo, mid)``, ``(mid, hi)``, interleaved."""
    def of(i):
        a, b = dr.gather(mi.UInt32, lo, i), dr.gather(mi.UInt32, hi, i)
        return a, b, (a + b) >> 1
    _, _, mid = of(split)
    j = dr.arange(mi.UInt32, 2 * dr.width(split))
    a, b, m = of(dr.gather(mi.UInt32, split, j >> 1))
    right = (j & 1) == 1
    return mid, dr.select(right, m, a), dr.select(right, b, m)


def integrate_refined(samples: EpipolarSamples, flags: mi.Bool, integrate, threshold: float,
                      refine: bool, max_rounds: int = 64) -> Integration:
    """Integrate the samples ``flags`` by ``integrate(lanes) -> (L, steps)``
    and, with ``refine`` (the ``visibility`` criterion), the midpoint of
    every interval between neighbouring integration samples whose results
    differ (:func:`split_intervals`), round after round until none does or
    the interval has no inner sample.

    An interval that does not split keeps its ends' values and a floor
    that only grows, so it never splits later: each round checks the
    halves of the last round's splits alone -- the samples integrated are
    those of checking every interval every round
    (:func:`visibility_refinement_reference`).  Each round is one
    integration kernel (writing the values, the flags, the slices' peaks
    and the step count on the device) and one split test whose count,
    read back, sizes the next round."""
    values = dr.zeros(mi.Color3f, samples.size)
    flags = mi.Bool(flags)
    peak = dr.zeros(mi.Float, samples.slices.count)
    steps = dr.zeros(mi.UInt32, 1)
    index = dr.compress(flags)
    lo, hi, inner = neighbour_intervals(samples, index) if refine else (None, None, None)
    count = rounds = 0
    while dr.width(index) and rounds < max_rounds:
        n = dr.width(index)
        lanes = two_or_more(index)
        L, st = integrate(lanes)
        dr.scatter(values, L, lanes)
        # the repeated lane of a one-entry list counts once
        once = dr.arange(mi.UInt32, dr.width(lanes)) < scalar_u32(n)
        dr.scatter_reduce(dr.ReduceOp.Add, steps, st, mi.UInt32(0), once)
        count, rounds = count + n, rounds + 1
        if not refine:
            break
        if rounds > 1:
            dr.scatter(flags, True, lanes)
        dr.scatter_reduce(dr.ReduceOp.Max, peak, luminance(L),
                          dr.gather(mi.UInt32, samples.slice, lanes))
        test = split_intervals(samples, lo, hi, inner, values, peak, threshold)
        dr.schedule(lo, hi)               # evaluated with the test, gathered from below
        split = dr.compress(test)
        if not dr.width(split):
            break
        index, lo, hi = halves(lo, hi, split)
        inner = _has_inner(samples, lo, hi)
    return Integration(values=values, flags=flags, count=count, steps=steps, rounds=rounds)


def visibility_refinement_reference(used: np.ndarray, flags: np.ndarray, value, threshold: float,
                                    max_rounds: int = 64) -> np.ndarray:
    """NumPy twin of :func:`integrate_refined`'s choice, by the rule as
    stated: every round, every interval between neighbouring integration
    samples of a row with an inner used sample whose ends' results
    (``value``: (S, M) luminances) differ by more than ``threshold`` of the
    larger, floored at 1e-3 of the row's brightest integration sample, gets
    its midpoint; until a round adds none.  Returns the final (S, M) flags."""
    flags = flags.copy()
    value = np.asarray(value, dtype=np.float32)
    for _ in range(max_rounds - 1):
        new = np.zeros_like(flags)
        for k in range(flags.shape[0]):
            pos = np.flatnonzero(flags[k])
            peak = np.float32(max([value[k, p] for p in pos], default=0.0))
            for a, b in zip(pos[:-1], pos[1:]):
                if b <= a + 1 or not used[k, a + 1]:
                    continue
                va, vb = value[k, a], value[k, b]
                limit = np.float32(threshold) * max(va, vb, np.float32(1e-3) * peak)
                if abs(va - vb) > limit:
                    new[k, (a + b) // 2] = True
        if not new.any():
            break
        flags |= new
    return flags
