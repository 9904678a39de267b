"""epipolar_tree: Baran et al. 2010, "A Hierarchical Volumetric Shadow
Algorithm for Single Scattering" (epipolar rectification + incremental
partial-sum tree).  The shared rectified maps live in
:mod:`integrators.epipolar_setup`, the point/spot-light maths (§9) in
:mod:`integrators.epipolar_local_light`, the sweep kernel in
:mod:`integrators.partial_sum_tree`, the separation of the integrand in
:mod:`integrators.integrand_svd`.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from .capture import capture_shadow_map
from .epipolar_local_light import (CHECK_POINTS, MAX_RANK,  # shared with the local kernel
                                   light_ray_factor, local_light_ray_grid, local_query_terms,
                                   local_separated_kernel, shadow_map_local_blocker_angles,
                                   trace_local_blocker_angles)
from .epipolar_setup import (assemble_queries, blocker_modes, directional_query_terms,
                             first_leaf_visibility, gather_queries,
                             gray, last_interval_correction, last_interval_visibility,
                             light_ray_grid, light_side_factor, light_side_gains,
                             rectified_depth,
                             shadow_map_blocker_angles, sweep_magnitude,
                             trace_sub_ray_blockers)
from .integrand_svd import SAMPLES, separate_integrand
from .kernel_table import tabulated_terms
from .partial_sum_tree import integrate_slices
from .epipolar_template import EpipolarIntegrator
from .template import read_bool, read_choice, read_number



class EpipolarTreeIntegrator(EpipolarIntegrator):
    r"""Hierarchical volumetric shadows (``epipolar_tree``).

    Single scattering with volumetric shadows of a directional, point or
    spot light (with or without a projected texture) in the homogeneous
    medium around the camera, after Baran et al. 2010:

    1. *Rectification* (§3, §8): epipolar slices (Baran's sinh distribution
       or a uniform one); every camera sample becomes a query of its nearest
       slice at its **own** β and depth D = d·sin β/Δγ, sorted by β -- no
       per-(slice, β) result is interpolated back to pixels (DESIGN §3).
       Blocker map S[α, γ]: ``d`` light rays per slice, each ray-traced with
       Mitsuba from the light (``traced``) or looked up in a classic shadow
       map (``resampled``), converted to the sweep's view-ray index, with
       ``prefilter`` jittered sub-rays per light ray giving depth modes (§7).
    2. *Integrand* (§6, Eq. 4): per light ray, L(γ) = e^{-σt h(α,γ)} (the
       light-side transmittance inside the medium box, initialised into the
       tree like a textured light); the kernel K = e^{-σt γ tan(β/2)} is
       separated by an SVD of a 64×64 sample (one per colour channel if σt
       is coloured) and extended exactly (Nyström) to the light rays and to
       every query's β.  1/sin β, the phase function (any Mitsuba phase,
       exactly, per query: for a directional light θ = β), σs and the
       irradiance are per-query factors.
       Point/spot lights (§9, :mod:`integrators.epipolar_local_light`): γ is
       the angle at the light, dt/r² = dγ/(L sin β) (a per-query factor);
       per light ray, Mitsuba's intensity (spot fall-off and projected
       texture, averaged over the ``prefilter`` sub-rays: §6 textured light)
       times the light-side attenuation outside the path e^{-σt (L − r_in)};
       the kernel K = e^{-σt (t + r − L)} f_p(β + γ) -- the phase function
       depends on β + γ and is part of K -- is separated like the
       directional one.  One γ lattice per frame (rows start at the spot
       cone in their slice), so K's light-ray factors are computed once per
       lattice cell.
    3. *Sweep* (§4-§5, Fig. 6): the Fenwick-tree kernel of
       :mod:`integrators.partial_sum_tree`; slices without blockers take its
       closed form.
    4. *Ring* (§6): samples within ``ring_degrees`` of the epipole (or the
       anti-epipole) are ray-marched with exact visibility.

    Beyond the paper (all measured against ``raymarch visibility=exact``):
    light-side attenuation in the medium box; anisotropic phase functions;
    the SVD sample is taken on log-spaced grids with γ-quadrature weights
    and each view ray's kernel normalised (the paper's uniform grid loses
    10× accuracy in thick media and near the anti-epipole,
    :func:`separate_channel`); each light-ray interval holds the exact mean
    of K over it, not a midpoint sample (:func:`~integrators.epipolar_setup.cell_average`).

    =========================  =============================================
    ``slices``                 number of epipolar slices; 0 (default):
                               automatic, Baran's sinh distribution (§8)
                               with lines at most ``slice_spacing`` px
                               apart (default 1: every pixel within half a
                               pixel of a slice)
    ``slice_spacing``          the automatic slices' largest spacing [px]
                               (default 1; 2: about half the slices, as
                               fast as the nearest slice at 1 and still
                               more accurate with interpolation on the
                               nave, grove and terrain)
    ``slice_interpolation``    each camera sample is a query of both
                               neighbouring slices, weighted by its
                               position between them (default true;
                               false: of the nearest slice alone, as the
                               paper; 1.4-10× lower relMSE on the suite
                               for 10-50 % more time)
    ``light_rays``             light rays ``d`` per slice; 0 (default):
                               the image diagonal in pixels (≥ 32), more
                               in thick media (4 per mean free path, ≤ 4096);
                               point/spot: the widest slice's, narrower
                               slices get fewer at the same angular spacing
    ``svd_rank``               terms N of the separated kernel per colour
                               channel; 0 (default): automatic, the smallest
                               N meeting ``svd_tolerance``
    ``svd_tolerance``          relative L2 error of each view ray's separated
                               kernel, for the automatic rank (default 1e-3)
    ``ring_degrees``           ray-marched ring around the (anti-)epipole
                               (default 2)
    ``ring_steps``             ray-marching segments in the ring (default 256)
    ``prefilter``              sub-rays k per light ray for the depth modes
                               of §7 (default 4; 1 = off, one ray through
                               the light ray's centre)
    ``adaptive_prefilter``     trace the sub-rays only where the blockers
                               at the light-ray boundaries are not smooth,
                               interpolate them elsewhere (default true:
                               blockers ~2× faster at equal error on the
                               nave and terrain; foliage rows are traced in
                               full, :func:`~integrators.epipolar_setup._smooth_intervals`)
    ``rectification``          ``traced`` (default): light rays traced with
                               Mitsuba; ``resampled``: blockers read from an
                               orthographic shadow map (as the paper)
    ``shadowmap_resolution``   texels per side for ``resampled`` (2048)
    =========================  =============================================

    Plus the template's ``output``, ``samples_per_pixel``, ``jitter_pixels``.
    ``self.timings`` splits the scattering stage into ``rectify``,
    ``blockers``, ``svd``, ``sweep``, ``unrectify`` and ``ring``.

    Does not: textured directional lights, translucent blockers,
    heterogeneous media, area or environment lights.  Approximations, all
    vanishing as ``slices``, ``light_rays`` and the rank grow: a sample
    blends the blockers and the light-side factors of its two neighbouring
    slices (or, without ``slice_interpolation``, takes its nearest slice's,
    up to half a slice spacing away: ≈1 % where the box exit is oblique to
    the slices, grazing shadow boundaries, the edge of a spot cone or of
    its texture seen edge-on, a few % on those pixels); visibility and L are
    resolved to a light-ray interval (a shadow edge passing right by the eye
    in a thick medium needs many slices and light rays), except the
    interval in which a view ray ends, ray-traced on the sample's own ray
    where its depth modes are mixed (:meth:`sweep_queries`); point/spot: the short segment between pinhole and near plane is
    taken with one midpoint sample (the light must be farther from the eye
    than the near plane).  ``rectification="resampled"`` adds the shadow
    map's texel size (orthographic, perspective or cube map by light kind).

    Baran, Chen, Ragan-Kelley, Durand, Lehtinen: A Hierarchical Volumetric
    Shadow Algorithm for Single Scattering, ACM TOG 29(6), 2010.
    Fenwick: A new data structure for cumulative frequency tables, 1994.
    """

    SLICE_INTERPOLATION = True

    def read_method_properties(self, props):
        self.prefilter = read_number(props, "prefilter", 4, minimum=1, maximum=16, integer=True)
        self.rectification = read_choice(props, "rectification", "traced",
                                         ("traced", "resampled"))
        self.adaptive_prefilter = read_bool(props, "adaptive_prefilter", True)

    # -- the method ---------------------------------------------------------------
    def integrate_queries(self, params, cap, queries, plan=None):
        return self.sweep_queries(params, cap, queries)

    def sweep_queries(self, params, cap, queries):
        """L_scat of every query (§3-§7; point/spot lights: §9,
        :mod:`integrators.epipolar_local_light`).

        The interval in which a view ray ends is not lit by its leaf's §7
        depth modes, whose sub-rays beyond the end point sample the ray's
        continuation behind the surface, but -- where those modes are mixed
        -- by exact shadow rays from the covered part of the query's own ray
        (:func:`~integrators.epipolar_setup.last_interval_visibility`,
        inside the ``unrectify`` stage); ``self.last_interval_traced``: how
        many of the ``self.query_count`` queries traced them."""
        local = params.light.kind != "directional"
        with self.stage("rectify") as keep:
            if local:
                t_end_max = float(dr.max(queries.t_near)[0]) + float(dr.max(cap.d)[0])
                rays = local_light_ray_grid(params, queries, self.light_rays, t_end_max)
                L, colour, lit = light_ray_factor(params, queries, rays, self.prefilter)
            else:
                rays = light_ray_grid(params, queries, self.light_rays)
                L, colour, lit = light_side_factor(params, queries, rays), None, None
            D = rectified_depth(queries, rays)
            keep.extend([D.array, L.array])
        with self.stage("blockers") as keep:
            beta_b = self.blocker_angles(params, cap, queries, rays, lit)
            modes = blocker_modes(queries, rays, beta_b, self.prefilter)
            keep.extend([modes.beta, modes.weight])
        with self.stage("svd") as keep:
            separate = local_separated_kernel if local else separated_kernel
            A, B = separate(params, queries, rays, self.svd_rank, self.svd_tolerance)
            keep.extend([A, B])
        with self.stage("sweep") as keep:
            integral = integrate_slices(D, modes, A, B, L=L, r_count=mi.Int32(queries.r_count),
                                        d_count=mi.Int32(rays.d_count) if local else None)
            keep.append(integral)
        with self.stage("unrectify") as keep:
            # the last, partial light-ray interval of each query: ray-traced
            # where its leaf's depth modes are uncertain (§5 lerp, §7 modes;
            # epipolar_setup.last_interval_visibility), the sweep's integral
            # corrected by the difference
            last = last_interval_visibility(params, cap, queries, rays, modes, D,
                                            self.prefilter)
            V0 = first_leaf_visibility(queries, modes, last)
            terms = (local_query_terms(params, cap, queries, rays, colour, V0) if local
                     else directional_query_terms(params, cap, queries, rays, V0))
            terms.last = last_interval_correction(queries, A, B, L, last)
            terms.magnitude = sweep_magnitude(queries, A, B, L)
            value = assemble_queries(terms, gather_queries(queries, integral))
            keep.append(value)
        self.last_interval_traced, self.query_count = last.traced, queries.count
        return value

    def blocker_angles(self, params, cap, queries, rays, lit=None):
        """The blocker map S (§3, §7 sub-rays): traced with Mitsuba, or read
        from a classic shadow map (``rectification="resampled"``)."""
        local = params.light.kind != "directional"
        if self.rectification == "traced":
            if local:
                return trace_local_blocker_angles(params, queries, rays, self.prefilter, lit=lit)
            return trace_sub_ray_blockers(params, queries, rays, self.prefilter,
                                          adaptive=self.adaptive_prefilter)
        shadow_map = capture_shadow_map(params, cap, self.shadowmap_resolution)
        if local:
            return shadow_map_local_blocker_angles(params, queries, rays, shadow_map,
                                                   self.prefilter)
        return shadow_map_blocker_angles(params, queries, rays, shadow_map, self.prefilter)

    def to_string(self):
        return (f"EpipolarTreeIntegrator[slices={self.slices}, light_rays={self.light_rays}, "
                f"svd_rank={self.svd_rank}, prefilter={self.prefilter}, "
                f"rectification={self.rectification}, output={self.output}]")


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
    """Separate K(γ, β) ≈ Σ_i a_i(γ) b_i(β) over γ ∈ [0, γ_max], β ∈ [β_lo, β_hi] (§6).

    As §6, a 64×64 sample of the kernel is decomposed by an SVD; unlike the
    paper's uniform grid (whose rank-N error is spent where K is flat), the
    sampled matrix is

        M_jk = √w_j · K(γ_j, β_k) · s_k,   s_k = 1 / ∫_0^{γ_max} K(γ, β_k) dγ,

    on grids uniform in log(1 + c·γ) and log(1 + σt γ_max tan(β/2))
    (c = σt tan(β_hi/2): dense where K decays fastest), with w_j the
    γ-quadrature weights of the grid: M's Frobenius error is then the
    relative L2 error of each view ray's integrand, the quantity the sweep
    sums.  (For σt γ_max tan(β/2) ≫ 1, e.g. thick media or view rays near the
    anti-epipole, the uniform grid's sum errors reach 10×; this one keeps
    them at the tolerance.)  The exact (Nyström) extension of
    :func:`integrators.integrand_svd.extend_nystrom` gives

        a_i(γ) = Σ_k K(γ, β_k) WA_ki,   WA = V diag(1/σ) · s,
        b_i(β) = Σ_j K(γ_j, β) WB_ji,   WB = √w · U,

    evaluated in Dr.Jit by :func:`exp_kernel_sum`.  Returns
    ``(γ grid, tan(β grid / 2), WA, WB)``."""
    G = max(float(gamma_max), 1e-30)
    if not beta_hi > beta_lo:
        beta_lo, beta_hi = beta_lo - 1e-4, beta_hi + 1e-4
    x_lo, x_hi = math.tan(0.5 * beta_lo), math.tan(0.5 * beta_hi)
    c = max(sigma_t * x_hi, 1e-6 / G)
    v = np.linspace(0.0, math.log1p(c * G), SAMPLES)
    gamma_grid = np.expm1(v) / c
    cb = max(sigma_t * G, 1e-6)
    u = np.linspace(math.log1p(cb * x_lo), math.log1p(cb * x_hi), SAMPLES)
    x_grid = np.expm1(u) / cb
    beta_grid = 2.0 * np.arctan(x_grid)

    def weight(gamma):                      # dγ/dv · Δv: the grid's quadrature weight
        return (1.0 + c * gamma) / c * (v[1] - v[0])

    def scale(beta):
        return 1.0 / (G * _phi(sigma_t * np.tan(0.5 * beta) * G))

    def I_w(gamma, beta):
        return np.sqrt(weight(gamma)) * kernel(sigma_t)(gamma, beta) * scale(beta)

    # the automatic rank is checked on the grid and on uniform points
    gamma = np.concatenate([gamma_grid, np.linspace(0.0, G, CHECK_POINTS)])
    beta = np.concatenate([beta_grid, np.linspace(beta_lo, beta_hi, CHECK_POINTS)])
    sep = separate_integrand(I_w, gamma, beta, N=rank or None, tol=tol,
                             grid=(gamma_grid, beta_grid), max_N=MAX_RANK)
    U, VS, sigma = sep.A[:SAMPLES], sep.B[:SAMPLES], sep.singular_values[:sep.N]
    WA = VS * scale(beta_grid)[:, None] / sigma ** 2
    WB = np.sqrt(weight(gamma_grid))[:, None] * U
    return gamma_grid, x_grid, WA, WB


def exp_kernel_sum(x: mi.Float, table: np.ndarray, weights: np.ndarray, sigma_t: float):
    """Σ_k e^{-σt x table[k]} weights[k, i] for each term i, per lane of x
    (the Nyström sums of :func:`separate_channel` in one Dr.Jit loop)."""
    K, N = weights.shape
    tab = mi.Float(np.asarray(table, np.float32))
    # float32 range: in extreme optical depths (σt·γ_max ≳ 80) some Nyström
    # weights exceed it; their kernel factor e^{-σt x t} has underflowed to
    # 0 there, and an inf weight would turn 0 into NaN
    finite = np.clip(np.nan_to_num(weights, nan=0.0), -1e30, 1e30)
    W = [mi.Float(np.ascontiguousarray(finite[:, i], np.float32)) for i in range(N)]
    st = dr.opaque(mi.Float, float(sigma_t))
    n_k = dr.opaque(mi.UInt32, K)

    def body(k, acc):
        e = dr.exp(-st * x * dr.gather(mi.Float, tab, k))
        return k + 1, tuple(a + e * dr.gather(mi.Float, w, k) for a, w in zip(acc, W))

    _, acc = dr.while_loop(state=(mi.UInt32(0), tuple(dr.zeros(mi.Float, dr.width(x))
                                                      for _ in range(N))),
                           cond=lambda k, acc: k < n_k, body=body)
    return list(acc)


def separated_kernel(params, queries, rays, rank: int, tol: float):
    """A (n, d, C, N) at the start γ_g of every light-ray interval and
    B (n, r, C, N) at the queries' own β (padded slots: 0);
    C = 1 for grey σt.  K(γ_g, β)·φ(σt tan(β/2) Δγ) is the exact mean of K
    over the interval (φ: :func:`~integrators.epipolar_setup.cell_average`,
    a per-query factor)."""
    sigma_t = np.asarray(params.medium.sigma_t, np.float64)
    channels = [0] if gray(sigma_t) else [0, 1, 2]
    gamma_max = float(dr.max(rays.gamma_max)[0])
    beta_lo, beta_hi = float(dr.min(queries.beta)[0]), float(dr.max(queries.beta)[0])
    x_lo, x_hi = math.tan(0.5 * beta_lo), math.tan(0.5 * beta_hi)
    # the per-query factor e^{-σt h_ref} multiplies the kernel's errors:
    # the automatic rank meets the tolerance after it (row_reference)
    gains = light_side_gains(sigma_t, rays.h)
    seps = [separate_channel(float(sigma_t[c]), gamma_max, beta_lo, beta_hi, rank,
                             tol / gains[c]) for c in channels]
    N = max(s[2].shape[1] for s in seps)
    C = len(channels)
    _, gamma = rays.positions(0.0)   # cell starts: φ in the query terms averages K
    tan_half = dr.tan(0.5 * queries.beta)   # only at the queries; padded slots stay 0
    A = dr.zeros(mi.Float, dr.width(gamma) * C * N)
    B = dr.zeros(mi.Float, queries.n * queries.r * C * N)
    lane_a = dr.arange(mi.UInt32, dr.width(gamma)) * (C * N)
    lane_b = queries.slot * (C * N)
    for c, (ch, (g_grid, x_grid, WA, WB)) in enumerate(zip(channels, seps)):
        st = float(sigma_t[ch])
        a_terms = tabulated_terms(gamma, 0.0, gamma_max, st * float(np.max(x_grid)),
                                  lambda x: exp_kernel_sum(x, x_grid, WA, st))
        b_terms = tabulated_terms(tan_half, x_lo, x_hi, st * gamma_max,
                                  lambda x: exp_kernel_sum(x, g_grid, WB, st))
        for i in range(WA.shape[1]):
            dr.scatter(A, a_terms[i], lane_a + c * N + i)
            dr.scatter(B, b_terms[i], lane_b + c * N + i)
    return (mi.TensorXf(A, shape=(queries.n, rays.d, C, N)),
            mi.TensorXf(B, shape=(queries.n, queries.r, C, N)))


mi.register_integrator("epipolar_tree", lambda props: EpipolarTreeIntegrator(props))
