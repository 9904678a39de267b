"""The exact visibility sum of a rectified shadow map (``fourier_filter``'s
oracle and fall-back, beyond Klehm et al. 2014).

For a query (view ray β_q, depth D_q in its row) the weighted average
visibility the filter approximates is

    V̄_q = Σ_g w_g(β_q) V(g, β_q) clip(D_q − g, 0, 1) / Σ_g w_g(β_q) clip(D_q − g, 0, 1),

``V(g, β) = 1`` iff ``β ≤ β_b(g)`` (the step of Eq. 5) and ``w_g(β)`` the
query's own weights ``L(γ_g) K(γ_g, β)`` (the reference kernel of
:func:`~integrators.fourier.references.row_kernel` at the query's own β:
no reference ray, no series).  Summed here directly, one loop over the
covered texels per query: no ringing, no leak, no weighting error, at a
cost of ``D_q`` gathers per query where the filter needs ``2 M`` (and one
prefilter of ``n d M`` per reference ray).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.opaque import scalar, scalar_u32
from ..epipolar.light_models import light_model


def texel_kernel(params, queries, rays, sigma_t: float):
    """``K(texel, tan(β/2))``: a function of (flat texel index, per-lane
    tan(β/2)) giving the kernel of :func:`~integrators.fourier.references.row_kernel`
    for any β (one value per lane): the light model's ``ray_kernel``, or a
    projective map's texel integral (Eq. 12; σt a kernel parameter)."""
    return (rays.own_kernel(sigma_t)
            or light_model(params).ray_kernel(params, queries, rays, sigma_t))


def exact_average(params, queries, rays, beta_b, cover, L, sigma_t: float,
                  active=True, recurrence: bool = True, tail=None, idx=None) -> mi.Float:
    """V̄_q of every query in ``active`` (module doc; 1 elsewhere and where
    the covered weight is 0): :func:`exact_sums`' ratio."""
    num, den = exact_sums(params, queries, rays, beta_b, cover, L, sigma_t, active,
                          recurrence, tail, idx)
    return dr.select(den > 0.0, num / den, 1.0)


