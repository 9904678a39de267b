"""The epipole ring (Baran et al. 2010 §6): samples near ``±w_l`` and peak
rays marched by brute force with exact visibility, and the re-march of
samples where neighbouring methods disagree.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify.coords import direction_to_alpha_beta

from ..core.capture import CameraCapture
from ..core.light_transport import scalar
from ..core.marching import lit_spacing, march, march_bisected
from ..core.opaque import scalar_u32
from .queries import EpipolarQueries


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
    ``bisections`` bisections (:func:`~integrators.core.marching.march_bisected`;
    0: the midpoint rule of :func:`~integrators.core.marching.march`).  The
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
    # one march, the steps per ray (core.marching.step_count)
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
    # the largest answer is the largest of the samples' largest (evaluated
    # with them: no kernel of its own)
    return dr.compress((shares == 2) & apart(hi, lo, hi, tolerance, peak))


def apart(hi, lo, y, tolerance: float, peak=None) -> mi.Bool:
    """:func:`disagreeing`'s test of two answers whose channel sums are
    ``hi ≥ lo``, of the frame's answers' channel sums ``y`` (or of arrays
    with the same largest value; ``peak``: as there)."""
    peak = dr.max(y) if peak is None else dr.maximum(dr.max(y), peak)
    spread = hi - lo
    return (spread > tolerance * hi) & (spread > tolerance * 1e-2 * peak)


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
