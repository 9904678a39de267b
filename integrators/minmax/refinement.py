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

from ..core.opaque import mean, scalar_i32, scalar_u32
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


def slice_peak(samples: EpipolarSamples, y: mi.Float, active: mi.Bool) -> mi.Float:
    """Per sample: the largest ``y`` of the ``active`` samples of its slice."""
    peak = dr.zeros(mi.Float, samples.slices.count)
    dr.scatter_reduce(dr.ReduceOp.Max, peak, y, samples.slice, active)
    return dr.gather(mi.Float, peak, samples.slice)


def visibility_midpoints(samples: EpipolarSamples, flags: mi.Bool, values: mi.Color3f,
                         threshold: float) -> mi.Bool:
    """New integration samples: the midpoint of every interval between
    neighbouring integration samples whose results differ by more than
    ``threshold`` relative to the larger (floored at 1e-3 of the brightest
    integration sample of the slice, so that darkness does not refine: a
    per-slice floor keeps each slice's samples its own business, as the
    per-slice partial renders of :mod:`.slice_subset` need)."""
    src = interpolation_sources(samples, flags)
    s = dr.arange(mi.UInt32, samples.size)
    # each interval once: at its first inner sample
    inner = samples.used & ~flags & (src.hi > src.lo) & (src.lo + 1 == s)
    va = luminance(dr.gather(mi.Color3f, values, src.lo))
    vb = luminance(dr.gather(mi.Color3f, values, src.hi))
    vmax = dr.maximum(va, vb)
    floor = 1e-3 * slice_peak(samples, luminance(values), flags)
    split = inner & (dr.abs(va - vb) > threshold * dr.maximum(vmax, floor))
    mid = (src.lo + src.hi) // 2
    out = dr.zeros(mi.Bool, samples.size)
    dr.scatter(out, True, mid, split)
    return out & ~flags
