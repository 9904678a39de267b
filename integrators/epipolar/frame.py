"""The epipolar frame of a scene's light and camera, its slices (Baran et
al. 2010 §3) and the epipole ring (§6).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from rectify.epipole import EpipolarFrame, directional_frame, point_frame
from rectify.slices import Slices, make_slices


#: view rays closer than this to ±w_l [rad] are always ray-marched (sin β → 0)
MIN_RING_RAD = 1e-5
#: β of padded query slots: above every real β ∈ [0, π]
PAD_BETA = 4.0


# --------------------------------------------------------------------------
# Frame and slices (§3, §8)
# --------------------------------------------------------------------------

def epipolar_frame_of(params) -> EpipolarFrame:
    """The epipolar frame of the camera and the light: directional (§3), or
    point/spot at ``params.light.position`` (§9, axis = eye -> light)."""
    light = params.light
    if light.kind == "directional":
        return directional_frame(params.camera, light.direction)
    return point_frame(params.camera, light.position, kind=light.kind)


#: automatic slices: an image narrower than this many pixels is sliced as if
#: it were this wide (a pixel's half-width is then a wide angle, and a sample
#: that far from its slice sees other blockers)
MIN_SLICE_PIXELS = 256


def choose_slices(frame: EpipolarFrame, count: int = 0, spacing: float = 1.0) -> Slices:
    """``count = 0``: Baran's sinh distribution (§8), lines at most
    ``spacing`` px apart (1: every pixel within half a pixel of a slice),
    the spacing scaled down on images narrower than ``MIN_SLICE_PIXELS``;
    otherwise about ``count`` slices with end points equally spaced along the
    image edges the slices leave through."""
    if count <= 0:
        size = max(frame.width, frame.height)
        return make_slices(frame, "sinh", spacing=spacing * min(1.0, size / MIN_SLICE_PIXELS))
    border = make_slices(frame, "uniform", spacing=1.0).count   # ≈ exit-edge length [px]
    return make_slices(frame, "uniform", spacing=max(border, 1) / count)


def in_ring(beta, ring_deg: float) -> mi.Bool:
    """View ray within ``ring_deg`` of ±w_l (rectify.ring's definition)."""
    limit = max(math.radians(ring_deg), MIN_RING_RAD)
    return dr.minimum(beta, math.pi - beta) < limit
