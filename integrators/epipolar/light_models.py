"""Light models: every difference between a directional light and a
point/spot light in the epipolar pipeline, behind one interface (DESIGN §3).

The epipolar methods (``epipolar_tree``, ``fourier_filter``) call the stages
of :class:`LightModel` and never branch on the light kind:

=========================  ==================================================
stage                      directional (Baran §3–§7) / point, spot (§9)
=========================  ==================================================
``light_rays``             parallel light rays per slice, γ = distance from
                           the camera–light axis / rays from the light, γ =
                           angle at the light (``epipolar.light_rays.directional.light_ray_grid``
                           / ``epipolar.light_rays.local.local_light_ray_grid``)
``light_factor``           L(γ) = e^{-σt (h − h_ref)} / intensity, fall-off,
                           texture and e^{-σt r} per light ray (§6 "textured
                           light"; ``light_side_factor`` / ``light_ray_factor``)
``trace_blockers``         blocker angle per (sub-)ray traced with Mitsuba
``sub_ray_blockers``       the tree's §7 sub-rays (directional: adaptive)
``resample_blockers``      blockers read from a shadow map, one path
                           (``epipolar.blockers.shadow_map_blocker_angles``) with
                           the model's ``map_point`` / ``map_blocker_beta``:
                           orthographic map, u = 0 / perspective or cube map,
                           distance L from the light
``separated_kernel``       Eq. 4, one path (``epipolar.kernel.separation.separate_kernel``)
                           with the model's ``separation``: K = e^{-σt γ tan(β/2)}
                           at the light rays / the §9 kernel per lattice cell
``query_terms``            per-query factors (1/sin β, phase, σs, radiance)
``light_length``           the length whose mean free paths set the default
                           light-ray count (and ``fourier_filter``'s reference rays)
``ray_kernel``             K of one light ray at any β (``fourier_filter``'s
                           weights and direct sum): e^{-σt γ tan(β/2)} / the
                           §9 kernel's interval mean
``projective``,            flags: Klehm's projective map (parallel rays only),
``kernel_recurrence``,     a geometric kernel over equal rays, and
``direct_sum_by_default``        ``fourier_filter``'s ``visibility=exact_directional``
=========================  ==================================================

Where the maths is one, a stage is one function parametrised by the model
(``separated_kernel``: the weighted SVD and Nyström path with the model's
``separation``; ``resample_blockers``: one shadow-map read with the model's
``map_point`` / ``map_blocker_beta``; the light-side extinction and the
channel layout of ``light_factor``; the rows' γ range and light-ray count
of ``light_rays``).  Where it truly differs the model keeps its own stage:
``light_rays`` (parallel rays, γ a distance, each with its own box exit h /
rays from the light on one lattice of angles, clipped to a spot's cone),
``light_factor`` (e^{-σt h} relative to the row's reference / Mitsuba's
intensity with fall-off and texture times e^{-σt (L − r_in)}),
``trace_blockers`` (traced down from above the scene along −w_l / out of
the light; the directional tree's adaptive §7 sub-rays), ``query_terms``
(1/sin β with the phase a per-query factor / 1/(L sin β) with the phase
inside the kernel) -- their geometry is different, not their code.

:func:`light_model` picks the model of a scene's light.
"""
from __future__ import annotations

import drjit as dr

from .blockers import (axial_blocker_beta, axial_map_point, shadow_map_blocker_angles,
                       trace_blocker_angles, trace_sub_ray_blockers)
from .kernel.local import LocalSeparation, local_ray_kernel
from .kernel.separation import DirectionalSeparation, directional_ray_kernel, separate_kernel
from .light_factor import light_side_factor
from .light_rays.directional import LIGHT_SIDE_RANGE, light_ray_grid
from .light_rays.local import local_light_ray_grid
from .local_blockers import radial_blocker_beta, radial_map_point, trace_local_blocker_angles
from .local_light_factor import light_ray_factor
from .local_query_terms import (asymptote_band_correction, band_queries, local_query_terms,
                                near_nodes, reaches_asymptote_band)
