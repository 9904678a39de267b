"""Per-query terms of a directional light: phase function, irradiance, the
light-ray kernel's cell average and the near-plane correction, and their
assembly with the rectified sum (Baran et al. 2010 §4 Eq. 3; DESIGN §1).
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.capture import CameraCapture
from ..core.light_transport import color, phase_eval, point, sample_light, segment_weight, vector
from .blockers import BlockerModes, leaf_visibility
from .last_interval import SWEEP_RESIDUE_EPS, LastInterval
from .light_rays.directional import LightRays, axial_exit
from .queries import EpipolarQueries


# --------------------------------------------------------------------------
# Per-query terms and the way back to camera samples
# --------------------------------------------------------------------------

@dataclass(eq=False)
class QueryTerms:
    """Per-query factors of the directional-light formulation (:mod:`integrators.epipolar`, "Per-query terms");
    ``last``: the change of the rectified integral when the last, partial
    light-ray interval takes the visibility of
    :func:`~integrators.epipolar.last_interval.last_interval_visibility`
    instead of its leaf's
    (:func:`~integrators.epipolar.last_interval.last_interval_correction`; 0: none)."""
    radiance: mi.Color3f    # σs · f_p · E · e^{-σt h_ref} · e^{σt t_near}
    view: mi.Color3f        # Δγ / sin β · φ(σt tan(β/2) Δγ)
    near: mi.Color3f        # V · ∫ over [0, t_near] of e^{-σt (h(0) − h_ref)} e^{-σt t(1−cos β)} dt
    last: object = 0.0      # f · (V_last − V_leaf) · Σ_i B_i(β) A_i(k0) L(k0), integral units
    magnitude: object = None  # Σ_{γ<D} Σ_i |A_i L| |B_i(β)| (sweep_magnitude); None: no flush


def first_leaf_visibility(queries: EpipolarQueries, modes: BlockerModes,
                          last: "LastInterval | None" = None) -> mi.Float:
    """V(γ ∈ leaf 0, β_q) per query from the blocker modes: the visibility of
    the rectified map next to the eye, which the sweep applies to the part
    of the view ray in front of the near plane.  With ``last``
    (:func:`~integrators.epipolar.last_interval.last_interval_visibility`), queries whose view
    ray ends in leaf
    0 take the last interval's visibility instead: the near segment is part
    of that interval and must be removed with the visibility it was counted
    with."""
    V = leaf_visibility(queries, modes, 0)
    if last is not None:
        V = dr.select(last.k0 == 0, last.V, V)
    return V


def cell_average(x):
    """φ(x) = (1 − e^{-x}) / x (φ(0) = 1), stable for every x ≥ 0: the mean
    of e^{-c(γ − γ_g)} over a light-ray interval [γ_g, γ_g + Δγ], x = c·Δγ."""
    small = x < 1e-2
    xs = dr.select(small, 1.0, x)
    series = 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0)))
    return dr.select(small, series, (1.0 - dr.exp(-xs)) / xs)


def directional_query_terms(params, cap: CameraCapture, queries: EpipolarQueries,
                            rays: LightRays, V_near=1.0) -> QueryTerms:
    """Per-query factors (:mod:`integrators.epipolar`, "Per-query terms");
    ``V_near``: visibility of the segment between pinhole and near plane
    (:func:`first_leaf_visibility`)."""
    sigma_t = color(params.medium.sigma_t)
    omega = dr.gather(mi.Vector3f, cap.omega, queries.sample)
    o = dr.gather(mi.Point3f, cap.o, queries.sample)
    wo, _, E = sample_light(params, o)
    f_p = phase_eval(params, omega, wo)
    h_ref = dr.gather(mi.Float, rays.h_ref, queries.row)
    # e^{-σt h_ref}: L's reference (light_side_factor); e^{σt t_near}: the
    # camera-side transmittance counted from the ray origin, not the pinhole
    radiance = color(params.medium.sigma_s) * f_p * E * dr.exp(sigma_t * (queries.t_near - h_ref))
    dg = dr.gather(mi.Float, rays.delta_gamma, queries.row)
    view = dg / dr.sin(queries.beta) * cell_average(sigma_t * dr.tan(0.5 * queries.beta) * dg)
    h0, _ = axial_exit(params, mi.Point3f(point(params.camera.origin)),
                        vector(queries.frame.axis))
    one_minus_cos = 1.0 - dr.dot(omega, wo)
    near = V_near * dr.exp(-sigma_t * (h0 - h_ref)) * segment_weight(sigma_t * one_minus_cos,
                                                                       0.0, queries.t_near)
    return QueryTerms(radiance, view, near)


def assemble_queries(terms: QueryTerms, integral: mi.Color3f) -> mi.Color3f:
    """L_scat per query from the rectified integral Σ_γ L K V cover (plus
    ``terms.last``, the last-interval correction)."""
    bracket = terms.view * (integral + terms.last) - terms.near
    if terms.magnitude is not None:
        # below the rounding error of its own parts: a fully shadowed ray's
        # float32 residue (sweep_magnitude), exactly 0
        scale = terms.view * (terms.magnitude + dr.abs(terms.last)) + dr.abs(terms.near)
        bracket = dr.select(dr.abs(bracket) <= SWEEP_RESIDUE_EPS * scale, 0.0, bracket)
    value = terms.radiance * bracket
    # e^{-σt h_ref} ≤ e^{c} (row_reference), but e^{σt t_near} overflows
    # when the near clip plane lies more than 88 mean free paths from the
    # eye; the sum it multiplies has underflowed to 0 by then, and the
    # query is returned as 0, not NaN (results/stability, scale 1e4).
    return dr.select(dr.isfinite(terms.radiance), dr.maximum(value, 0.0), 0.0)
