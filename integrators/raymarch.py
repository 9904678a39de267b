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
=========================  ==================================================
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .capture import capture_shadow_map, seed_offset
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

    def scattering(self, params, cap):
        shadow_map = None
        if self.visibility == "shadowmap":
            with self.stage("shadowmap"):
                shadow_map = capture_shadow_map(params, cap, self.shadowmap_resolution)
        return march(params, cap, self.steps, shadow_map, self.jitter, self.render_seed)


def march(params, cap, steps, shadow_map=None, jitter=False, seed=0):
    """L_scat per camera sample by ``steps`` analytic segments (see module doc)."""
    n = dr.width(cap.d)
    sigma_t = color(params.medium.sigma_t)
    sigma_s = color(params.medium.sigma_s)
    dt = cap.d / steps
    if jitter:
        rng = mi.PCG32(size=n, initstate=dr.arange(mi.UInt64, n) + seed_offset(seed, 0x853C49E6748FEA9B))
        offset = rng.next_float32()
    else:
        offset = mi.Float(0.5)
    n_steps = dr.opaque(mi.UInt32, steps)

    def body(k, L):
        t = (mi.Float(k) + offset) * dt
        x = cap.o + cap.omega * t
        wo, dist, L_light = sample_light(params, x)
        tau, t_in, t_out = segment_box(params, x, wo, dist)
        if shadow_map is None:
            V = dr.select(visible_exact(params, x, wo, dist, t_in, t_out), 1.0, 0.0)
        else:
            V = shadow_map.visibility(x)
        f_p = phase_eval(params, cap.omega, wo, x)
        w = segment_weight(sigma_t, mi.Float(k) * dt, mi.Float(k + 1) * dt)
        L += sigma_s * f_p * L_light * light_transmittance(params, tau) * V * w
        return k + 1, L

    k, L = dr.while_loop(
        state=(mi.UInt32(0), dr.zeros(mi.Color3f, n)),
        cond=lambda k, L: k < n_steps,
        body=body,
    )
    return L


mi.register_integrator("raymarch", lambda props: RaymarchIntegrator(props))
