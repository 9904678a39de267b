"""A query's unshadowed sum summed directly over its light rays: the check
of the separated kernel's sum where its error is amplified beyond the
tolerance it was separated to (Baran et al. 2010 §6, DESIGN §3).

The separated kernel K̃ = Σ_i a_i(γ) b_i(β) bounds each view ray's error
relative to ∫K dγ (:func:`~integrators.epipolar.kernel.separation.separate_channel`),
and its sum check bounds the rows' sums relative to the frame's largest
(:func:`~integrators.epipolar.kernel.separation.checked_tolerances`).
Neither bounds a query's own sum U = Σ_γ L(γ) K(γ, β) relative to
itself: where the light-side factor L grows along the slice as fast as
the kernel decays (a thick fog seen toward the light, whose light-side
path shrinks as the camera-side path grows), U is carried by light rays at
which K is e^{-20…-30} of its largest value, below any absolute error of
K̃, and the separated U is wrong by any factor.  The direct sum costs one
light ray per step of the query's own ray (a geometric recurrence for a
directional light's equal rays), no separation.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import scalar, scalar_u32
from .last_interval import LastInterval, factor_arrays
from .queries import EpipolarQueries


#: the kernel depth σt γ tan(β/2) at a query's end below which its
#: separated sum is not checked: K stays above e^{-KERNEL_DEPTH} on every
#: light ray it covers, where the separated kernel's absolute error is
#: a small part of each term (the sums off by more than 1e-3 of
#: themselves on held-out seed 2016, its box 1x-3x as large, all end at a
#: depth of 11.7 or more)
KERNEL_DEPTH = 7.0


@dataclass(eq=False)
class DirectSums:
    """Per query: the direct unshadowed sum ``U`` (:func:`direct_unshadowed`)
    where ``checked``, 0 elsewhere."""
    U: mi.Color3f
    checked: mi.Bool


def direct_unshadowed(queries: EpipolarQueries, rays, L, last: LastInterval,
                      sigma_t) -> DirectSums:
    """U = Σ_{g<k0} L_g K(γ_g, β) + f·L_{k0} K(γ_{k0}, β) per query and
    colour channel, K = e^{-σt γ tan(β/2)} at each light ray's start γ_g
    (the directional light's kernel as the sweep samples it,
    :class:`~integrators.epipolar.kernel.separation.DirectionalSeparation`),
    the last light ray k0 covered to the fraction f as the sweep's lerp
    covers it (``last``, :func:`~integrators.epipolar.last_interval.last_leaf`):
    the sweep's unshadowed sum (:func:`~integrators.epipolar.last_interval.sweep_magnitude`'s
    U) without the separation.  ``rays``: equally wide light rays
    (``rays.equal_widths``; rows from ``rays.start``, widths
    ``rays.delta_gamma``); L (n|1, d) or (n|1, d, C); ``sigma_t`` per
    channel (grey: one kernel for every channel of L).  Only the queries
    whose kernel falls below e^{-KERNEL_DEPTH} on their own ray (σt the
    largest channel's, γ their end) are summed (``checked``); the others
    take no step.  One symbolic loop
    (it joins the kernel that evaluates its result); σt and d are kernel
    parameters, not literals."""
    sigma_t = np.atleast_1d(np.asarray(sigma_t, np.float64))
    l, nL, d, CL, _ = factor_arrays(L, False)
    grey = bool(np.all(sigma_t == sigma_t[0]))
    C = 1 if grey and CL == 1 else 3
    if not queries.count:
        return DirectSums(dr.zeros(mi.Color3f, 0), dr.zeros(mi.Bool, 0))
    row, k0, f = queries.row, last.k0, last.f
    d_o = scalar_u32(d)
    base = row * d_o if nL > 1 else dr.zeros(mi.UInt32, queries.count)
    tan = dr.tan(0.5 * queries.beta)
    start, delta = rays.start(row), dr.gather(mi.Float, rays.delta_gamma, row)
    kernels = 1 if grey else C
    sig = [scalar(float(sigma_t[min(c, len(sigma_t) - 1)])) for c in range(kernels)]
    k_first = [dr.exp(-s * tan * start) for s in sig]
    steps = [dr.exp(-s * tan * delta) for s in sig]
    CL_o = scalar_u32(CL)
    end = start + (mi.Float(k0) + f) * delta
    checked = scalar(float(np.max(sigma_t))) * tan * end > scalar(KERNEL_DEPTH)

    def cond(g, *state):
        return checked & (g <= k0)

    def body(g, *state):
        ks, sums = state[:kernels], state[kernels:]
        t = (base + g) * CL_o
        last_ray = g == k0
        out = []
        for c in range(C):
            K = ks[min(c, kernels - 1)]
            w = dr.gather(mi.Float, l, t + min(c, CL - 1)) * dr.select(last_ray, K * f, K)
            out.append(sums[c] + w)
        return (g + 1, *[k * s for k, s in zip(ks, steps)], *out)

    state = dr.while_loop((dr.zeros(mi.UInt32, queries.count), *[mi.Float(k) for k in k_first],
                           *[dr.zeros(mi.Float, queries.count) for _ in range(C)]),
                          cond, body, label="direct_unshadowed")
    U = list(state[1 + kernels:])
    return DirectSums(mi.Color3f(*(U * 3 if C == 1 else U)), checked)
