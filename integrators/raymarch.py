"""Brute-force ray marching: the baseline every paper compares against.

Each camera ray ``x(t) = o + t·ω``, ``t ∈ [0, d]`` is cut into ``steps``
equal segments; on segment ``k`` the light term is evaluated at one point
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
                           segments where 1/r² peaks) or ``auto`` (default:
                           equiangular for point/spot, uniform otherwise)
``march``                  ``full`` (default) or ``hybrid`` (Wyman & Ramsey
                           2008, :mod:`integrators.hybrid_march`: exact
                           visibility traced only inside the occluders'
                           bounded shadow volumes; needs ``visibility=exact``)
``volume_boxes``           boxes per occluder mesh bounding its shadow
                           volume for ``hybrid`` (default 8)
=========================  ==================================================
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .capture import capture_shadow_map, seed_offset
from .hybrid_march import shadow_range
from .light_transport import (color, light_transmittance, phase_eval, sample_light,
                              segment_box, segment_weight, visible_exact)
from .template import EpiscatterIntegrator, read_choice, read_number


class RaymarchIntegrator(EpiscatterIntegrator):
    def read_properties(self, props):
        self.steps = read_number(props, "steps", 256, minimum=1, integer=True)
        self.visibility = read_choice(props, "visibility", "shadowmap", ("shadowmap", "exact"))
        self.shadowmap_resolution = read_number(props, "shadowmap_resolution", 2048,
                                                minimum=1, maximum=32768, integer=True)
        self.jitter = bool(props.get("jitter", False))
        self.spacing = read_choice(props, "spacing", "auto", ("auto", "uniform", "equiangular"))
        self.march = read_choice(props, "march", "full", ("full", "hybrid"))
        self.volume_boxes = read_number(props, "volume_boxes", 8, minimum=1, integer=True)
        if self.march == "hybrid" and self.visibility != "exact":
            raise ValueError("Property 'march' = 'hybrid' traces exact visibility inside the "
                             "shadow volumes: set visibility='exact' (or march='full').")

    def scattering(self, params, cap):
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
        return march(params, cap, self.steps, shadow_map, self.jitter, self.render_seed,
                     spacing, t_range)


def auto_spacing(params) -> str:
    """Equiangular segments for point/spot lights, uniform for directional."""
    return "uniform" if params.light.kind == "directional" else "equiangular"


def step_boundaries(params, cap, steps, spacing):
    """t(s) for s in [0, steps]: where segment k = [t(k), t(k+1)] lies on each
    camera ray.  ``uniform``: t = d·s/steps.  ``equiangular`` (point/spot
    lights; Kulla & Fajardo 2012): uniform in the angle θ subtended at the
    light, t = t0 + b·tan θ (t0: the ray's closest approach to the light, b:
    its distance), so segments shrink where 1/r² peaks."""
    d = cap.d
    if spacing == "uniform" or params.light.position is None:
        return lambda s: d * (s / steps)
    p_l = mi.Point3f(*map(float, params.light.position))
    q = mi.Vector3f(p_l - cap.o)
    t0 = dr.dot(q, cap.omega)
    b = dr.norm(q - cap.omega * t0)
    ok = b > 1e-6 * params.scene_extent
    b = dr.select(ok, b, 1.0)
    th_a, th_b = dr.atan2(-t0, b), dr.atan2(d - t0, b)

    def t_of(s):
        t = t0 + b * dr.tan(th_a + (th_b - th_a) * (s / steps))
        return dr.select(ok, dr.clip(t, 0.0, d), d * (s / steps))
    return t_of


def march(params, cap, steps, shadow_map=None, jitter=False, seed=0, spacing="uniform",
          shadow_range=None):
    """L_scat per camera sample by ``steps`` analytic segments (see module doc).
    ``shadow_range = (t_lo, t_hi)`` per sample (Wyman & Ramsey 2008): exact
    visibility is traced only at points with ``t`` in it, ``V = 1`` elsewhere
    (:func:`integrators.hybrid_march.shadow_range`)."""
    n = dr.width(cap.d)
    sigma_t = color(params.medium.sigma_t)
    sigma_s = color(params.medium.sigma_s)
    t_of = step_boundaries(params, cap, steps, spacing)
    if jitter:
        rng = mi.PCG32(size=n, initstate=dr.arange(mi.UInt64, n) + seed_offset(seed, 0x853C49E6748FEA9B))
        offset = rng.next_float32()
    else:
        offset = mi.Float(0.5)
    n_steps = dr.opaque(mi.UInt32, steps)

    def body(k, L):
        s = mi.Float(k)
        t = t_of(s + offset)
        x = cap.o + cap.omega * t
        wo, dist, L_light = sample_light(params, x)
        tau, t_in, t_out = segment_box(params, x, wo, dist)
        if shadow_map is None:
            active = True if shadow_range is None else (t >= shadow_range[0]) & (t <= shadow_range[1])
            V = dr.select(visible_exact(params, x, wo, dist, t_in, t_out, active), 1.0, 0.0)
        else:
            V = shadow_map.visibility(x)
        f_p = phase_eval(params, cap.omega, wo, x)
        w = segment_weight(sigma_t, t_of(s), t_of(s + 1))
        L += sigma_s * f_p * L_light * light_transmittance(params, tau) * V * w
        return k + 1, L

    k, L = dr.while_loop(
        state=(mi.UInt32(0), dr.zeros(mi.Color3f, n)),
        cond=lambda k, L: k < n_steps,
        body=body,
    )
    return L


mi.register_integrator("raymarch", lambda props: RaymarchIntegrator(props))
