r"""Epipolar rectification shared by ``epipolar_tree`` and ``fourier_filter``
(and in part by ``minmax_epipolar``): Baran et al. 2010, "A Hierarchical
Volumetric Shadow Algorithm for Single Scattering", §3-§9.

Stages, one module each, in pipeline order:

- :mod:`.frame` — the epipolar frame of light and camera, slices, ring;
- :mod:`.queries` — camera samples → queries sorted into rows;
- :mod:`.light_rays` — the light-ray layout of each row (one protocol,
  :mod:`.light_rays.layout`): :mod:`.light_rays.directional` (parallel
  rays) and :mod:`.light_rays.local` (point and spot lights);
- :mod:`.light_factor`, :mod:`.local_light_factor` — the light side of
  each light ray (light-side transmittance, intensity, texture);
- :mod:`.blockers`, :mod:`.local_blockers` — blocker maps (traced or
  resampled) and the sweep's depth modes;
- :mod:`.kernel` — the separated kernel ``Σ aᵢ(γ) bᵢ(β)``
  (:mod:`.kernel.separation` directional, :mod:`.kernel.local` point and
  spot, on :mod:`.kernel.svd` and :mod:`.kernel.table`);
- :mod:`.query_terms`, :mod:`.local_query_terms`, :mod:`.last_interval`
  — the per-query factors and the end of each view ray;
- :mod:`.direct_sum` — a query's unshadowed sum summed directly, the
  check of the separated one where the light side amplifies its error;
- :mod:`.ring` — the brute-force march of the epipole ring, peak rays and
  disagreeing samples;
- :mod:`.light_models` — the dispatch over light kinds that the plugins
  call (the one place that tells a directional light from a local one);
- :mod:`.factor_layout` — the shape of the sweep's factor tensors.

Every camera sample is evaluated at its own view ray and its own depth
(DESIGN §3, "known trap"): nothing is computed per (slice, β-sample) and
interpolated back to pixels.

Geometry (:mod:`rectify` conventions)
-------------------------------------
``o`` is the pinhole (``params.camera.origin``), ``w_l`` the unit direction
*toward* the light (the frame's ``axis``).  A slice α is a half-plane
bounded by the line ``o + u·w_l``; in it a view ray makes the angle β with
``w_l``, a light ray is the line at distance γ from the axis, and the point
at distance ``t`` from ``o`` on view ray β lies on light ray ``γ = t·sin β``
at the axial coordinate ``u = t·cos β = γ·cot β`` (§3, Fig. 3).

Queries (:func:`~integrators.epipolar.queries.assign_queries`)
    Each camera sample whose ray has ``d > 0`` and lies outside the epipole
    ring (§6) is a *query* of its nearest slice (the slice whose α is
    closest to the sample's own α).  Queries are sorted by (slice, β): the
    sweep order of Fig. 6, "from the light away".  Slices without queries
    are dropped; the remaining ones are the *rows* ``0..n-1`` of the
    rectified maps, padded to ``r`` = the largest number of queries of a
    row (``r_count`` per row).  The query keeps its own β and the distance
    ``γ_end = t_end·sin β`` of its end point from the axis
    (``t_end = t_near + d``: the camera ray starts on the near plane,
    ``t_near`` from the pinhole).
Light rays (:func:`~integrators.epipolar.light_rays.directional.light_ray_grid`)
    ``d`` light rays per row spanning ``γ ∈ [0, γ_max]``, ``γ_max`` = the
    largest ``γ_end`` of the row's queries; light ray (leaf) ``g`` covers
    ``[g, g+1)·Δγ``, ``Δγ = γ_max / d``.  A query's depth is the fractional
    light-ray index ``D = γ_end / Δγ`` (§5).
Blocker map (:func:`~integrators.epipolar.blockers.trace_blocker_angles`,
:func:`~integrators.epipolar.blockers.shadow_map_blocker_angles`)
    Light ray γ of slice α is first blocked (coming from the light) at the
    axial coordinate ``u_b``; its points with ``u < u_b`` are in shadow, so
    view ray β is shadowed on it iff ``β > S := atan2(γ, u_b)`` (``S = π``
    when nothing blocks it).  ``traced``: the light rays are ray-traced with
    Mitsuba from outside the scene along ``-w_l`` (exact, no resampling,
    DESIGN §3).  ``resampled``: ``u_b`` is read from a classic orthographic
    :class:`~integrators.core.capture.ShadowMap` (nearest texel), as in the paper.
    Prefiltering (§7, Fig. 7): ``k`` stratified jittered sub-rays per
    light-ray interval give up to ``k`` depth modes of weight ``1/k``.
    :func:`~integrators.epipolar.blockers.blocker_modes` converts blocker angles to the sweep's
    view-ray
    index units: the number of the row's queries with ``β_q ≤ S`` (a mode
    at index ``m`` acts on queries ``m, m+1, ...``, i.e. exactly those with
    ``β_q > S``), merging sub-rays that land on the same index.
Light side (:func:`~integrators.epipolar.light_rays.directional.light_ray_grid`,
:func:`~integrators.epipolar.light_factor.light_side_factor`)
    With the medium box, the light-side path length of a point is
    ``τ = h(α, γ) − u``, ``h`` the axial coordinate where light ray γ leaves
    the box toward the light (DESIGN §1).  Hence

        e^{-σt τ} e^{-σt t} dt = L(γ) · K(γ, β) dγ / sin β,
        L(γ) = e^{-σt h(α, γ)},   K(γ, β) = e^{-σt γ tan(β/2)},

    a per-light-ray factor (the tree's ``L``, "textured light" of §6) times
    a kernel of (γ, β).  ``L`` is sampled at the light ray's centre and
    stored relative to the row's smallest ``h`` (``h_ref``: keeps thick
    media inside float32's range); ``K`` is averaged exactly over the
    light-ray interval: ``K(γ_g, β)·φ(σt tan(β/2) Δγ)``, ``γ_g`` the
    interval's start, ``φ(x) = (1 − e^{-x})/x``
    (:func:`~integrators.epipolar.query_terms.cell_average`).
Per-query terms (:func:`~integrators.epipolar.query_terms.directional_query_terms`,
:func:`~integrators.epipolar.query_terms.assemble_queries`)
    ``L_scat = e^{σt (t_near − h_ref)} σs f_p E [Δγ φ/sin β · Σ_γ L K V cover − N]``:
    Mitsuba's phase function ``f_p`` (``phase_eval``, per query at its own
    ω) and delivered irradiance ``E`` (``sample_light``), the factor
    ``Δγ / sin β`` (``ds/dγ``, §4 Eq. 3), ``N`` the closed-form integral
    over ``[0, t_near]`` between pinhole and near plane (lit as the first
    light ray of the map says,
    :func:`~integrators.epipolar.query_terms.first_leaf_visibility`), which the
    rectified sum includes but the camera ray does not, and
    ``e^{σt t_near}``, which re-bases the camera-side transmittance to the
    ray origin.  The light-ray interval in which the view ray ends counts
    the exact visibility of its covered part where its depth modes are
    mixed (:func:`~integrators.epipolar.last_interval.last_interval_visibility`,
    :func:`~integrators.epipolar.last_interval.last_interval_correction`).
Ring (§6; :func:`~integrators.epipolar.frame.in_ring`,
:func:`~integrators.epipolar.ring.march_ring`)
    Samples whose view ray is within ``ring_deg`` of ``±w_l`` (rectify's
    :func:`~rectify.ring_mask` definition, evaluated at the sample's own
    direction) are ray-marched by brute force with exact (ray-traced)
    visibility, reusing :func:`integrators.core.marching.march`.  View rays
    within ``MIN_RING_RAD`` of the axis are always marched (``sin β → 0``).

Point and spot lights (§9): :func:`~integrators.epipolar.frame.epipolar_frame_of`,
:func:`~integrators.epipolar.queries.assign_queries`, the light-ray offset ``γ_lo`` of
:class:`~integrators.epipolar.light_rays.directional.LightRays`,
:func:`~integrators.epipolar.light_rays.layout.rectified_depth` and the sub-ray and
blocker-mode functions serve
them too, with γ the angle at the light (``rectify`` conventions); the
rest of the local-light maths (blockers traced from the light, intensity,
kernel, per-query terms) is in the point and spot light sections below.
All Dr.Jit on the active variant; NumPy only for small
host-side tables.

Point and spot lights (§9)
==========================

The slices, the queries and the sweep are those of the directional light
(:mod:`integrators.epipolar`); §9 changes the light rays: γ is the
*angle at the light* between the light ray and the direction light -> eye
(:mod:`rectify` conventions).  This module holds what that changes.

Geometry (§9)
-------------
``o`` the pinhole, ``p_l`` the light, ``L = |p_l − o|``, the axis from ``o``
toward ``p_l``.  In slice α, view ray β (angle at ``o`` from the axis) and
light ray γ (angle at ``p_l`` from the direction toward ``o``) meet at the
third corner ``x`` of the triangle (o, p_l, x), whose angle is π − β − γ; by
the law of sines

    t = L sin γ / sin(β+γ)   (from the eye),   r = L sin β / sin(β+γ)   (from the light).

Along view ray β, γ grows from 0 (at the eye) to π − β (at infinity).

Integrand in γ (the §4 change of variables)
-------------------------------------------
``dt/dγ = L sin β / sin²(β+γ)``, hence ``dt / r² = dγ / (L sin β)``: the
1/r² fall-off and the Jacobian cancel up to a per-view-ray factor.  The
angle at ``x`` between −ω and the direction to the light is θ = π − β − γ,
so ``cos θ = −cos(β+γ)`` and the phase function is a function of β+γ.  With
the light-side path ``τ = r − r_in(α, γ)`` (``r_in``: where the light ray
enters the medium box, 0 for a light inside it; ``x`` is always inside)

    L_scat = σs / (L sin β) ∫ I(α,γ) e^{-σt (L − r_in)} · K(γ, β) · V dγ,
    K(γ, β) = e^{-σt (t + r − L)} f_p(β+γ),
    t + r − L = 2L x / (1 − x),   x = tan(β/2) tan(γ/2)

(the half-angle form of ``L (sin β + sin γ − sin(β+γ)) / sin(β+γ)``: exact
and stable; x < 1 ⟺ β+γ < π).  ``I(α, γ)`` is Mitsuba's intensity with the
spot fall-off and projected texture: per light ray, initialised into the
tree like §6's textured light, together with ``e^{-σt (L − r_in)}``
(:func:`~integrators.epipolar.local_light_factor.light_ray_factor`).  For L → ∞ with γ =
γ_dir/L the kernel becomes
the directional ``e^{-σt γ_dir tan(β/2)}``.

Visibility
----------
On light ray γ, ``dr/dβ = L sin γ / sin²(β+γ) > 0``: the distance from the
light grows with β.  A light ray first blocked at ``r_b`` shades exactly
the view rays with ``β > β_b``, β_b = the eye's angle of the blocker point:
the directional rule, so the sweep over increasing β (Fig. 6) needs no
change (:func:`~integrators.epipolar.local_blockers.trace_local_blocker_angles`, traced from
``p_l``;
:func:`~integrators.epipolar.blockers.shadow_map_blocker_angles` with
:func:`~integrators.epipolar.local_blockers.radial_map_point` and
:func:`~integrators.epipolar.local_blockers.radial_blocker_beta`, read from the
perspective/cube shadow map).

Light rays (:func:`~integrators.epipolar.light_rays.local.local_light_ray_grid`)
-----------------------------------------
Row α needs ``[γ_lo, γ_hi]``: ``[0, max γ_end]`` for a point light, clipped
to the spot cone's γ-interval in the slice for a spot light
(:func:`~integrators.epipolar.light_rays.local.cone_interval`; rows outside the cone are dark:
one light ray, no
updates, the sweep's closed form).  Uniform in γ = uniform in ``∫ dt/r²``
(equiangular sampling).  All rows share one lattice ``γ = j·Δγ`` (Δγ: the
widest row's range / (d − 1)); a row starts at a lattice point and has
``d_count ≤ d`` light rays, so the kernel's light-ray factors are computed
once per lattice cell, not once per (row, light ray).

Kernel separation: :mod:`integrators.epipolar.kernel.local`.

Per query (:func:`~integrators.epipolar.local_query_terms.local_query_terms`)
-------------------------------------
``σs·colour·Δγ / (L sin β)`` times the sweep's sum, re-based to the ray
origin (``e^{σt t_near}``), minus the part between pinhole and near plane
(one midpoint sample of the exact integrand, lit as the first leaf says).

Ring (§6): view rays within ``ring_degrees`` of the light or of its
opposite are ray-marched (:func:`~integrators.epipolar.ring.march_ring`).
"""