def exact_sums(params, queries, rays, beta_b, cover, L, sigma_t: float,
               active=True, recurrence: bool = True, tail=None, idx=None):
    """(Σ_g w_g V cover, Σ_g w_g cover) per query in ``active`` (module doc;
    0 elsewhere): the shadowed and the unshadowed sum with the query's own
    weights; ``L`` a list of per-light-ray factors (colour channels over one
    kernel): lists of both sums, one pass.  ``beta_b``, ``L``: (n·d) per light ray;
    ``cover``: :class:`~integrators.fourier.rectified_map.Coverage`.  Equal light
    rays of a directional light take the kernel by recurrence
    (e^{-c γ_{g+1}} = e^{-c γ_g} e^{-c Δγ}; ``recurrence=False``: per texel,
    as the others).  ``tail``: the runs behind each query's last visibility
    change traced on its own ray
    (:func:`~integrators.fourier.tail.tail_visibility`), which replace the
    map's visibility there.  ``idx``: only these queries (the result has
    one value per entry of ``idx``; ``active`` then refers to them).
    σt and ``d`` enter the kernels as parameters (opaque), not literals."""
    d = scalar_u32(rays.d)
    sigma = scalar(sigma_t)
    row, beta, texel, frac = queries.row, queries.beta, cover.texel, cover.frac
    # the traced runs' changes, of every channel, at all traced queries in
    # one kernel (read at ``idx``) where the trace kept its queries
    frame_tail = (row, beta, texel, frac, tail) if tail is not None and tail.idx is not None \
        else None
    if idx is not None:
        row, beta, texel, frac = (dr.gather(type(x), x, idx) for x in (row, beta, texel, frac))
        tail = None if tail is None or frame_tail is not None else tail.subset(idx)
    count = dr.width(beta)
    first = row * d
    k0 = texel - first                        # last (partly) covered texel
    tan = dr.tan(0.5 * beta)
    active = mi.Bool(active)
    geometric = recurrence and light_model(params).kernel_recurrence and rays.equal_widths
    if geometric:
        c = sigma * tan
        k_first = dr.exp(-c * rays.start(row))
        step = dr.exp(-c * dr.gather(mi.Float, rays.delta_gamma, row))
        kernel = None
    else:
        kernel = texel_kernel(params, queries, rays, sigma_t)
        k_first = step = dr.zeros(mi.Float, count)

    Ls = L if isinstance(L, list) else [L]
    C = len(Ls)

    def cond(g, k, *sums):
        return active & (g <= k0)

    def body(g, k, *sums):
        t = first + g
        K = k if geometric else kernel(t, tan)
        K = dr.select(g == k0, K * frac, K)
        lit = beta <= dr.gather(mi.Float, beta_b, t)
        out = []
        for c in range(C):
            w = dr.gather(mi.Float, Ls[c], t) * K
            out += [sums[c] + dr.select(lit, w, 0.0), sums[C + c] + w]
        return (g + 1, k * step, *out[0::2], *out[1::2])

    zeros = [dr.zeros(mi.Float, count) for _ in range(2 * C)]
    state = dr.while_loop((dr.zeros(mi.UInt32, count), mi.Float(k_first), *zeros), cond, body,
                          labels=("g", "k") + tuple(f"num{c}" for c in range(C))
                          + tuple(f"den{c}" for c in range(C)), label="fourier_exact_sums")
    num, den = list(state[2:2 + C]), list(state[2 + C:])
    if frame_tail is not None:
        deltas = _tail_deltas(params, queries, rays, beta_b, Ls, sigma, geometric, kernel,
                              *frame_tail)
        at = dr.arange(mi.UInt32, count) if idx is None else idx
        Q = scalar_u32(queries.count)
        for c in range(C):
            off = at if c == 0 else scalar_u32(c) * Q + at
            num[c] += dr.select(active, dr.gather(mi.Float, deltas, off), 0.0)
    elif tail is not None:     # the traced end runs instead of the map there
        kernel_at = _run_kernel(rays, row, beta, sigma, geometric, kernel)
        for c in range(C):
            delta = tail.delta(row, texel, frac, beta, beta_b, rays.d,
                               lambda t, q: dr.gather(mi.Float, Ls[c], t) * kernel_at(t, q))
            num[c] += dr.select(active, delta, 0.0)
    return (num, den) if isinstance(L, list) else (num[0], den[0])


def _tail_deltas(params, queries, rays, beta_b, Ls, sigma, geometric: bool, kernel,
                 row, beta, texel, frac, tail) -> mi.Float:
    """(C·Q) the traced end runs' change of each channel's shadowed sum
    (:meth:`~integrators.fourier.tail.TailVisibility.delta`, channel c at
    c·Q + q) of every query, in one kernel; each bit for bit
    :func:`exact_sums`' own per query."""
    kernel_at = _run_kernel(rays, row, beta, sigma, geometric, kernel)

    def weight(t, q, c=None):
        L_t = dr.gather(mi.Float, Ls[-1], t)
        if c is not None:
            for ch in reversed(range(len(Ls) - 1)):
                L_t = dr.select(c == ch, dr.gather(mi.Float, Ls[ch], t), L_t)
        return L_t * kernel_at(t, q)
    return tail.delta(row, texel, frac, beta, beta_b, rays.d,
                      weight if len(Ls) > 1 else (lambda t, q: weight(t, q)), len(Ls))


def _run_kernel(rays, row, beta, sigma, geometric: bool, kernel):
    """K(t, q) of light ray ``t`` at query ``q`` (its β read where used):
    the texel ``kernel``, or the directional light's e^{-σt γ_t tan(β/2)}
    at the ray's start where ``geometric`` -- the traced end runs' weights
    (:meth:`~integrators.fourier.tail.TailVisibility.delta`)."""
    d = scalar_u32(rays.d)

    def kernel_at(t, q):
        tq = dr.tan(0.5 * dr.gather(mi.Float, beta, q))    # tan, where read (no kernel)
        if not geometric:
            return kernel(t, tq)
        r = dr.gather(mi.UInt32, row, q)
        gamma = rays.start(r) + mi.Float(t - r * d) * dr.gather(mi.Float, rays.delta_gamma, r)
        return dr.exp(-sigma * tq * gamma)
    return kernel_at
