"""Several filters of the same rows at once: the reference rays of a row
(``fourier_filter``; :mod:`integrators.fourier.references`).

Each reference ray ``k`` weights the series texels of the rectified map
by ``L · K_k`` and filters them (Klehm et al. 2014, §3.2-§3.3); a query
mixes the weighted sums of its two nearest rays.  Instead of one filter
and one pass over every query per ray, the rays' filters are *layers* of
one stacked filter (rows ``l·n_f + row``: the depths and their region
bounds are the rows' own, the weights the ray's), made in one kernel, and
each query reads its two layers alone: two lookups per query whatever the
number of rays.  Layers are batched so that one batch's textures stay
within ``FILTER_BYTES``.  Each layer is bit for bit the filter of its ray
alone (:func:`~integrators.fourier.prefilter.prefix_filter`'s ``layers``).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.opaque import Divisor, opaque_scalar, scalar_u32, two_or_more
from .prefilter import FilteredBasis, filtered_visibility
from .rectified_map import (RectifiedShadowMap, kernel_weights, near_step_weight, prefilter_rows,
                            stacked_class_sums)
from .references import interpolated_sum, row_kernel


#: most bytes of filtered-basis textures (B̄, W) of the layers filtered
#: together
FILTER_BYTES = 1 << 30


def layer_batches(smap: RectifiedShadowMap, M: int, count: int) -> list:
    """(first layer, layers) of each batch of ``count`` layers whose
    textures (``M`` coefficients and a weight sum per texel of the
    filtered rows) fit in ``FILTER_BYTES``."""
    if smap.n_filtered == 0:
        return []
    per_layer = dr.width(two_or_more(smap.rows)) * smap.d * (M + 1) * 4
    per = max(1, FILTER_BYTES // per_layer)
    return [(first, min(per, count - first)) for first in range(0, count, per)]


def prefilter_layers(smap: RectifiedShadowMap, L, K, counts, first: int, layers: int,
                     opt, per: int = 0) -> FilteredBasis:
    """The filters of layers ``first .. first + layers − 1``: layer ``l``
    weights texel t by ``L[t] · K[l·n·d + t]`` (``K``: the layers' kernels
    one after another, :func:`~integrators.fourier.references.row_kernel`;
    ``L`` a list of colour channels over ``per`` kernels each: layer
    ``c·per + k`` weights by channel c's L and kernel k,
    :func:`~integrators.fourier.rectified_map.kernel_weights`) and filters
    only the rows that have it (``counts[row] > k``: the rows' layer
    counts)."""
    weights = kernel_weights(L, K, dr.width(smap.lit), first, per)
    first_o = opaque_scalar(mi.UInt32, first)
    if isinstance(L, list) and len(L) > 1:
        per_o = Divisor(per)
        ray = (lambda l: per_o.divmod(l + first_o)[1])
    else:
        ray = (lambda l: l + first_o)
    return prefilter_rows(smap, weights if layers > 1 else (lambda texel: weights(0, texel)),
                          opt, layers,
                          rows=lambda l, src: dr.gather(mi.UInt32, counts, src) > ray(l))


def layer_visibility(smap: RectifiedShadowMap, fb: FilteredBasis, first: int, queries, cover,
                     opt, clamp: bool, layer: mi.UInt32, active, band: float = 0.0):
    """:func:`~integrators.fourier.rectified_map.series_visibility` of each
    query through the filter of its ``layer`` (a batch of
    :func:`prefilter_layers` from ``first``); visibility 1 (drop 0) where
    not ``active`` or its row has no series texels."""
    on = dr.gather(mi.Bool, smap.filtered, queries.row) & active
    frow = dr.select(on, dr.gather(mi.UInt32, smap.frow, queries.row), 0)
    row = dr.select(on, (layer - opaque_scalar(mi.UInt32, first))
                    * scalar_u32(fb.layer_rows or fb.n_rows) + frow, 0)
    return filtered_visibility(fb, row, cover.j, smap.z_r, clamp, opt.exact_bounds, on, band)


def layered_average(params, queries, rays, smap: RectifiedShadowMap, cover, L, sigma_t: float,
                    refs, beta_b, tail, kernels: dict, opt, clamp: bool, band: float, stage):
    """(V̄, S, P, near) of ``fourier_filter``'s interpolated reference rays
    (``refs``, :func:`~integrators.fourier.references.reference_rays`): the
    weighted average visibility of each query with the weights of its mix
    of its two nearest rays, and its shadowed, unshadowed and near-step
    weight sums (``band`` > 0: the near-step band,
    :func:`~integrators.fourier.rectified_map.near_step_weight`; 0: none).
    The rays' kernels (kept in ``kernels`` for the other channels of this
    σt), class sums and end-run corrections (``tail``) are made together
    once; the filters as layers, in batches (module doc).  ``L`` a list of
    colour channels' factors over the same kernels: every channel's rays
    are layers of the same filter (layer ``c·count + k``), and the result
    is a list of the four per channel, each bit for bit its channel's
    alone.  ``stage(name)``: the integrator's timed stages ("prefilter",
    "evaluate")."""
    if ("kernels", sigma_t) not in kernels:
        K = row_kernel(params, queries, rays, sigma_t, refs, refs.count)
        dr.eval(K)
        kernels["kernels", sigma_t] = K
    K = kernels["kernels", sigma_t]
    channels = len(L) if isinstance(L, list) else 1
    count = channels * refs.count
    size = dr.width(smap.lit)
    # each ray's weights multiplied where they are read: by the filter,
    # the class sums and the tail correction
    sums = stacked_class_sums(smap, cover, L, K, count, refs.count)
    corrections = None
    if tail is not None:     # every layer's at layer·Q + query, one kernel
        corrections = tail.correction(queries, cover, beta_b,
                                      kernel_weights(L, K, size, 0, refs.count), count)
        dr.eval(corrections)
    Q_o = scalar_u32(queries.count)
    ones = dr.full(mi.Float, 1.0, queries.count)

    def layer_sums(first, layers):
        fb = None
        with stage("prefilter") as keep:
            if smap.n_filtered:
                fb = prefilter_layers(smap, L, K, refs.counts, first, layers, opt, refs.count)
                keep.extend([fb.B_bar, fb.W])

        def of(k, use):
            V, drop = ones, dr.zeros(mi.Float, queries.count)
            if fb is not None and band > 0.0:
                V, drop = layer_visibility(smap, fb, first, queries, cover, opt, clamp, k, use,
                                           band)
            elif fb is not None:
                V = layer_visibility(smap, fb, first, queries, cover, opt, clamp, k, use)
            lit, series, P = sums.at(k, use)
            S = lit + series * V
            if corrections is not None:
                S += dr.gather(mi.Float, corrections,
                               k * Q_o + dr.arange(mi.UInt32, queries.count), use)
            return S, P, near_step_weight(series, drop)
        return of

    batches = layer_batches(smap, opt.M, count) or [(0, count)]
    out = interpolated_sum(refs, batches, layer_sums, lambda: stage("evaluate"), channels)
    out = [(dr.select(P > 0.0, S / P, 1.0), S, P, near)
           for S, P, near in (out if channels > 1 else [out])]
    return out if isinstance(L, list) else out[0]
