"""The ring around the epipole (Baran et al. 2010, §6).

At the epipole view rays and light rays are parallel, the rectification is
singular (``ds/dgamma -> inf``), so Baran ray-marches the pixels "within a
small ring (about two degrees) around the epipole".  A pixel is in the ring
when its view ray makes an angle below ``ring_deg`` with the camera-light
axis, in either direction: ``min(beta, pi - beta) < ring_deg`` (the
``pi - beta`` side is the anti-epipole of a light behind the camera, where
the epipolar lines converge just as singularly).  The mask is empty when
the (anti-)epipole is off screen by more than the ring's angle.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ._dr import const, pixel_centres
from .coords import pixel_to_alpha_beta
from .epipole import EpipolarFrame

DEFAULT_RING_DEG = 2.0


def ring_mask(frame: EpipolarFrame, ring_deg: float = DEFAULT_RING_DEG, x=None, y=None) -> mi.Bool:
    """Per pixel centre (flat row-major unless x, y given): inside the ring."""
    if x is None:
        x, y = pixel_centres(frame.width, frame.height)
    _, beta = pixel_to_alpha_beta(frame, x, y)
    return dr.minimum(beta, math.pi - beta) < const(math.radians(ring_deg))


def ring_mask_reference(frame: EpipolarFrame, ring_deg: float = DEFAULT_RING_DEG) -> np.ndarray:
    """(H, W) bool: angle between each pixel's view ray and +-axis below ring_deg."""
    yy, xx = np.mgrid[0:frame.height, 0:frame.width]
    d = frame.camera.direction(xx + 0.5, yy + 0.5)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip(np.abs(d @ frame.axis), 0.0, 1.0)))
    return ang < ring_deg


def ring_pixel_count(frame: EpipolarFrame, ring_deg: float = DEFAULT_RING_DEG) -> int:
    return int(dr.count(ring_mask(frame, ring_deg))[0])
