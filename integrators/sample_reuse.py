"""Partial renders for temporal reuse (Lin et al. §3): compute L_scat of the
dirty camera samples only and keep the previous frame's values elsewhere.

Until the render template takes a sample mask itself (``render_layers(...,
samples=mask)`` with a ``widen_samples`` hook per method), this module does
it for the methods whose camera samples are independent of each other:
``raymarch`` with exact visibility (``march`` full or hybrid) evaluates each
sample from its own ray alone, so the dirty samples alone are captured
(:func:`integrators.capture.capture_camera` with ``samples``), marched, and
scattered back into the last frame's capture and L_scat
(:func:`render_samples`): the cost of a frame follows the dirty fraction,
capture included.  A shadow-mapped marcher fits its map to all
samples of the frame and the jittered marcher draws its random offsets by
position in the capture: neither gives a sample the value it has in a full
render, so both are refused (:func:`reuse_blocker`).
"""
from __future__ import annotations

from dataclasses import replace

import drjit as dr
import mitsuba as mi

from .capture import CameraCapture


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


def merge_samples(previous: CameraCapture, part: CameraCapture, idx) -> CameraCapture:
    """``previous`` with the samples ``idx`` replaced by those of ``part``
    (a capture of exactly those samples, in that order)."""
    def put(t, old, new):
        out = t(old)
        dr.scatter(out, new, idx)
        return out
    return replace(previous, d=put(mi.Float, previous.d, part.d),
                   T_cam=put(mi.Color3f, previous.T_cam, part.T_cam),
                   L_surface=put(mi.Color3f, previous.L_surface, part.L_surface),
                   hit=put(mi.Bool, previous.hit, part.hit))


def render_samples(integrator, params, capture, mask=None, previous=None):
    """``(cap, L_scat)`` of a frame: every sample (``mask`` or ``previous``
    None: ``capture()`` of all samples, then the method's scattering), or
    only the samples in ``mask``: ``capture(idx)`` of those alone, their
    scattering, both scattered into ``previous = (cap, L_scat)`` of the last
    frame.  ``capture(samples)`` returns the camera capture of the sample
    indices ``samples`` (None: all)."""
    if mask is None or previous is None:
        cap = capture(None)
        return cap, integrator.scattering(params, cap)
    prev_cap, prev_L = previous
    idx = dr.compress(mi.Bool(mask))
    if dr.width(idx) == 0:
        return prev_cap, prev_L
    part = capture(idx)
    values = integrator.scattering(params, part)
    L = mi.Color3f(prev_L)
    dr.scatter(L, values, idx)
    return merge_samples(prev_cap, part, idx), L