from .query_terms import directional_query_terms


class LightModel:
    """The light-kind stages of the epipolar pipeline (module doc)."""

    #: ``params.light.kind`` values this model serves
    KINDS: tuple = ()
    #: whether the light rays start at the light (point/spot) rather than
    #: running parallel to its direction
    local = False

    def light_length(self, params, queries, cap) -> float:
        """Length over which the medium's mean free paths are counted."""
        raise NotImplementedError

    def light_rays(self, params, queries, d: int, cap=None):
        """``d`` light rays per row (0: automatic); ``cap``: the camera
        capture when the rays must reach its farthest sample."""
        raise NotImplementedError

    def light_factor(self, params, queries, rays, k: int = 1,
                     light_side_range=LIGHT_SIDE_RANGE):
        """(L, colour, lit): the per-light-ray factor, the light's colour when
        L is grey (else None) and the light rays that carry light (None: all);
        ``light_side_range``: a directional light's c (its light rays beyond
        it are left out)."""
        raise NotImplementedError

    def trace_blockers(self, params, queries, rays, k: int = 1, lit=None):
        """Blocker angle of ``k`` sub-rays per light ray, traced."""
        raise NotImplementedError

    def sub_ray_blockers(self, params, queries, rays, k: int, lit=None, adaptive=True):
        """The tree's §7 sub-ray blockers (default: :meth:`trace_blockers`)."""
        return self.trace_blockers(params, queries, rays, k, lit=lit)

    #: the shadow-map kinds (:class:`~integrators.core.capture.ShadowMap`) this model reads
    shadow_maps: tuple = ()

    def map_point(self, frame, alpha, gamma):
        """Where light ray (α, γ) is looked up in a shadow map."""
        raise NotImplementedError

    def map_blocker_beta(self, params, frame, shadow_map, alpha, gamma, z_b):
        """The eye's β of the blocker at map depth ``z_b`` on light ray (α, γ)."""
        raise NotImplementedError

    def resample_blockers(self, params, queries, rays, shadow_map, k: int = 1):
        """Blocker angle of ``k`` sub-rays per light ray from a shadow map
        (one path for both kinds,
        :func:`~integrators.epipolar.blockers.shadow_map_blocker_angles`)."""
        return shadow_map_blocker_angles(params, queries, rays, shadow_map, self, k)

    #: the light kind's stages of the kernel separation (:func:`~integrators.epipolar.kernel.separation.separate_kernel`)
    separation = None

    def separated_kernel(self, params, queries, rays, rank: int, tol: float, frame_rays=None,
                         band_cells: int = 0):
        """(A, B): the separated kernel at the light rays and the queries
        (one path for both kinds, :func:`~integrators.epipolar.kernel.separation.separate_kernel`;
        ``frame_rays``: the whole frame's light rays when ``queries`` and
        ``rays`` are some of its rows; ``band_cells``: the local light's
        banded kernel, :meth:`band_correction`)."""
        return separate_kernel(self.banded(band_cells), params, queries, rays, rank, tol,
                               frame_rays=frame_rays)

    def banded(self, band_cells: int):
        """The separation with an asymptote band of ``band_cells`` light-ray
        cells (only the local light has one)."""
        return self.separation

    def band_correction(self, params, queries, rays, A, B, L, modes, last, band_cells: int):
        """What the sweep's sum of each query misses in the asymptote band
        of a banded kernel (0: no band)."""
        return 0.0

    def schedule_band(self, queries, rays, last, band_cells: int) -> None:
        """Schedule what :meth:`band_correction` will read of the queries
        alone (evaluated by the next kernel over them; nothing by default)."""

    def band_for(self, params, queries, rays, band_cells: int) -> int:
        """The asymptote band a render needs: ``band_cells`` where some
        query reaches it, else 0 (only the local light has one)."""
        return 0

    def query_terms(self, params, cap, queries, rays, colour, V_near):
        """Per-query factors of the integral."""
        raise NotImplementedError

    def schedule_query_terms(self, params, cap, queries) -> None:
        """Schedule what :meth:`query_terms` will read of the queries alone
        (evaluated by the next kernel over them; nothing by default)."""

    def ray_kernel(self, params, queries, rays, sigma_t: float):
        """K of light ray t at tan(β/2), as a callable ``(t, tan)`` (the
        reference-ray weights and the direct sum of ``fourier_filter``)."""
        raise NotImplementedError

    #: whether the kernel is geometric over equally wide light rays
    #: (e^{-c γ_{g+1}} = e^{-c γ_g} e^{-c Δγ}), so a direct sum may step it
    kernel_recurrence = False
    #: whether Klehm's projective rectification (§4.2, parallel light rays) applies
    projective = False
    #: whether ``fourier_filter``'s default ``visibility="exact_directional"`` takes the direct
    #: sum (cheap where the kernel is a recurrence) rather than the filter
    direct_sum_by_default = False


