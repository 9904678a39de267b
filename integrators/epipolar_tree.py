"""epipolar_tree: Baran et al. 2010, "A Hierarchical Volumetric Shadow
Algorithm for Single Scattering" (epipolar rectification + incremental
partial-sum tree).  The shared rectified maps live in
:mod:`integrators.epipolar.queries`, the point/spot-light maths (§9) in
:mod:`integrators.epipolar.kernel.local`, the sweep kernel in
:mod:`integrators.tree.partial_sum_tree`, the separation of the integrand in
:mod:`integrators.epipolar.kernel.svd`.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .core.capture import capture_shadow_map
from .core.properties import read_bool, read_choice, read_number
from .core.quality_auto import register_rule
from .epipolar.blockers import blocker_modes
from .epipolar.direct_sum import direct_unshadowed
from .epipolar.last_interval import (last_interval_correction, last_interval_visibility,
                                     sweep_magnitude, unresolved_samples)
from .epipolar.light_models import light_model
from .epipolar.light_rays.layout import rectified_depth
from .epipolar.queries import beta_map, gather_queries
from .epipolar.query_terms import assemble_queries, first_leaf_visibility
from .partial.row_subset import frame_choices, take_light_rays, take_rows
from .template.epipolar import EpipolarIntegrator
from .tree.partial_sum_tree import integrate_slices
from .tree.quality import TREE_RULE


@dataclass(frozen=True, eq=False)
class LightSide:
    """What the ``rectify`` stage leaves for the blockers and the sweep:
    the light rays, L per light ray, the light's colour when L is grey
    (else None), the light rays that carry light (None: all), D, and the
    asymptote band the frame's separated kernel needs (cells; 0: none)."""
    rays: object
    L: mi.TensorXf
    colour: object
    lit: object
    D: mi.TensorXf
    band: int = 0

    def of_rows(self, queries) -> "LightSide":
        """The light side of the rows of ``queries`` (a
        :class:`~integrators.partial.row_subset.RowSubset`; a whole frame: itself)."""
        return LightSide(take_light_rays(queries, self.rays), take_rows(queries, self.L),
                         self.colour, take_rows(queries, self.lit), take_rows(queries, self.D),
                         self.band)


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
       Point/spot lights (§9, :mod:`integrators.epipolar.kernel.local`): γ is
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
       :mod:`integrators.tree.partial_sum_tree`; slices without blockers take its
       closed form.
    4. *Ring* (§6): samples within ``ring_degrees`` of the epipole (or the
       anti-epipole) are ray-marched with exact visibility (point/spot: those
       within a pixel's angle of the light with 8× ``ring_steps``: the 1/r²
       peak); so are the samples whose two slices disagree
       (``remarch_disagreement``: a shaft edge or a narrow beam running
       along the slices); and so are the samples whose sums the separated
       kernel does not resolve (:func:`~integrators.epipolar.last_interval.unresolved_samples`:
       the unshadowed sum below 1e-2 of its terms' magnitude, e.g. a thick
       medium seen away from a light whose light-side path shrinks along
       the slices; ``stats["unresolved"]`` counts them).

    Beyond the paper (all measured against ``raymarch visibility=exact``):
    light-side attenuation in the medium box; anisotropic phase functions;
    the SVD sample is taken on log-spaced grids with γ-quadrature weights
    and each view ray's kernel normalised (the paper's uniform grid loses
    10× accuracy in thick media and near the anti-epipole,
    :func:`~integrators.epipolar.kernel.separation.separate_channel`); each light-ray interval
    holds the exact mean
    of K over it, not a midpoint sample (:func:`~integrators.epipolar.query_terms.cell_average`).

    =========================  =============================================
    ``slices``                 number of epipolar slices; 0 (default):
                               automatic, Baran's sinh distribution (§8)
                               with lines at most ``slice_spacing`` px
                               apart (default 1: every pixel within half a
                               pixel of a slice)
    ``slice_spacing``          the automatic slices' largest spacing [px]
                               (default 1 at one sample per pixel, 1/√spp
                               with spp jittered samples per pixel: the
                               slices follow the samples; 2: about half
                               the slices, as
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
                               the image diagonal in pixels (≥ 256), more
                               in thick media (4 per mean free path, ≤ 4096)
                               and where the light-side depth changes by
                               more than 1/4 mean free path per light ray
                               (directional: a grazing face,
                               :func:`~integrators.epipolar.light_rays.directional.light_side_step`);
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
    ``ring_bisections``        bisections of the shadow/cone edges on the
                               ring's and re-marched samples' segments
                               (default 4; 0: midpoint rule)
    ``prefilter``              sub-rays k per light ray for the depth modes
                               of §7 (default 4; 1 = off, one ray through
                               the light ray's centre)
    ``adaptive_prefilter``     trace the sub-rays only where the blockers
                               at the light-ray boundaries are not smooth,
                               interpolate them elsewhere (default true;
                               foliage rows are traced in full,
                               :func:`~integrators.epipolar.blockers._smooth_intervals`)
    ``remarch_disagreement``   with ``slice_interpolation``: a camera
                               sample whose two slices' values differ by
                               more than this fraction of the larger (and
                               of 1e-2 of the frame's largest) is
                               ray-marched like the ring instead (default
                               0.25; 1: never).  A shaft edge or a narrow
                               spot beam running along the slices falls
                               between them; ``stats["remarched"]`` counts
                               these samples
    ``blockers``               ``traced`` (default): light rays traced with
                               Mitsuba; ``resampled``: blockers read from an
                               orthographic shadow map (as the paper)
    ``shadowmap_resolution``   texels per side for ``resampled`` (2048)
    =========================  =============================================

    Plus the template's ``output``, ``samples_per_pixel``, ``jitter_pixels``.
    ``RenderResult.timings`` splits the scattering stage into ``rectify``,
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
    than the near plane).  ``blockers="resampled"`` adds the shadow
    map's texel size (orthographic, perspective or cube map by light kind).

    Baran, Chen, Ragan-Kelley, Durand, Lehtinen: A Hierarchical Volumetric
    Shadow Algorithm for Single Scattering, ACM TOG 29(6), 2010.
    Fenwick: A new data structure for cumulative frequency tables, 1994.
    """

    RENAMED_PROPERTIES = {"rectification": "blockers"}

    SLICE_INTERPOLATION = True
    ROW_SUBSETS = True
    #: point/spot lights: light-ray cells before each view ray's asymptote
    #: in which the sweep's separated kernel is replaced by the exact cell
    #: means per query (:class:`~integrators.epipolar.kernel.local.LocalSeparation`)
    ASYMPTOTE_BAND = 2

    def read_method_properties(self, props):
        self.prefilter = read_number(props, "prefilter", 4, minimum=1, maximum=16, integer=True)
        self.blockers = read_choice(props, "blockers", "traced", ("traced", "resampled"))
        self.adaptive_prefilter = read_bool(props, "adaptive_prefilter", True)

    def reuse_refusal(self):
        if self.blockers == "resampled":
            return ("epipolar_tree with blockers='resampled' reads its blockers from a "
                    "shadow map fitted to what the whole frame sees, so an object moving "
                    "elsewhere changes slices the reuse keeps: use blockers='traced' "
                    "(the default) or reuse=False.")
        return None

    # -- the method ---------------------------------------------------------------
    def integrate_queries(self, params, cap, queries, plan=None):
        return self.sweep_queries(params, cap, queries)

    def sweep_queries(self, params, cap, queries):
        """L_scat of every query (§3-§7; point/spot lights: §9,
        :mod:`integrators.epipolar.kernel.local`).

        The interval in which a view ray ends is not lit by its leaf's §7
        depth modes, whose sub-rays beyond the end point sample the ray's
        continuation behind the surface, but -- where those modes are mixed
        -- by exact shadow rays from the covered part of the query's own ray
        (:func:`~integrators.epipolar.last_interval.last_interval_visibility`,
        inside the ``unrectify`` stage); the render's
        ``stats["last_interval_traced"]``: how many of its
        ``stats["query_count"]`` queries traced them."""
        model = light_model(params)
        # frame-wide choices on the whole frame's queries, then the rows of
        # ``queries`` (all of them, or a partial render's RowSubset)
        whole = queries.whole_frame
        frame_side = self.light_side(params, cap, whole, model)
        band = frame_side.band
        self.record(frame_choices=frame_choices(whole, frame_side.rays) + (("band", band),),
                    asymptote_band=band)
        side = frame_side.of_rows(queries)
        # these rows' samples that meet a light ray the light-side factor left out
        self.record(dropped_marched=self.march_dropped(params, queries, side.rays,
                                                       (whole, frame_side.rays)))
        with self.stage("svd") as keep:
            # separated on the whole frame, evaluated at these rows
            A, B = model.separated_kernel(params, queries, side.rays, self.svd_rank,
                                          self.svd_tolerance, frame_rays=frame_side.rays,
                                          band_cells=band)
            keep.extend([A, B])
        modes = self.blocker_stage(params, cap, queries, side)
        rays, L, D = side.rays, side.L, side.D
        with self.stage("sweep") as keep:
            # the counts as they are (the sweep converts them where it reads them)
            integral = integrate_slices(D, modes, A, B, L=L, r_count=queries.r_count,
                                        d_count=rays.d_count if model.local else None)
            keep.append(integral)
        with self.stage("unrectify") as keep:
            # the last, partial light-ray interval of each query: ray-traced
            # where its leaf's depth modes are uncertain (§5 lerp, §7 modes;
            # epipolar.last_interval.last_interval_visibility), the sweep's integral
            # corrected by the difference
            last = last_interval_visibility(params, cap, queries, rays, modes, D,
                                            self.prefilter)
            V0 = first_leaf_visibility(queries, modes, last)
            terms = model.query_terms(params, cap, queries, rays, side.colour, V0)
            terms.last = (last_interval_correction(queries, A, B, L, last)
                          + model.band_correction(params, queries, rays, A, B, L, modes, last,
                                                  band))
            terms.magnitude, unshadowed = sweep_magnitude(queries, A, B, L, last)
            value = assemble_queries(terms, gather_queries(queries, integral))
            # sums the separated kernel does not resolve: ray-marched by the
            # template with the samples it re-marches anyway (remarch_disagreeing)
            direct = (direct_unshadowed(queries, rays, L, last, params.medium.sigma_t)
                      if model.kernel_recurrence else None)
            unresolved = unresolved_samples(queries, unshadowed, terms.magnitude, direct)
            keep.extend([value, unshadowed, terms.magnitude, unresolved])
        self.record(last_interval_traced=last.traced, query_count=queries.count,
                    unresolved=self.march_samples(unresolved))
        return value

    # -- stages (each timed; an experiment may call or override them) -------------
    def light_side(self, params, cap, queries, model) -> "LightSide":
        """Stage ``rectify`` (after the queries): the light rays of every
        slice, the per-light-ray factor L (§6), the rectified depth D and
        the asymptote band (only where some view ray of the frame reaches
        it; its test, with the other reads of the queries, in one kernel
        with the blockers' map of the queries' β)."""
        with self.stage("rectify") as keep:
            rays = model.light_rays(params, queries, self.light_rays, cap)
            L, colour, lit = model.light_factor(params, queries, rays, self.prefilter)
            D = rectified_depth(queries, rays)
            dr.schedule(D.array)
            beta_map(queries)       # the blockers' map of the queries' β, with D
            band = model.band_for(params, queries, rays, self.ASYMPTOTE_BAND)
            keep.extend([D.array, L.array])
        return LightSide(rays, L, colour, lit, D, band)

    def blocker_stage(self, params, cap, queries, side: "LightSide"):
        """Stage ``blockers``: the blocker map S and its §7 depth modes."""
        with self.stage("blockers") as keep:
            beta_b = self.blocker_angles(params, cap, queries, side.rays, side.lit)
            modes = blocker_modes(queries, side.rays, beta_b, self.prefilter)
            keep.extend([modes.beta, modes.weight])
        return modes

    def blocker_angles(self, params, cap, queries, rays, lit=None):
        """The blocker map S (§3, §7 sub-rays): traced with Mitsuba, or read
        from a classic shadow map (``blockers="resampled"``)."""
        model = light_model(params)
        if self.blockers == "traced":
            return model.sub_ray_blockers(params, queries, rays, self.prefilter, lit=lit,
                                          adaptive=self.adaptive_prefilter)
        shadow_map = self.shadow_map(params, cap)
        return model.resample_blockers(params, queries, rays, shadow_map, self.prefilter)

    def shadow_map(self, params, cap):
        """The classic shadow map of ``blockers="resampled"``."""
        return capture_shadow_map(params, cap, self.shadowmap_resolution)

    def to_string(self):
        return (f"EpipolarTreeIntegrator[slices={self.slices}, light_rays={self.light_rays}, "
                f"svd_rank={self.svd_rank}, prefilter={self.prefilter}, "
                f"blockers={self.blockers}, output={self.output}]")


register_rule("epipolar_tree", TREE_RULE)
mi.register_integrator("epipolar_tree", lambda props: EpipolarTreeIntegrator(props))
