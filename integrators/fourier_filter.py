"""fourier_filter: Klehm et al. 2014, "Filter-Based Real-Time Single
Scattering using Rectified Shadow Maps" (JCGT 3(3)) -- the plugin, which
strings together the stages of :mod:`integrators.fourier` on the epipolar
rectification of :mod:`integrators.epipolar`.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .core.capture import capture_shadow_map
from .core.opaque import two_or_more
from .core.properties import read_bool, read_choice, read_number
from .core.quality_auto import register_rule
from .epipolar.frame import choose_slices, epipolar_frame_of
from .epipolar.light_models import light_model
from .epipolar.query_terms import assemble_queries
from .fourier.basis import check_M
from .fourier.exact import exact_sums
from .fourier.layers import layered_average
from .fourier.prefilter import region_length
from .fourier.projective_rays import (ProjectiveLightRays, projective_map_rays,
                                      projective_query_terms, texel_separated_kernel)
from .fourier.quality import FILTER_RULE
from .fourier.rectified_map import (DEPTH_RANGES, REFERENCES, Coverage, FilterSettings,
                                    query_beta_range,
                                    class_and_total_sums, near_band, near_step_weight,
                                    prefilter_rows, rectified_shadow_map, series_sum,
                                    series_unreliable, series_visibility)
from .fourier.references import reference_rays, reference_rows
from .fourier.rows import ProjectivePlan, auto_texels, projective_plan, row_spacing, texel_size
from .fourier.sums import (KernelParts, RectifiedSums, channels, near_visibility, reference_kernel,
                           row_shift, schedule_band, unresolved_by_separation,
                           unshadowed_band, unshadowed_sums)
from .fourier.tail import tail_visibility
from .partial.row_subset import frame_choices, take_light_rays, take_rows
from .template.epipolar import EpipolarIntegrator


WEIGHTS = ("average", "reference_ray", "exact")
#: ``visibility``: ``exact_directional`` (the default: the direct sum for a
#: directional light, Klehm's filter for point and spot lights), ``exact``
#: (the direct sum, :mod:`integrators.fourier.exact`) or ``filter`` (Klehm's)
VISIBILITIES = ("exact_directional", "exact", "filter")
#: properties of the Fourier filter: setting one makes the default ``visibility`` the filter
FILTER_PROPERTIES = ("coefficients", "weights", "reference", "reference_rays", "regions",
                     "clamp", "fit_depth", "exact_bounds", "depth_range")
RECTIFICATIONS = ("auto", "epipolar", "projective")
#: the light-side range c of the direct sum (a directional light's light
#: rays leaving the box more than c mean free paths behind the eye are left
#: out and their samples marched): the separated kernels' 4
#: (:data:`~integrators.epipolar.light_rays.directional.LIGHT_SIDE_RANGE`)
#: is their float32 resolution, the direct sum's terms L·K stay in range to
#: e^{±20} (held-out seed 2016 at 320x240: c = 4 marched 34,289 of its
#: 76,800 samples, 0.83 s a frame against 0.11 s)
EXACT_LIGHT_SIDE_RANGE = 20.0
BLOCKERS = ("traced", "resampled")
#: default ``projective_min_angle`` [deg]: ``auto`` takes the projective map
#: when every view ray of the image is at least this far from the light
#: direction (Klehm §4.2: "distance of the epipole to screen border").
#: 90°: at most one view direction qualifies, so ``auto`` keeps the epipolar
#: slices unless the threshold is lowered; results/projective_angles has
#: the measurements behind this default.
PROJECTIVE_MIN_ANGLE = 90.0


class FourierFilterIntegrator(EpipolarIntegrator):
    r"""Filter-based single scattering (``fourier_filter``).

    Klehm et al. 2014's filter on the epipolar rectification shared with
    ``epipolar_tree`` (or Klehm's projective one): the stages, in pipeline
    order, and the method's maths are in :mod:`integrators.fourier`'s
    docstring (DESIGN §3).

    =========================  =============================================
    ``visibility``             ``exact_directional`` (default) | ``exact`` |
                               ``filter``
                               (:mod:`integrators.fourier`)
    ``reference_rays``         reference rays per row of ``reference_ray``
                               (0: automatic, 1: Klehm's single ray)
    ``coefficients``           M, Fourier coefficients, sines and cosines
                               counted apart (even, default 32, §5)
    ``weights``                ``average`` | ``reference_ray`` (default) |
                               ``exact`` (:mod:`integrators.fourier`)
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
                               z = β/π (:mod:`integrators.fourier.rectified_map`)
    ``exact_fallback``         the exact sum where the series is mostly its
                               blurred step (above; default true; false:
                               the series alone, as the paper)
    ``trace_ends``             trace the short run of texels behind each
                               ray's last visibility change on its own ray
                               (above; default true)
    ``slices``                 epipolar slices (projective: rows); 0
                               (default): automatic (sinh distribution;
                               projective: equal steps), every pixel
                               within half a pixel of a slice (row)
    ``slice_spacing``          automatic epipolar slices at most this many
                               pixels apart (default: 1 at one sample per
                               pixel, 1/√spp with spp jittered samples)
    ``slice_interpolation``    each camera sample a query of both
                               neighbouring slices, weighted by its
                               position between them (default true;
                               false: the nearest slice, as the paper:
                               a sample across a shaft's edge from its
                               slice takes the other side's light,
                               :mod:`integrators.template.epipolar`)
    ``remarch_disagreement``   with ``slice_interpolation``: a camera
                               sample whose two slices' answers differ by
                               more than this fraction of the larger is
                               ray-marched like the ring (default 0.25;
                               1: never; ``stats["remarched"]``; shared
                               with ``epipolar_tree``)
    ``light_rays``             texels (light rays) per row; 0 (default):
                               4× ``epipolar_tree``'s automatic count, at
                               most 1024 (:func:`~integrators.fourier.rows.auto_texels`);
                               point/spot:
                               the widest row's, narrower rows get fewer
                               at the same angular spacing
    ``ring_degrees``           ray-marched ring around the (anti-)epipole
                               (default 2)
    ``ring_steps``             ray-marching segments in the ring (256)
    ``ring_bisections``        bisections of the shadow/cone edges on the
                               ring's and re-marched samples' segments
                               (default 4; 0: midpoint rule)
    ``svd_rank``,              separated kernel: rank (0: automatic) and
    ``svd_tolerance``          relative L2 tolerance (1e-3)
    ``rectification``          ``auto`` (default): ``projective`` for a
                               directional light whose (anti-)epipole is
                               far off screen (every view ray at least
                               ``projective_min_angle`` from the light
                               direction), else ``epipolar``;
                               ``epipolar``: Baran's slices; ``projective``:
                               Klehm §4.2 (above; refused with a
                               ValueError for point/spot lights, an
                               on-screen (anti-)epipole or view rays
                               within 5° of the light direction)
    ``projective_min_angle``   ``auto``'s threshold in degrees (default
                               90: never, ``PROJECTIVE_MIN_ANGLE``; the
                               measurements, results/projective_angles)
    ``projective_splits``      Klehm's splits of the projective columns;
                               0 (default): automatic, each spans ≤ 2× in x
                               (:func:`~rectify.projective.auto_splits`)
    ``blockers``               ``traced`` (default) | ``resampled``
    ``shadowmap_resolution``   texels per side (per cube face) for
                               ``resampled`` (2048)
    =========================  =============================================

    Plus the template's ``output``, ``samples_per_pixel``, ``jitter_pixels``.
    ``RenderResult.timings`` splits the scattering stage into ``rectify``,
    ``blockers``, ``svd``, ``prefilter``, ``evaluate``, ``unrectify`` and
    ``ring``; ``RenderResult.stats["rectification_used"]`` says which rectification the
    render took (``epipolar`` or ``projective``).

    =====================  ==================================================
    light                  supported
    =====================  ==================================================
    directional            yes (L: light-side transmittance); epipolar or
                           projective rectification
    point                  yes (§9 light rays; cube map for ``resampled``);
                           epipolar rectification only
    spot                   yes (rows start at the cone; perspective map for
                           ``resampled`` up to 60° cutoff, else cube);
                           epipolar rectification only
    spot, ``texture``      yes (coloured L: three filter sets even in a
                           grey medium, Klehm §3.2's "triples storage")
    area, environment,     no: ``ValueError`` from the scene check naming
    several emitters       the emitter and the fix
    =====================  ==================================================

    Does not: the projective rectification of point and spot lights
    (``ValueError``: use ``epipolar``/``auto``), rasterising the projective
    map (its texels are traced or read from the shadow map like the
    epipolar ones), depth-mode prefiltering of sub-texel blockers (one ray
    per texel, also for the projected texture and the cone's edge),
    translucent blockers, heterogeneous media.  Approximations, all
    vanishing as ``coefficients``, ``slices`` and ``light_rays`` grow
    (``weights="exact"``; the other two keep their weighting error): the
    truncated Fourier series blurs each shadow step over ~1/M of the slice's
    depth range and rings (Gibbs) next to it; a sample uses the blockers and
    the light-side factor (point/spot: intensity, fall-off, texture) of its
    two neighbouring slices (or its nearest slice, row); visibility is resolved to a light-ray interval
    (texel); point/spot: the short segment between pinhole and near plane
    is one midpoint sample; projective: the segment in front of the map's
    first edge takes the first texel's visibility.  Coloured σt runs every
    filter once per channel; a textured light in a grey medium stacks its
    channels as layers of the reference rays' filter
    (:meth:`stacked_channel_sums`).

    Klehm, Seidel, Eisemann: Filter-Based Real-Time Single Scattering using
    Rectified Shadow Maps, JCGT 3(3), 2014.
    Annen, Mertens, Bekaert, Seidel, Kautz: Convolution Shadow Maps, EGSR 2007.
    Baran, Chen, Ragan-Kelley, Durand, Lehtinen: A Hierarchical Volumetric
    Shadow Algorithm for Single Scattering, ACM TOG 29(6), 2010.
    """

    #: per-row partial renders (temporal reuse), epipolar rows only: the
    #: projective map's rows and texels are fitted to the whole frame
    ROW_SUBSETS = True
    SLICE_INTERPOLATION = True
    #: point/spot lights, ``weights`` ``average``/``reference_ray``: light-ray
    #: cells before each view ray's asymptote in which U takes the exact cell
    #: means instead of the separated kernel (``epipolar_tree``'s band,
    #: :class:`~integrators.epipolar.kernel.local.LocalSeparation`).  The
    #: texels are TEXEL_FACTOR = 4 times narrower than the tree's light rays,
    #: so 8 cells span the tree's 2; 16 (random seed 233: mean ratio 0.983
    #: with 2 cells, 0.995 with 8, 0.998 with 16)
    ASYMPTOTE_BAND = 16

    def read_method_properties(self, props):
        explicit_filter = any(k in props for k in FILTER_PROPERTIES)
        M = read_number(props, "coefficients", 32, minimum=2, maximum=1024, integer=True)
        if M % 2:
            raise ValueError(f"Property 'coefficients' = {M} must be even (sines and "
                             "cosines of each harmonic are counted apart).")
        self.M = check_M(M)
        self.weights = read_choice(props, "weights", "reference_ray", WEIGHTS)
        self.reference = read_choice(props, "reference", "bisectrix", REFERENCES)
        if props.get("visibility", None) == "auto":
            raise ValueError("Property 'visibility' = 'auto' is now called 'exact_directional' "
                             "(the default: the exact visibility sum for a directional light, "
                             "Klehm's filter for point and spot lights); or choose 'exact' or "
                             "'filter'.")
        self.visibility = read_choice(props, "visibility", "exact_directional", VISIBILITIES)
        #: the default: the exact sum, unless a property of the filter asks for it
        self.visibility_used = (self.visibility if self.visibility != "exact_directional" else
                                "filter" if explicit_filter else "exact")
        self.reference_rays = read_number(props, "reference_rays", 0, minimum=0,
                                          maximum=256, integer=True)
        self.regions = read_number(props, "regions", 1, minimum=1, maximum=64, integer=True)
        self.clamp = read_bool(props, "clamp", True)
        self.fit_depth = read_bool(props, "fit_depth", False)
        self.exact_bounds = read_bool(props, "exact_bounds", True)
        self.depth_range = read_choice(props, "depth_range", "slice", DEPTH_RANGES)
        self.rectification = read_choice(props, "rectification", "auto", RECTIFICATIONS)
        self.projective_min_angle = read_number(props, "projective_min_angle",
                                                PROJECTIVE_MIN_ANGLE, minimum=0.5,
                                                maximum=90.0)
        self.projective_splits = read_number(props, "projective_splits", 0, minimum=0,
                                             maximum=4096, integer=True)
        self.blockers = read_choice(props, "blockers", "traced", BLOCKERS)
        self.exact_fallback = read_bool(props, "exact_fallback", True)
        self.trace_ends = read_bool(props, "trace_ends", True)

    @property
    def filter_settings(self) -> FilterSettings:
        return FilterSettings(self.M, self.regions, self.fit_depth, self.exact_bounds)

    # -- rectification: epipolar (template) or projective (§4.2) -------------------
    def choose_rows(self, params, cap):
        """The template's epipolar slices, or the projective map's rows when
        :meth:`~integrators.fourier.rows.projective_plan` returns one (then also the plan);
        the render's ``stats["rectification_used"]`` says which it took."""
        plan = self.projective_plan(params, cap)
        self.record(rectification_used="epipolar" if plan is None else "projective")
        if plan is None:     # Baran's slices, fine enough on small images (fourier.rows)
            frame = epipolar_frame_of(params)
            cam = params.camera
            spacing = row_spacing(self.slice_spacing_for(cap), cam.width, cam.height)
            return frame, choose_slices(frame, self.slices, spacing), None
        return plan.frame, plan.rows.slices, plan

    def projective_plan(self, params, cap) -> "ProjectivePlan | None":
        """:func:`~integrators.fourier.rows.projective_plan` of this render."""
        return projective_plan(params, cap, self.rectification, self.projective_min_angle,
                               self.slices)

    def projective_rays(self, params, queries, plan: "ProjectivePlan",
                        d: int) -> ProjectiveLightRays:
        """``d`` texels per row over the x range of the queries, in
        ``projective_splits`` splits (0: :func:`~rectify.projective.auto_splits`)."""
        return projective_map_rays(params, queries, plan.rows, d, self.projective_splits)

    # -- the method ---------------------------------------------------------------
    def integrate_queries(self, params, cap, queries, plan=None):
        """L_scat of every query (§3, Listing 4); ``plan``: the projective
        map's rows (:meth:`~integrators.fourier.rows.projective_plan`), None: epipolar slices."""
        rect = self.rectified_sums(params, cap, queries, plan)
        with self.stage("unrectify"):
            V_near = near_visibility(queries, rect.rays, rect.beta_b)
            if plan is not None:
                terms = projective_query_terms(params, cap, queries, rect.rays, V_near)
            else:
                terms = light_model(params).query_terms(params, cap, queries, rect.rays,
                                                        rect.colour, V_near)
            # evaluated by the next kernel over the queries, the template's
            # disagreement test (design §5: a stage's result only the next
            # kernel of its width reads)
            value = assemble_queries(terms, rect.integral())
        return value

    def rectified_sums(self, params, cap, queries, plan=None) -> "RectifiedSums":
        """Σ_γ L K V cover per query and colour channel, as the unshadowed
        sum U times the effective visibility V̄ (class doc)."""
        model = light_model(params)
        # frame-wide choices on the whole frame's queries (texel count, light
        # rays, per-light-ray factor, separated kernel, reference-ray length),
        # then the rows of ``queries`` (all, or a partial render's RowSubset)
        whole = queries.whole_frame
        with self.stage("rectify"):
            d = self.light_rays or auto_texels(params, whole, cap)
            if plan is not None:    # Klehm §4.2: texels of equal steps in 1/x
                rays = self.projective_rays(params, whole, plan, d)
            else:   # local lights: Baran §9, γ = angle at the light (Klehm §3.2)
                rays = model.light_rays(params, whole, d)
            # the direct sum takes more of a directional light's light rays
            # behind the eye than a separated kernel resolves
            exact = self.exact_visibility(params)
            side_range = ({"light_side_range": EXACT_LIGHT_SIDE_RANGE}
                          if exact and not model.local else {})
            L, colour, lit = model.light_factor(params, whole, rays, **side_range)
        length = model.light_length(params, whole, cap)
        frame_rays = rays
        rays, L, lit = take_light_rays(queries, rays), take_rows(queries, L), \
            take_rows(queries, lit)
        self.record(dropped_marched=self.march_dropped(params, queries, rays,
                                                       (whole, frame_rays), **side_range))
        A = B = None        # the direct sum needs no separated kernel (its own gives U)
        with self.stage("svd") as keep:
            if exact:
                pass
            elif plan is not None:
                A, B = texel_separated_kernel(model, params, queries, rays,
                                              self.svd_rank, self.svd_tolerance)
            else:    # separated on the whole frame, evaluated at these rows
                A, B = model.separated_kernel(params, queries, rays, self.svd_rank,
                                              self.svd_tolerance, frame_rays=frame_rays,
                                              band_cells=self.band_cells(model, plan))
            keep.extend([] if A is None else [A, B])
        if plan is None:
            # after the separation, whose reads of the queries' domain
            # evaluated the x it reads (no kernel of its own)
            self.record(frame_choices=frame_choices(whole, frame_rays) + (("length", length),))
        with self.stage("rectify"):
            # with the coverage's kernel: the queries' β range and what the
            # query terms (unrectify stage) read of the queries alone
            query_beta_range(queries)
            model.schedule_query_terms(params, cap, queries)
            cover = Coverage.of(queries, rays)
        with self.stage("blockers"):
            beta_b = self.blocker_angles(params, cap, queries, rays, lit)
            smap = self.rectified_map(queries, rays, beta_b,
                                      rows_with=self.reference_rows_of(params, queries, L, A,
                                                                       length))
            if self.regions > 1:
                region_length(rays.d, self.regions)      # ValueError if a region is empty
            # the band's queries with the traced runs' mask (one kernel)
            schedule_band(model, queries, rays, A, cover, self.band_cells(model, plan))
            tail = (tail_visibility(params, cap, queries, rays, beta_b, cover)
                    if self.trace_ends else None)
            self.record(tail_traced=0 if tail is None else tail.traced)
        sigma_t = np.asarray(params.medium.sigma_t, np.float64)
        U, V, Ls, unreliable = [], [], [], None
        C = channels(L, A, sigma_t)
        swept = None        # the unresolved test's sums of A L, read by U too
        with self.stage("evaluate") as keep:
            band = unshadowed_band(model, params, queries, rays, A, B, L, cover,
                                   self.band_cells(model, plan))
            keep.append(band)
            if A is not None and plan is None:
                # samples whose U the separated kernel cannot resolve:
                # marched (the mask made by the ring's kernel over the queries)
                unresolved, swept = unresolved_by_separation(
                    queries, A, B, L, cover, rays if model.kernel_recurrence else None, sigma_t)
                self.march_later("unresolved", unresolved)
        kernels = {}        # the channels of one σt share reference rays and kernels
        parts = [KernelParts.of(queries, rays, L, A, B, c, swept) for c in range(C)]
        sums = self.stacked_channel_sums(params, queries, rays, smap, cover, parts, sigma_t,
                                         length, beta_b, tail, kernels)
        if sums is not None:
            sums, unreliable = sums
        for c in range(C):
            U_c, V_c, bad = (sums[c] if sums is not None else
                             self.channel_sums(params, queries, rays, smap, cover, parts[c],
                                               float(sigma_t[c]), length, beta_b, tail,
                                               kernels))
            U.append(U_c + band[c])
            V.append(V_c)
            Ls.append(parts[c].L)
            if bad is not None and sums is None:
                unreliable = bad if unreliable is None else unreliable | bad
        if unreliable is not None:
            with self.stage("evaluate") as keep:
                V = self.fallback(params, queries, rays, beta_b, cover, Ls,
                                  [float(sigma_t[min(c, len(sigma_t) - 1)]) for c in range(C)],
                                  tail, V, unreliable, with_runs=self.weights == "exact")
                keep.extend(V)
        return RectifiedSums(rays, beta_b, U, V, colour)

    def band_cells(self, model, plan) -> int:
        """The asymptote band of the separated kernel (``ASYMPTOTE_BAND``):
        point/spot lights (``model.local``) on epipolar rows with
        ``weights`` ``average`` or ``reference_ray``,
        whose separated kernel gives U alone (``exact``'s component filters
        have no band correction: 0)."""
        return (self.ASYMPTOTE_BAND if model.local and plan is None and self.weights != "exact"
                else 0)

    def rectified_map(self, queries, rays, beta_b, rows_with=()):
        """The rectified shadow map of the blocker angles (§2.2, §4.1;
        :func:`~integrators.fourier.rectified_map.rectified_shadow_map`, with
        its ``rows_with``): a stage method, so an experiment observes the map
        by overriding it."""
        return rectified_shadow_map(queries, rays, beta_b, self.depth_range, rows_with)

    def reference_rows_of(self, params, queries, L, A, length: float) -> tuple:
        """The rows' arrays of the reference rays the sums will make
        (:func:`~integrators.fourier.references.reference_rows` of each
        channel's σt, ``weights="reference_ray"``), for the map's kernel over
        the rows; () where the sums make none."""
        if self.weights != "reference_ray" or self.exact_visibility(params):
            return ()
        sigma_t = np.asarray(params.medium.sigma_t, np.float64)
        C = channels(L, A, sigma_t)
        out = []
        for s in dict.fromkeys(float(sigma_t[min(c, len(sigma_t) - 1)]) for c in range(C)):
            out += reference_rows(queries, s, length, self.reference_rays).arrays()
        return tuple(out)

    def blocker_angles(self, params, cap, queries, rays, lit=None):
        """β_b per light ray (one ray through each texel's centre): traced
        from the light, or read from a classic shadow map (orthographic,
        perspective or cube by light kind); ``lit``: the local light's
        texels that carry light (the others are not traced)."""
        model = light_model(params)
        if self.blockers == "traced":
            return rays.read_blockers(model.trace_blockers, params, queries, 1, lit=lit)
        shadow_map = capture_shadow_map(params, cap, self.shadowmap_resolution)
        return rays.read_blockers(model.resample_blockers, params, queries, shadow_map, 1)

    def channel_sums(self, params, queries, rays, smap, cover, parts, sigma_t: float,
                     length: float = 0.0, beta_b=None, tail=None, kernels=None):
        """(U, V̄) per query for one colour channel: the unshadowed sum and
        the effective average visibility of ``weights`` (clamped to [0, 1]
        with ``clamp``, Appendix A); ``length``: the decay length of the
        reference rays (the light model's ``light_length``); ``kernels``: a
        dict the channels of one render share, which keeps the reference
        rays and their kernels of each σt (a grey medium's channels differ
        in the light's colour alone)."""
        kernels = {} if kernels is None else kernels
        if self.exact_visibility(params):      # the direct sum (fourier.exact), no series
            with self.stage("evaluate") as keep:
                # U from the query's own kernel too: the separated kernel's
                # error is relative to the row's largest weight, which in a
                # thick medium dwarfs a query's own sum (random stress seed
                # 31: U < 0)
                S, U = exact_sums(params, queries, rays, beta_b, cover, parts.L, sigma_t,
                                  tail=tail)
                V = dr.select(U > 0.0, S / U, 1.0)
                keep.extend([U, V])
            return U, V, None
        # U evaluated with V and the fallback's mask, at the end (one kernel)
        U = parts.unshadowed(cover, queries)
        refs = None
        if self.weights == "reference_ray":
            if ("refs", sigma_t) not in kernels:
                kernels["refs", sigma_t] = reference_rays(queries, sigma_t, length,
                                                          self.reference_rays)
            refs = kernels["refs", sigma_t]
        if self.weights == "exact":
            S_K, S, P, near = self.exact_sum(queries, smap, cover, parts)
            V = dr.select(U > 0.0, S_K / U, 1.0)
        elif refs is not None and refs.count > 1:      # several reference rays per row
            V, S, P, near = self.interpolated_average(params, queries, rays, smap, cover,
                                                      parts.L, sigma_t, refs, beta_b, tail,
                                                      kernels)
        else:
            w = parts.L * (texel_size(rays) if self.weights == "average" else
                           reference_kernel(params, queries, rays, sigma_t, self.reference))
            dr.eval(w)          # read by the filter and every sum of filtered_average
            V, S, P, near = self.filtered_average(queries, smap, cover, w, self.clamp,
                                                  beta_b, tail)
        with self.stage("evaluate") as keep:
            if self.clamp:
                V = dr.clip(V, 0.0, 1.0)
            bad = series_unreliable(near, S, P) if self.exact_fallback else None
            keep.extend([U, V] + ([] if bad is None else [bad]))
        return U, V, bad

    def stacked_channel_sums(self, params, queries, rays, smap, cover, parts, sigma_t,
                             length: float, beta_b=None, tail=None, kernels=None):
        """:meth:`channel_sums` of every colour channel at once (a list of
        their (U, V̄, unreliable)), where the channels share one kernel (a
        grey σt: a textured spot light's colour) and their weights are
        several reference rays' (``weights="reference_ray"``): the
        channels' unshadowed sums in one stack
        (:func:`~integrators.fourier.sums.unshadowed_sums`), their reference
        rays layers of one filter (:func:`~integrators.fourier.layers.layered_average`),
        each channel bit for bit its own :meth:`channel_sums`; with the
        union of their unreliable masks (evaluated with them).  None where
        that does not apply (one channel, a coloured σt, other weights, the
        direct sum, one reference ray): the caller runs :meth:`channel_sums`
        per channel."""
        sigma_t = np.asarray(sigma_t, np.float64)
        if (len(parts) < 2 or not np.all(sigma_t == sigma_t[0])
                or self.weights != "reference_ray" or self.exact_visibility(params)):
            return None
        s = float(sigma_t[0])
        if ("refs", s) not in kernels:
            kernels["refs", s] = reference_rays(queries, s, length, self.reference_rays)
        refs = kernels["refs", s]
        if refs.count <= 1:
            return None
        U = unshadowed_sums(parts, cover, queries)
        band = near_band(self.M) if self.exact_fallback else 0.0
        out = layered_average(params, queries, rays, smap, cover, [p.L for p in parts], s, refs,
                              beta_b, tail, kernels, self.filter_settings, self.clamp, band,
                              self.stage)
        result, unreliable = [], None
        with self.stage("evaluate") as keep:
            for U_c, (V, S, P, near) in zip(U, out):
                if self.clamp:
                    V = dr.clip(V, 0.0, 1.0)
                bad = series_unreliable(near, S, P) if self.exact_fallback else None
                keep.extend([U_c, V])
                result.append((U_c, V, bad))
                if bad is not None:
                    unreliable = bad if unreliable is None else unreliable | bad
            if unreliable is not None:      # the fallback's mask, with them
                keep.append(unreliable)
        return result, unreliable

    def fallback(self, params, queries, rays, beta_b, cover, Ls, sigma_ts, tail, V,
                 unreliable, with_runs: bool = False) -> list:
        """Every channel's ``V`` (lists: per channel L and σt) with the exact
        sum (:func:`~integrators.fourier.exact.exact_sums`, the traced end
        runs included) at the queries ``unreliable`` in any channel, and
        with ``with_runs`` at those whose end run was traced
        (:mod:`integrators.fourier.tail`; ``weights="exact"``, whose
        component filters take no run correction); one pass for all
        channels of a grey medium (their kernel is one);
        ``stats["exact_fallback"]`` counts the queries (a single one is
        summed twice: :func:`~integrators.core.opaque.two_or_more`)."""
        if tail is not None and with_runs:
            unreliable |= tail.runs()
        idx = dr.compress(unreliable)
        self.record(exact_fallback=dr.width(idx))
        if not dr.width(idx):
            return V
        idx = two_or_more(idx)
        groups = ([list(range(len(Ls)))] if len(set(sigma_ts)) == 1 else
                  [[c] for c in range(len(Ls))])
        V = [mi.Float(v) for v in V]
        for group in groups:
            S, P = exact_sums(params, queries, rays, beta_b, cover, [Ls[c] for c in group],
                              sigma_ts[group[0]], tail=tail, idx=idx)
            for c, S_c, P_c in zip(group, S, P):
                # an average of 0s and 1s: [0, 1] but for float32 rounding
                dr.scatter(V[c], dr.clip(dr.select(P_c > 0.0, S_c / P_c, 1.0), 0.0, 1.0), idx)
        return V

    def exact_visibility(self, params) -> bool:
        """The direct sum: ``visibility="exact"``, or the default without filter
        properties for a directional light (point/spot lights keep the
        filter under ``exact_directional``: their kernel per texel and query makes the
        direct sum many times the filter's cost)."""
        if self.visibility_used != "exact":
            return False
        return self.visibility == "exact" or light_model(params).direct_sum_by_default

    def filtered(self, queries, smap, cover, w, clamp: bool, band: bool | None = None):
        """Prefilter the weights ``w`` (one filter; ``prefilter`` stage) and
        evaluate the series visibility of every query (``evaluate``);
        ``band`` True: ``(V, drop)``, also the series' drop across the
        near-step band (:func:`~integrators.fourier.rectified_map.near_step_weight`);
        False: ``(V, 0)``."""
        opt = self.filter_settings
        with self.stage("prefilter") as keep:
            fb = prefilter_rows(smap, w, opt)
            if fb is not None:
                keep.extend([fb.B_bar, fb.W])
        with self.stage("evaluate") as keep:
            if not band:
                V = series_visibility(smap, fb, queries, cover, opt, clamp)
                keep.append(V)
                return V if band is None else (V, dr.zeros(mi.Float, queries.count))
            V, drop = series_visibility(smap, fb, queries, cover, opt, clamp,
                                        near_band(self.M))
            keep.extend([V, drop])
        return V, drop

    def interpolated_average(self, params, queries, rays, smap, cover, L, sigma_t: float,
                             refs, beta_b, tail, kernels: dict):
        """(V̄, S, P, near): the weighted average visibility with the weights
        of each query's mix of its two nearest reference rays
        (:mod:`integrators.fourier.references`), one filter per reference
        ray (layers of one stacked filter, :mod:`integrators.fourier.layers`),
        and its shadowed, unshadowed and near-step weight sums; ``tail``:
        the traced end runs replace the map's visibility
        (:meth:`~integrators.fourier.tail.TailVisibility.correction`);
        ``kernels``: the reference rays' kernels of this σt, kept for the
        other channels (:meth:`channel_sums`)."""
        band = near_band(self.M) if self.exact_fallback else 0.0
        return layered_average(params, queries, rays, smap, cover, L, sigma_t, refs, beta_b,
                               tail, kernels, self.filter_settings, self.clamp, band,
                               self.stage)

    def filtered_average(self, queries, smap, cover, w, clamp: bool, beta_b=None, tail=None):
        """(V̄, S, P, near): the weighted average visibility with one filter of
        weights ``w`` (§3.1, §3.2): (Σ_lit w + Σ_series w · V̄) / Σ w, its
        numerator S, denominator P and near-step weight; ``tail`` as
        :meth:`interpolated_average`."""
        V_series, drop = self.filtered(queries, smap, cover, w, clamp, band=self.exact_fallback)
        lit, series, P = class_and_total_sums(smap, cover, w)
        S = lit + series * V_series
        if tail is not None:
            S += tail.correction(queries, cover, beta_b, w)
        return dr.select(P > 0.0, S / P, 1.0), S, P, near_step_weight(series, drop)

    def exact_sum(self, queries, smap, cover, parts):
        """(S, S_L, P_L, near): S = Σ_n B_n(β) Σ_γ L A_n V cover, every
        component through its own filter with shifted, non-negative weights
        L (A_n + c_n), minus c_n times the filter of weights L (class doc);
        S_L, P_L and near: the shadowed, unshadowed and near-step sums of
        the weights L (what :func:`~integrators.fourier.rectified_map.series_unreliable`
        judges)."""
        V0, drop = self.filtered(queries, smap, cover, parts.L, clamp=False,
                                 band=self.exact_fallback)
        lit_L, series_L, P_L = class_and_total_sums(smap, cover, parts.L)
        S0 = series_L * V0                                      # Σ_series L V
        S = dr.zeros(mi.Float, queries.count)
        for a, b in zip(parts.A, parts.B):
            shift = row_shift(a, smap)
            w = parts.L * (a + dr.gather(mi.Float, shift, smap.texel_row))
            Vn = self.filtered(queries, smap, cover, w, clamp=False)
            lit = cover.sum(dr.select(smap.lit, parts.L * a, 0.0))
            S += b * (lit + series_sum(smap, cover, w, Vn)
                      - dr.gather(mi.Float, shift, queries.row) * S0)
            dr.eval(S)          # one component at a time: the same kernels for any rank
        return S, lit_L + S0, P_L, near_step_weight(series_L, drop)

    def to_string(self):
        return (f"FourierFilterIntegrator[coefficients={self.M}, weights={self.weights}, "
                f"regions={self.regions}, clamp={self.clamp}, fit_depth={self.fit_depth}, "
                f"depth_range={self.depth_range}, rectification={self.rectification}, "
                f"slices={self.slices}, light_rays={self.light_rays}, output={self.output}]")


register_rule("fourier_filter", FILTER_RULE)
mi.register_integrator("fourier_filter", lambda props: FourierFilterIntegrator(props))