class Directional(LightModel):
    """A directional light (Baran §3–§7; DESIGN §1)."""
    KINDS = ("directional",)
    separation = DirectionalSeparation()
    ray_kernel = staticmethod(directional_ray_kernel)
    kernel_recurrence = True
    projective = True
    direct_sum_by_default = True
    shadow_maps = ("ortho",)
    map_point = staticmethod(axial_map_point)
    map_blocker_beta = staticmethod(axial_blocker_beta)

    def light_length(self, params, queries, cap):
        return float(dr.max(queries.gamma_end)[0])

    def light_rays(self, params, queries, d, cap=None):
        return light_ray_grid(params, queries, d)

    def light_factor(self, params, queries, rays, k=1, light_side_range=LIGHT_SIDE_RANGE):
        return light_side_factor(params, queries, rays, light_side_range), None, None

    def trace_blockers(self, params, queries, rays, k=1, lit=None):
        return trace_blocker_angles(params, queries, rays, k)

    def sub_ray_blockers(self, params, queries, rays, k, lit=None, adaptive=True):
        return trace_sub_ray_blockers(params, queries, rays, k, adaptive=adaptive)

    def query_terms(self, params, cap, queries, rays, colour, V_near):
        return directional_query_terms(params, cap, queries, rays, V_near)


class Local(LightModel):
    """A point or spot light (Baran §9)."""
    KINDS = ("point", "spot")
    local = True
    light_factor = staticmethod(light_ray_factor)
    separation = LocalSeparation()
    ray_kernel = staticmethod(local_ray_kernel)
    shadow_maps = ("persp", "cube")
    map_point = staticmethod(radial_map_point)
    map_blocker_beta = staticmethod(radial_blocker_beta)
    query_terms = staticmethod(local_query_terms)

    def light_length(self, params, queries, cap):
        return float(dr.max(queries.t_near)[0]) + float(dr.max(cap.d)[0])

    def light_rays(self, params, queries, d, cap=None):
        t_end_max = 0.0 if cap is None else self.light_length(params, queries, cap)
        return local_light_ray_grid(params, queries, d, t_end_max)

    def trace_blockers(self, params, queries, rays, k=1, lit=None):
        return trace_local_blocker_angles(params, queries, rays, k, lit=lit)

    def banded(self, band_cells):
        return LocalSeparation(band_cells) if band_cells else self.separation

    def band_correction(self, params, queries, rays, A, B, L, modes, last, band_cells):
        return asymptote_band_correction(params, queries, rays, A, B, L, modes, last, band_cells)

    def band_for(self, params, queries, rays, band_cells):
        return band_cells if reaches_asymptote_band(params, queries, rays, band_cells) else 0

    def schedule_band(self, queries, rays, last, band_cells):
        if band_cells:
            band_queries(queries, rays, last, band_cells)

    def schedule_query_terms(self, params, cap, queries):
        near_nodes(params, cap, queries)


MODELS = (Directional(), Local())


def light_model(params) -> LightModel:
    """The :class:`LightModel` of the scene's light."""
    for model in MODELS:
        if params.light.kind in model.KINDS:
            return model
    raise ValueError(f"No epipolar light model for a '{params.light.kind}' light; "
                     "use a directional, point or spot emitter.")
