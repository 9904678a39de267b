"""Brute-force ray marching: the baseline every paper compares against.

Each camera ray ``x(t) = o + t·ω``, ``t ∈ [0, d]`` (from where it enters the
medium when the camera is outside it) is cut into ``steps`` equal segments; on segment ``k`` the light term is evaluated at one point
(the midpoint, or a per-ray jittered offset) and multiplied by the exact
integral of the camera-side transmittance over the segment:

    L_scat ≈ Σ_k  σs · f_p(θ) · L_light(x_k) · e^{-σt τ(x_k)} · V(x_k)
                  · ∫_{t_k}^{t_{k+1}} e^{-σt t} dt

(DESIGN §1; Baran 2010 §2 and Klehm 2014 §2 use it as their reference.)
``V`` comes from a shadow map (the papers' baseline) or from a ray test at
every step (``visibility="exact"``: deterministic, noise-free, the project's
working reference once it agrees with ``volpath``).

Properties (besides the template's ``output``, ``samples_per_pixel``):

=========================  ==================================================
``steps``                  segments per camera ray (default 256)
``visibility``             ``shadowmap`` (default) or ``exact``
``shadowmap_resolution``   texels per side (per cube face) (default 2048)
``jitter``                 jitter the sample inside each segment with one
                           random offset per ray (default false: midpoints)
``spacing``                ``uniform`` segments, ``equiangular`` (uniform in
                           the angle seen from a point/spot light: short
                           segments where 1/r² peaks), ``cone`` (spot:
                           equiangular inside the spot's cone alone) or
                           ``auto`` (default:
                           equiangular for point/spot, uniform otherwise)
``march``                  ``full`` (default) or ``hybrid`` (Wyman & Ramsey
                           2008, :mod:`integrators.core.hybrid_march`: exact
                           visibility traced only inside the occluders'
                           bounded shadow volumes; needs ``visibility=exact``)
``volume_boxes``           boxes per occluder mesh bounding its shadow
                           volume for ``hybrid`` (default 8)
``boundary_bisections``    0 (default: the light term at one point per
                           segment) or the bisections that locate each
                           segment's shadow and cone edges
                           (:func:`~integrators.core.marching.march_bisected`;
                           needs ``visibility=exact``, ``march=full``, no
                           ``jitter``): a thin shaft's lit length is then
                           exact, not a whole number of segments
=========================  ==================================================
"""
from __future__ import annotations

import mitsuba as mi

from .core.capture import capture_shadow_map
from .core.hybrid_march import shadow_range
from .core.march_quality import MARCH_RULE
from .core.marching import auto_spacing, march, march_bisected
from .core.properties import read_bool, read_choice, read_number
from .core.quality_auto import register_rule
from .template.base import EpiscatterIntegrator


class RaymarchIntegrator(EpiscatterIntegrator):
    def read_properties(self, props):
        self.steps = read_number(props, "steps", 256, minimum=1, integer=True)
        self.visibility = read_choice(props, "visibility", "shadowmap", ("shadowmap", "exact"))
        self.shadowmap_resolution = read_number(props, "shadowmap_resolution", 2048,
                                                minimum=1, maximum=32768, integer=True)
        self.jitter = read_bool(props, "jitter", False)
        self.spacing = read_choice(props, "spacing", "auto",
                                   ("auto", "uniform", "equiangular", "cone"))
        self.march = read_choice(props, "march", "full", ("full", "hybrid"))
        self.volume_boxes = read_number(props, "volume_boxes", 8, minimum=1, integer=True)
        self.boundary_bisections = read_number(props, "boundary_bisections", 0, minimum=0,
                                               maximum=40, integer=True)
        if self.boundary_bisections and (self.visibility != "exact" or self.march != "full"
                                         or self.jitter):
            raise ValueError("Property 'boundary_bisections' bisects ray-traced visibility "
                             "along each camera ray: set visibility='exact', march='full' and "
                             "jitter=false (or boundary_bisections=0).")
        if self.march == "hybrid" and self.visibility != "exact":
            raise ValueError("Property 'march' = 'hybrid' traces exact visibility inside the "
                             "shadow volumes: set visibility='exact' (or march='full').")

    def samples_alone(self, params):
        """With exact visibility each sample is marched from its own ray
        alone (the jitter is keyed by the sample's index); a shadow map is
        fitted to what the whole frame sees."""
        return self.visibility == "exact"

    def widen_samples(self, params, cap, mask, moved=None):
        """Per sample: each sample is marched along its own ray (a shadow map
        is fitted to the whole capture, ``cap.whole()``)."""
        return mask

    def reuse_refusal(self):
        if self.visibility != "exact":
            return ("raymarch with visibility='shadowmap' fits its map to what the whole frame "
                    "sees and reads it with 2x2 PCF, so an object moving elsewhere changes "
                    "samples the change mask keeps: use visibility='exact' (march='hybrid' "
                    "for speed) or reuse=False.")
        return None

    def scattering(self, params, cap):
        cap = cap.entered()             # a camera outside the medium: from each ray's entry
        shadow_map = None
        if self.visibility == "shadowmap":
            with self.stage("shadowmap"):
                shadow_map = capture_shadow_map(params, cap, self.shadowmap_resolution)
        spacing = auto_spacing(params) if self.spacing == "auto" else self.spacing
        t_range = None
        if self.march == "hybrid":
            with self.stage("shadow_volumes") as keep:
                t_range = shadow_range(params, cap, self.volume_boxes)
                keep.extend(t_range)
        if self.boundary_bisections:
            return march_bisected(params, cap, self.steps, self.boundary_bisections, spacing)
        return march(params, cap, self.steps, shadow_map, self.jitter, self.render_record.seed,
                     spacing, t_range)
register_rule("raymarch", MARCH_RULE)
mi.register_integrator("raymarch", lambda props: RaymarchIntegrator(props))
