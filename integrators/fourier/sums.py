"""The rectified sums of the filter: kernel parts per channel, the
unshadowed band, the reference kernel and the near visibility
(Klehm et al. 2014 §4).
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import Divisor, scalar_u32, uints
from ..epipolar.direct_sum import direct_unshadowed
from ..epipolar.kernel.separation import nonzero_terms
from ..epipolar.last_interval import (LastInterval, SweepSums, sweep_magnitude, sweep_sums,
                                      unresolved_samples)
from ..epipolar.light_rays.directional import LightRays
from ..epipolar.queries import frame_memo
from .rectified_map import Coverage, query_beta_range, reference_angle
from .references import row_kernel


@dataclass(eq=False)
class RectifiedSums:
    """Per query and colour channel (1 or 3): U = Σ_γ L K cover (no
    blockers) and the effective average visibility V̄ of the blockers;
    ``colour``: a point/spot light's colour when L is grey
    (:func:`~integrators.epipolar.local_light_factor.light_ray_factor`), else None."""
    rays: LightRays
    beta_b: mi.Float      # (n·d) blocker angle per light ray
    U: list
    V: list
    colour: mi.Color3f | None = None

    def integral(self) -> mi.Color3f:
        """Σ_γ L K V cover = U · V̄ as a Color3f."""
        values = [u * v for u, v in zip(self.U, self.V)]
        return mi.Color3f(*(values * 3 if len(values) == 1 else values))


def _channel_count(t: mi.TensorXf, axis: int) -> int:
    return t.shape[axis] if len(t.shape) > axis else 1


def channels(L: mi.TensorXf, A: mi.TensorXf | None, sigma_t) -> int:
    """Colour channels the filters run for: 3 if the per-light-ray factor
    L (n, d[, 3]) or the kernel A (n, d, C, N) is coloured (coloured σt, or
    a textured spot light's colour per light ray), else 1; without a
    separated kernel (A None, the direct sum) σt says whether it is coloured."""
    kernel = A.shape[2] if A is not None else (1 if np.all(sigma_t == sigma_t[0]) else 3)
    return max(_channel_count(L, 2), kernel)


def used_components(queries, B) -> np.ndarray:
    """(C, N) whether some query's B of channel c, component i is not 0
    (the components a channel's sums need), for every channel in one
    read, once per frame's queries and B: the flags the kernel that wrote
    B made (:func:`~integrators.epipolar.kernel.separation.nonzero_terms`),
    else in one kernel of their own."""
    def make():
        C, N = B.shape[2], B.shape[3]
        flags = nonzero_terms(queries, B)
        if flags is not None:
            return np.asarray(flags).reshape(C, N)
        term, q = Divisor(queries.count).divmod(dr.arange(mi.UInt32, C * N * queries.count))
        b_all = dr.gather(mi.Float, B.array, queries.slot_of(q) * scalar_u32(C * N) + term)
        used = dr.zeros(mi.UInt32, C * N)
        dr.scatter_reduce(dr.ReduceOp.Max, used, mi.UInt32(b_all != 0.0), term)
        return np.asarray(used).reshape(C, N)
    return frame_memo(queries, ("used_components", B), make)


class KernelParts:
    """One colour channel of the separated integrand: L (n·d) per light ray,
    A_n (n·d) per light ray (directional: at its start; point/spot: its
    interval's mean), B_n (Q) at every query's β."""

    def __init__(self, L, A, B, terms=None):
        self.L, self.A, self.B = L, A, B
        #: (A array, B array, stride): where the used components (``used``)
        #: lie in A (n·d·C·N) and B (n·r·C·N) -- for sums over all of them
        #: in kernels that do not depend on their count
        self.terms = terms
        #: the used components' offsets in A and B (c·N + i), on the host
        self.used = []
        #: the channel the parts were taken from and the sweep's sums of the
        #: same A and L (:func:`~integrators.epipolar.last_interval.sweep_sums`;
        #: None: none), which :func:`unshadowed_sums` reads where given
        self.channel = 0
        self.swept = None

    @staticmethod
    def of(queries, rays, L, A, B, c: int, swept: SweepSums | None = None) -> "KernelParts":
        """Channel ``c`` of L and of A, B (a grey one serves every channel);
        the rank's stride and the component's offset are kernel parameters,
        so every component (of any rank) reads with the same kernels;
        ``swept``: the sweep's sums of these A and L, if made
        (:func:`unresolved_by_separation`)."""
        lanes = dr.arange(mi.UInt32, queries.n * rays.d)
        CL = _channel_count(L, 2)
        channel = c
        L_c = dr.gather(mi.Float, L.array, lanes * CL + min(c, CL - 1))
        if A is None or not queries.count:    # the direct sum: no separated kernel
            return KernelParts(L_c, [], [])
        C, N = A.shape[2], A.shape[3]
        c = min(c, C - 1)
        stride = scalar_u32(C * N)
        used = used_components(queries, B)[c]
        A_c, B_c = [], []
        for i in range(N):
            if not used[i]:             # unused component of this channel
                continue
            offset = scalar_u32(c * N + i)
            b = dr.gather(mi.Float, B.array, queries.slot * stride + offset)
            A_c.append(dr.gather(mi.Float, A.array, lanes * stride + offset))
            B_c.append(b)
        parts = KernelParts(L_c, A_c, B_c, (A.array, B.array, stride))
        parts.used = [c * N + i for i in range(N) if used[i]]
        parts.channel, parts.swept = channel, swept
        return parts

    def unshadowed(self, cover: Coverage, queries) -> mi.Float:
        """U(β) = Σ_n B_n(β) Σ_γ L A_n cover: the query's sum without
        blockers (the closed form of unblocked rows):
        :func:`unshadowed_sums` of this channel alone."""
        return unshadowed_sums([self], cover, queries)[0]


def unshadowed_sums(parts: list, cover: Coverage, queries) -> list:
    """:meth:`KernelParts.unshadowed` of each channel's parts (one
    separated kernel A, B; their L apart): every channel's components' L
    A_n stacked and prefix-summed at once, and each channel's U summed over
    its components in a loop (``queries``: theirs) -- two kernels, the same
    for any rank and channel count; the sums of adding one component after
    another (a stacked prefix sum sums each row's block as a lone one
    does), each U bit for bit its channel's alone.  Where the unresolved
    test's sweep summed the same A and L, its prefix sums are read instead
    (:func:`_swept_sums`: no kernel of their own, the same U)."""
    out = [dr.zeros(mi.Float, dr.width(cover.frac)) for _ in parts]
    live = [c for c, p in enumerate(parts) if p.A]
    if not live:
        return out
    swept = _swept_sums(parts, live, cover, queries)
    if swept is not None:
        return swept
    A, B, stride = parts[live[0]].terms
    first, offsets, owner = {}, [], []
    for c in live:
        first[c] = len(offsets)
        offsets += parts[c].used
        owner += [c] * len(parts[c].used)
    offsets_o, owner_o = uints(offsets), uints(owner)
    count = len(offsets)
    size = dr.width(parts[live[0]].L)
    per = Divisor(size)
    comp, t = per.divmod(dr.arange(mi.UInt32, count * size))
    if len(live) == 1:
        L_t = dr.gather(mi.Float, parts[live[0]].L, t)
    else:
        ch = dr.gather(mi.UInt32, owner_o, comp)
        L_t = dr.gather(mi.Float, parts[live[-1]].L, t)
        for c in reversed(live[:-1]):
            L_t = dr.select(ch == c, dr.gather(mi.Float, parts[c].L, t), L_t)
    stack = L_t * dr.gather(mi.Float, A, t * stride + dr.gather(mi.UInt32, offsets_o, comp))
    dr.eval(stack)
    P = dr.block_prefix_sum(stack, cover.d, exclusive=True)
    slot = queries.slot * stride
    for c in live:
        base, n_c = scalar_u32(first[c]), scalar_u32(len(parts[c].used))

        def body(i, U, base=base):
            b = dr.gather(mi.Float, B, slot + dr.gather(mi.UInt32, offsets_o, base + i))
            return i + 1, U + b * cover.read(P, stack, (base + i) * per.d)
        _, out[c] = dr.while_loop(state=(mi.UInt32(0), out[c]),
                                  cond=lambda i, U, n_c=n_c: i < n_c, body=body)
    return out


def _swept_sums(parts: list, live: list, cover: Coverage, queries) -> list | None:
    """:func:`unshadowed_sums` from the prefix sums of A L that the
    unresolved test's sweep made of the same A and L (the parts'
    ``swept``, :func:`~integrators.epipolar.last_interval.sweep_sums`: the
    same terms summed in the same order, no kernel of their own), each U
    bit for bit the stack's; None where the parts have none."""
    sums = parts[live[0]].swept
    if sums is None or sums.w != cover.d + 1 or any(parts[c].swept is not sums for c in live):
        return None
    B, stride = parts[live[0]].terms[1], parts[live[0]].terms[2]
    N = sums.N
    # per used component: its offset in B and its block in the sweep's layout
    offsets, blocks = [], []
    for c in live:
        p = parts[c]
        offsets += p.used
        blocks += [p.channel * N + (off % N) for off in p.used]
    offsets_o, blocks_o = uints(offsets), uints(blocks)
    k0 = covered_interval(queries, cover).k0
    at0 = queries.row * scalar_u32(sums.C * sums.N)
    w = scalar_u32(sums.w)
    slot = queries.slot * stride
    out = [dr.zeros(mi.Float, dr.width(cover.frac)) for _ in parts]
    first = 0
    for c in live:
        base, n_c = scalar_u32(first), scalar_u32(len(parts[c].used))
        first += len(parts[c].used)

        def body(i, U, base=base):
            b = dr.gather(mi.Float, B, slot + dr.gather(mi.UInt32, offsets_o, base + i))
            at = (at0 + dr.gather(mi.UInt32, blocks_o, base + i)) * w + k0
            return i + 1, U + b * (dr.gather(mi.Float, sums.cum, at)
                                   + cover.frac * dr.gather(mi.Float, sums.v, at))
        _, out[c] = dr.while_loop(state=(mi.UInt32(0), out[c]),
                                  cond=lambda i, U, n_c=n_c: i < n_c, body=body)
    return out


def unshadowed_band(model, params, queries, rays, A, B, L, cover: Coverage,
                    band_cells: int) -> mi.Color3f:
    """What U (:meth:`KernelParts.unshadowed`, the banded separated kernel)
    misses in each query's asymptote band: the light model's
    ``band_correction`` (``epipolar_tree``'s, Baran §9's kernel near
    β + γ = π) with every cell lit and the last one covered to the query's
    depth (0: no band, or no separated kernel)."""
    if A is None or not band_cells:
        return dr.zeros(mi.Color3f, queries.count)
    return model.band_correction(params, queries, rays, A, B, L, None,
                                 covered_interval(queries, cover), band_cells)


def covered_interval(queries, cover: Coverage) -> LastInterval:
    """Each query's last light-ray interval as the coverage reads it (the
    texel ⌊D⌋ and its covered fraction), every texel lit; one per frame's
    queries and coverage (the band and the unresolved test read the same)."""
    def make():
        k0 = cover.texel - queries.row * scalar_u32(cover.d)
        ones = dr.full(mi.Float, 1.0, queries.count)
        return LastInterval(k0, cover.frac, ones, ones, dr.zeros(mi.UInt32, 0))
    return frame_memo(queries, ("covered_interval", cover), make)


def schedule_band(model, queries, rays, A, cover: Coverage, band_cells: int) -> None:
    """Schedule what :func:`unshadowed_band` will read of the queries alone
    (the light model's ``schedule_band``): evaluated by the next kernel
    over them (nothing without a band or a separated kernel)."""
    if A is not None and band_cells:
        model.schedule_band(queries, rays, covered_interval(queries, cover), band_cells)


def unresolved_by_separation(queries, A, B, L, cover: Coverage, direct_rays=None,
                             sigma_t=None) -> tuple:
    """(maker, sums): the maker of a mask of the camera samples with a query whose unshadowed sum U the
    separated kernel does not resolve: U below
    :data:`~integrators.epipolar.last_interval.UNRESOLVED_RATIO` of the
    magnitude of its terms
    (:func:`~integrators.epipolar.last_interval.unresolved_samples`, the
    tree's test).  In a thick medium a query's U is then a float32
    cancellation of terms scaled by the row's brightest light rays, wrong
    whatever the rank (held-out directional seed 2012: 20× the exact U);
    the series' V̄ multiplies it.  ``direct_rays``, ``sigma_t``: a
    directional light's equally wide light rays and the medium's σt, with
    which U is also checked against its direct sum where the kernel decays
    along the query
    (:func:`~integrators.epipolar.direct_sum.direct_unshadowed`, the
    tree's second test: a thick fog seen toward the sun, where the light
    side grows as the kernel decays).  Such samples are ray-marched.  The
    sums the test reads are made here (``sums``: the sweep's,
    :func:`~integrators.epipolar.last_interval.sweep_sums`, which
    :func:`unshadowed_sums` can read); the mask, a scatter over the
    queries, where the maker is called (in the next kernel over the
    queries: the epipolar template's ``march_later``)."""
    last = covered_interval(queries, cover)
    sums = sweep_sums(queries, A, B, L)
    M, U = sweep_magnitude(queries, A, B, L, last, sums)
    direct = (None if direct_rays is None else
              direct_unshadowed(queries, direct_rays, L, last, sigma_t))
    return (lambda: unresolved_samples(queries, U, M, direct)), sums


def row_shift(a, smap) -> mi.Float:
    """c (n,): the smallest shift making a + c ≥ 0 on the row's series texels."""
    lo = dr.block_reduce(dr.ReduceOp.Min, dr.select(smap.series, a, dr.inf), smap.d)
    return dr.select(dr.isfinite(lo), dr.maximum(-lo, 0.0), 0.0)


def reference_kernel(params, queries, rays, sigma_t: float, how: str) -> mi.Float:
    """K(γ, β_ref) per light ray (n·d): the weights of the slice's reference
    ray (§3.2, Eq. 11; the light side included), β_ref by
    :func:`~integrators.fourier.rectified_map.reference_angle`; the kernel itself is
    :func:`~integrators.fourier.references.row_kernel`."""
    lo, hi = query_beta_range(queries)
    return row_kernel(params, queries, rays, sigma_t, reference_angle(lo, hi, how))


def near_visibility(queries, rays, beta_b) -> mi.Float:
    """V of the first light ray at each query's β: the visibility the
    rectified sum gives the view ray in front of the near plane
    (:func:`~integrators.epipolar.query_terms.directional_query_terms`,
    :func:`~integrators.epipolar.local_query_terms.local_query_terms`; a spot
    light's first light ray is the first in its cone, as in epipolar_tree)."""
    first = dr.gather(mi.Float, beta_b, queries.row * scalar_u32(rays.d))
    return dr.select(queries.beta <= first, 1.0, 0.0)
