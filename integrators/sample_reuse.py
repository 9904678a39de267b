"""Partial renders for temporal reuse (Lin et al. §3): compute L_scat of the
dirty camera samples only and keep the previous frame's values elsewhere.

Until the render template takes a sample mask itself (``render_layers(...,
samples=mask)`` with a ``widen_samples`` hook per method), this module does
it for the methods whose camera samples are independent of each other:
``raymarch`` with exact visibility (``march`` full or hybrid) evaluates each
sample from its own ray alone, so the dirty samples are gathered into a
capture of their own (:func:`integrators.epipolar_setup.subset_capture`),
marched, and scattered back.  A shadow-mapped marcher fits its map to all
samples of the frame and the jittered marcher draws its random offsets by
position in the capture: neither gives a sample the value it has in a full
render, so both are refused (:func:`reuse_blocker`).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .epipolar_setup import subset_capture


def reuse_blocker(integrator) -> str | None:
    """Why ``integrator`` cannot reuse samples through this module (a
    sentence naming the fix), or None when it can."""
    name = type(integrator).__name__
    if name != "RaymarchIntegrator":
        return (f"{name} evaluates camera samples together (per slice or row): its reuse needs "
                "the render template's sample mask; re-render every frame (reuse=False, "
                "--no-reuse) until then.")
    if integrator.visibility != "exact":
        return ("raymarch with visibility='shadowmap' fits its map to the whole frame, so a "
                "partial render differs from a full one: use visibility='exact' "
                "(march='hybrid' for speed) or reuse=False.")
    if integrator.jitter:
        return ("raymarch with jitter=true draws its offsets by position in the capture: use "
                "jitter=false or reuse=False.")
    return None


def scattering_of_samples(integrator, params, cap, mask, previous):
    """L_scat per camera sample of ``cap``: the method's own value where
    ``mask`` is set, ``previous`` (the last frame's values) elsewhere.
    ``mask=None`` computes every sample."""
    if mask is None or previous is None:
        return integrator.scattering(params, cap)
    idx = dr.compress(mi.Bool(mask))
    out = mi.Color3f(previous)
    if dr.width(idx) == 0:
        return out
    if dr.width(idx) == dr.width(cap.d):
        return integrator.scattering(params, cap)
    values = integrator.scattering(params, subset_capture(cap, idx))
    dr.scatter(out, values, idx)
    return out
