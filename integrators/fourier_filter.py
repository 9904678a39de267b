"""fourier_filter: Klehm et al. 2014, "Filter-Based Real-Time Single
Scattering using Rectified Shadow Maps" (JCGT 3(3)).

The rectified shadow map is built on the epipolar rectification shared with
``epipolar_tree`` (:mod:`integrators.epipolar_setup`, directional light) by
:mod:`integrators.fourier_setup`; the Fourier-basis prefilter and the
per-pixel evaluation are :mod:`integrators.fourier_basis`; the separated
kernel of ``weights="exact"`` is ``epipolar_tree``'s
(:func:`integrators.epipolar_tree.separated_kernel`).
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .capture import capture_shadow_map
from .epipolar_setup import (LightRays, assemble_queries, auto_light_rays,
                             directional_query_terms, gray, light_ray_grid, light_side_factor,
                             require_directional, shadow_map_blocker_angles,
                             trace_blocker_angles)
from .epipolar_tree import separated_kernel
from .fourier_basis import check_M, region_length
from .fourier_setup import (DEPTH_RANGES, REFERENCES, Coverage, FilterSettings,
                            prefilter_rows, query_beta_range, rectified_shadow_map,
                            reference_angle, series_sum, series_visibility,
                            shadowed_sum)
from .epipolar_template import EpipolarIntegrator
from .template import read_bool, read_choice, read_number

WEIGHTS = ("average", "reference_ray", "exact")
RECTIFICATIONS = ("auto", "epipolar", "projective")
BLOCKERS = ("traced", "resampled")


class FourierFilterIntegrator(EpipolarIntegrator):
    r"""Filter-based single scattering (``fourier_filter``).

    Single scattering with volumetric shadows of a directional light in the
    homogeneous medium around the camera, after Klehm et al. 2014:

    1. *Rectified shadow map* (§2.2, §4.1): epipolar slices = rows, ``d``
       light rays per slice = texels, each traced with Mitsuba from the
       light (``blockers="traced"``) or read from a classic orthographic
       shadow map (``"resampled"``).  The depth constant along a view ray is
       its angle β to the light; a texel holds its blocker's angle β_b
       (view ray β is shadowed there iff β > β_b: Eq. 5's step).  Every
       camera sample is evaluated at its **own** β and depth (it is a query
       of its nearest slice; nothing is interpolated back to pixels).
       See :mod:`integrators.fourier_setup` for the depth mapping
       (``depth_range``).
    2. *Basis and prefilter* (§3.1 Eqs. 6-10, §3.3 Listings 1-3): the shadow
       test is expanded in ``M`` Fourier coefficients; weighted running
       prefix sums of the basis along every row (normalised, Appendix A).
    3. *Per pixel* (Listing 4): ``M`` coefficients of the ray's depth, one
       dot product per lookup, times the weight sum of the texels in front
       of its end point: L_scat = σs f_p E · Δγ/sin β · Σ_γ L(γ) K(γ, β) V.

    With L(γ) = e^{-σt h(α,γ)} the light-side transmittance per light ray and
    K(γ, β) = e^{-σt γ tan(β/2)} the camera and light transmittance kernel
    (DESIGN §1, :mod:`integrators.epipolar_setup`), ``weights`` chooses how
    the weighted sum Σ L K V is obtained:

    ``average`` (§3.1)
        filter weights L(γ): the average visibility V̄ of Eq. 4/Listing 4
        times the query's own unshadowed sum U(β) = Σ L K(γ, β).
    ``reference_ray`` (§3.2, Eq. 11, Listing 2; default)
        filter weights L(γ) K(γ, β_ref) of one reference ray per slice:
        the bisectrix of the slice's (smallest, largest) transmittance
        decay, or the min-max optimum (``reference``, see
        :func:`~integrators.fourier_setup.reference_angle`); V̄ · U(β).
    ``exact`` (beyond the paper)
        K = Σ_n A_n(γ) B_n(β) separated as in ``epipolar_tree`` (SVD,
        ``svd_rank``/``svd_tolerance``); one filter per component with the
        non-negative weights L (A_n + c_n) (c_n: a per-row shift, undone with
        one more filter of weights L), combined with B_n(β) of the query:
        Σ_γ L K V with the query's own kernel, no reference ray.  Linear in
        the filters, so ``clamp`` applies to the combined average.

    U(β) uses the same separated kernel (prefix sums of L A_n, no filter).
    Rows with no blocker in view take U directly (closed form, no filter).

    =========================  =============================================
    ``coefficients``           M, Fourier coefficients, sines and cosines
                               counted apart (even, default 32, §5)
    ``weights``                ``average`` | ``reference_ray`` (default) |
                               ``exact`` (above)
    ``reference``              reference ray of ``reference_ray``:
                               ``bisectrix`` (default, §3.2) | ``optimal``
    ``regions``                prefix-sum regions per row (§3.3, default 1)
    ``clamp``                  clamp the filtered visibility to [0, 1]
                               (Appendix A; default true)
    ``fit_depth``              map each region's blocker depth range onto
                               [0, 1/2] (sharper steps; default false)
    ``exact_bounds``           regions entirely in front of / behind a ray
                               are exactly lit / shadowed (default true)
    ``depth_range``            ``slice`` (default): each slice's β range,
                               texels outside it summed exactly; ``full``:
                               z = β/π (:mod:`integrators.fourier_setup`)
    ``slices``                 epipolar slices; 0 (default): automatic
                               (sinh distribution, every pixel within half
                               a pixel of a slice)
    ``light_rays``             texels (light rays) per row; 0 (default):
                               4× ``epipolar_tree``'s automatic count, at
                               most 1024 (:func:`auto_texels`)
    ``ring_degrees``           ray-marched ring around the (anti-)epipole
                               (default 2)
    ``ring_steps``             ray-marching segments in the ring (256)
    ``svd_rank``,              separated kernel: rank (0: automatic) and
    ``svd_tolerance``          relative L2 tolerance (1e-3)
    ``rectification``          ``auto`` = ``epipolar`` (default);
                               ``projective`` (§4.2) is not implemented
    ``blockers``               ``traced`` (default) | ``resampled``
    ``shadowmap_resolution``   texels per side for ``resampled`` (2048)
    =========================  =============================================

    Plus the template's ``output``, ``samples_per_pixel``, ``jitter_pixels``.
    ``self.timings`` splits the scattering stage into ``rectify``,
    ``blockers``, ``svd``, ``prefilter``, ``evaluate``, ``unrectify`` and
    ``ring``.

    Does not: point and spot lights (raises ``ValueError``), textured
    lights, the projective rectification of §4.2 (raises ``ValueError``),
    depth-mode prefiltering of sub-texel blockers, translucent blockers,
    heterogeneous media.  Approximations, all vanishing as ``coefficients``,
    ``slices`` and ``light_rays`` grow (``weights="exact"``; the other two
    keep their weighting error): the truncated Fourier series blurs each
    shadow step over ~1/M of the slice's depth range and rings (Gibbs) next
    to it; a sample uses the blockers and the light-side factor of its
    nearest slice; visibility is resolved to a light-ray interval.  Coloured
    σt runs every filter once per channel.

    Klehm, Seidel, Eisemann: Filter-Based Real-Time Single Scattering using
    Rectified Shadow Maps, JCGT 3(3), 2014.
    Annen, Mertens, Bekaert, Seidel, Kautz: Convolution Shadow Maps, EGSR 2007.
    Baran, Chen, Ragan-Kelley, Durand, Lehtinen: A Hierarchical Volumetric
    Shadow Algorithm for Single Scattering, ACM TOG 29(6), 2010.
    """

    def read_method_properties(self, props):
        M = read_number(props, "coefficients", 32, minimum=2, maximum=1024, integer=True)
        if M % 2:
            raise ValueError(f"Property 'coefficients' = {M} must be even (sines and "
                             "cosines of each harmonic are counted apart).")
        self.M = check_M(M)
        self.weights = read_choice(props, "weights", "reference_ray", WEIGHTS)
        self.reference = read_choice(props, "reference", "bisectrix", REFERENCES)
        self.regions = read_number(props, "regions", 1, minimum=1, maximum=64, integer=True)
        self.clamp = read_bool(props, "clamp", True)
        self.fit_depth = read_bool(props, "fit_depth", False)
        self.exact_bounds = read_bool(props, "exact_bounds", True)
        self.depth_range = read_choice(props, "depth_range", "slice", DEPTH_RANGES)
        self.rectification = read_choice(props, "rectification", "auto", RECTIFICATIONS)
        if self.rectification == "projective":
            raise ValueError("Property 'rectification' = 'projective': Klehm's projective "
                             "rectification (§4.2) is not implemented yet in fourier_filter; "
                             "use 'epipolar' or 'auto'.")
        self.blockers = read_choice(props, "blockers", "traced", BLOCKERS)

    @property
    def filter_settings(self) -> FilterSettings:
        return FilterSettings(self.M, self.regions, self.fit_depth, self.exact_bounds)

    # -- the method ---------------------------------------------------------------
    def check_light(self, params):
        require_directional(params, "fourier_filter", "Klehm 2014 §3.2 local lights")

    def integrate_queries(self, params, cap, queries):
        """L_scat of every query (§3, Listing 4)."""
        rect = self.rectified_sums(params, cap, queries)
        with self.stage("unrectify") as keep:
            V_near = near_visibility(queries, rect.rays, rect.beta_b)
            terms = directional_query_terms(params, cap, queries, rect.rays, V_near)
            value = assemble_queries(terms, rect.integral())
            keep.append(value)
        return value

    def rectified_sums(self, params, cap, queries) -> "RectifiedSums":
        """Σ_γ L K V cover per query and colour channel, as the unshadowed
        sum U times the effective visibility V̄ (class doc)."""
        with self.stage("rectify"):
            d = self.light_rays or auto_texels(params, queries)
            rays = light_ray_grid(params, queries, d)
            cover = Coverage.of(queries, rays)
            L = light_side_factor(params, queries, rays)
        with self.stage("blockers"):
            beta_b = self.blocker_angles(params, cap, queries, rays)
            smap = rectified_shadow_map(queries, rays, beta_b, self.depth_range)
            if self.regions > 1:
                region_length(rays.d, self.regions)      # ValueError if a region is empty
        with self.stage("svd") as keep:
            A, B = separated_kernel(params, queries, rays, self.svd_rank, self.svd_tolerance)
            keep.extend([A, B])
        sigma_t = np.asarray(params.medium.sigma_t, np.float64)
        C = 1 if gray(sigma_t) else 3
        U, V = [], []
        for c in range(C):
            parts = KernelParts.of(queries, rays, L, A, B, c, C)
            U_c, V_c = self.channel_sums(queries, rays, smap, cover, parts, float(sigma_t[c]))
            U.append(U_c)
            V.append(V_c)
        return RectifiedSums(rays, beta_b, U, V)

    def blocker_angles(self, params, cap, queries, rays):
        if self.blockers == "traced":
            return trace_blocker_angles(params, queries, rays, 1)
        shadow_map = capture_shadow_map(params, cap, self.shadowmap_resolution)
        return shadow_map_blocker_angles(params, queries, rays, shadow_map, 1)

    def channel_sums(self, queries, rays, smap, cover, parts, sigma_t: float):
        """(U, V̄) per query for one colour channel: the unshadowed sum and
        the effective average visibility of ``weights`` (clamped to [0, 1]
        with ``clamp``, Appendix A)."""
        with self.stage("evaluate") as keep:
            U = parts.unshadowed(cover)
            keep.append(U)
        if self.weights == "exact":
            S = self.exact_sum(queries, smap, cover, parts)
            V = dr.select(U > 0.0, S / U, 1.0)
        else:
            w = parts.L if self.weights == "average" else \
                parts.L * reference_kernel(queries, rays, sigma_t, self.reference)
            V = self.filtered_average(queries, smap, cover, w, self.clamp)
        with self.stage("evaluate") as keep:
            if self.clamp:
                V = dr.clip(V, 0.0, 1.0)
            keep.append(V)
        return U, V

    def filtered(self, queries, smap, cover, w, clamp: bool):
        """Prefilter the weights ``w`` (one filter; ``prefilter`` stage) and
        evaluate the series visibility of every query (``evaluate``)."""
        opt = self.filter_settings
        with self.stage("prefilter") as keep:
            fb = prefilter_rows(smap, w, opt)
            if fb is not None:
                keep.extend([fb.B_bar, fb.W])
        with self.stage("evaluate") as keep:
            V = series_visibility(smap, fb, queries, cover, opt, clamp)
            keep.append(V)
        return V

    def filtered_average(self, queries, smap, cover, w, clamp: bool):
        """Weighted average visibility with one filter of weights ``w``
        (§3.1, §3.2): (Σ_lit w + Σ_series w · V̄) / Σ w."""
        V_series = self.filtered(queries, smap, cover, w, clamp)
        P = cover.sum(w)
        return dr.select(P > 0.0, shadowed_sum(smap, cover, w, V_series) / P, 1.0)

    def exact_sum(self, queries, smap, cover, parts):
        """Σ_n B_n(β) Σ_γ L A_n V cover, every component through its own
        filter with shifted, non-negative weights L (A_n + c_n), minus
        c_n times the filter of weights L (class doc)."""
        V0 = self.filtered(queries, smap, cover, parts.L, clamp=False)
        S0 = series_sum(smap, cover, parts.L, V0)              # Σ_series L V
        S = dr.zeros(mi.Float, queries.count)
        for a, b in zip(parts.A, parts.B):
            shift = row_shift(a, smap)
            w = parts.L * (a + dr.gather(mi.Float, shift, smap.texel_row))
            Vn = self.filtered(queries, smap, cover, w, clamp=False)
            lit = cover.sum(dr.select(smap.lit, parts.L * a, 0.0))
            S += b * (lit + series_sum(smap, cover, w, Vn)
                      - dr.gather(mi.Float, shift, queries.row) * S0)
        return S

    def to_string(self):
        return (f"FourierFilterIntegrator[coefficients={self.M}, weights={self.weights}, "
                f"regions={self.regions}, clamp={self.clamp}, fit_depth={self.fit_depth}, "
                f"depth_range={self.depth_range}, slices={self.slices}, "
                f"light_rays={self.light_rays}, output={self.output}]")


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------

#: default texels per row: this many times epipolar_tree's light rays ...
TEXEL_FACTOR = 4
#: ... but not above this (unless epipolar_tree's own count is larger)
MAX_AUTO_TEXELS = 1024


def auto_texels(params, queries) -> int:
    """Default texels (light rays) per row.  ``epipolar_tree`` resolves each
    light ray into ``prefilter`` = 4 sub-rays (Baran §7); a rectified shadow
    map has one depth per texel, so it takes ``TEXEL_FACTOR`` times its
    light rays (:func:`~integrators.epipolar_setup.auto_light_rays`), up to
    ``MAX_AUTO_TEXELS`` (Klehm §5 uses 1024 for 1920×1080)."""
    cam = params.camera
    d = auto_light_rays(cam.width, cam.height, float(np.max(params.medium.sigma_t)),
                        float(dr.max(queries.gamma_end)[0]))
    return max(d, min(TEXEL_FACTOR * d, MAX_AUTO_TEXELS))


@dataclass(eq=False)
class RectifiedSums:
    """Per query and colour channel (1 or 3): U = Σ_γ L K cover (no
    blockers) and the effective average visibility V̄ of the blockers."""
    rays: LightRays
    beta_b: mi.Float      # (n·d) blocker angle per light ray
    U: list
    V: list

    def integral(self) -> mi.Color3f:
        """Σ_γ L K V cover = U · V̄ as a Color3f."""
        values = [u * v for u, v in zip(self.U, self.V)]
        return mi.Color3f(*(values * 3 if len(values) == 1 else values))


class KernelParts:
    """One colour channel of the separated integrand: L (n·d) per light ray,
    A_n (n·d) at every light ray's start, B_n (Q) at every query's β."""

    def __init__(self, L, A, B):
        self.L, self.A, self.B = L, A, B

    @staticmethod
    def of(queries, rays, L, A, B, c: int, C: int) -> "KernelParts":
        lanes = dr.arange(mi.UInt32, queries.n * rays.d)
        CL = L.shape[2] if len(L.shape) == 3 else 1
        L_c = dr.gather(mi.Float, L.array, lanes * CL + min(c, CL - 1))
        N = A.shape[3]
        A_c, B_c = [], []
        for i in range(N):
            b = dr.gather(mi.Float, B.array, queries.slot * (C * N) + c * N + i)
            if dr.all(b == 0.0):        # unused component of this channel
                continue
            A_c.append(dr.gather(mi.Float, A.array, lanes * (C * N) + c * N + i))
            B_c.append(b)
        return KernelParts(L_c, A_c, B_c)

    def unshadowed(self, cover: Coverage) -> mi.Float:
        """U(β) = Σ_n B_n(β) Σ_γ L A_n cover: the query's sum without
        blockers (the closed form of unblocked rows)."""
        U = dr.zeros(mi.Float, dr.width(cover.frac))
        for a, b in zip(self.A, self.B):
            U += b * cover.sum(self.L * a)
        return U


def row_shift(a, smap) -> mi.Float:
    """c (n,): the smallest shift making a + c ≥ 0 on the row's series texels."""
    lo = dr.block_reduce(dr.ReduceOp.Min, dr.select(smap.series, a, dr.inf), smap.d)
    return dr.select(dr.isfinite(lo), dr.maximum(-lo, 0.0), 0.0)


def reference_kernel(queries, rays, sigma_t: float, how: str) -> mi.Float:
    """K(γ_g, β_ref) per light ray (n·d): the transmittance weights of the
    slice's reference ray (§3.2, Eq. 11; the light side included)."""
    lo, hi = query_beta_range(queries)
    tan_ref = dr.tan(0.5 * reference_angle(lo, hi, how))
    s, gamma = rays.positions(0.0)
    return dr.exp(-sigma_t * gamma * dr.gather(mi.Float, tan_ref, s))


def near_visibility(queries, rays, beta_b) -> mi.Float:
    """V of the first light ray at each query's β: the visibility the
    rectified sum gives the view ray in front of the near plane
    (:func:`~integrators.epipolar_setup.directional_query_terms`)."""
    first = dr.gather(mi.Float, beta_b, queries.row * rays.d)
    return dr.select(queries.beta <= first, 1.0, 0.0)


mi.register_integrator("fourier_filter", lambda props: FourierFilterIntegrator(props))
