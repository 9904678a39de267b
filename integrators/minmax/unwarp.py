"""Stage "to camera": bilateral unwarp and the fix-up pass (Yusov 2013,
"Transformation from epipolar to rectangular coordinates", "Fix-up pass").

Every pixel centre lies between two slices; on each it reads the two
samples around its own ``β``; the four bilinear weights are multiplied by a
depth weight ``exp(−½ ((d_i − d)/(σ d))²)`` of the sample's depth ``d_i``
against the pixel's ``d`` and renormalised.  ``σ`` defaults to the default
relative depth-break threshold of the refinement (:data:`DEPTH_SIGMA`): a
break the refinement sees as two surfaces is one the weights tell apart (a
tap across a break of four thresholds weighs e^{−8}); a wider ``σ`` blends
the far side of small relative breaks (a pillar's edge before a wall 12 %
deeper) into the near pixels (:func:`rectify.unrectify_bilateral`,
whose NumPy twin :func:`rectify.unrectify_bilateral_reference` is the direct
formula).  Pixels whose weight sum falls below ``fixup_threshold`` have no
sample at their depth (a foreground edge between slices, a thin object):
the fix-up pass ray-marches them on their own (talk: "using fewer steps and
no min/max optimization"), with exact visibility for traced blockers and
the shadow map for resampled ones.  Beyond the talk, the pixels within
``ring_degrees`` of the epipole (Baran 2010 §6's ring, :func:`rectify.ring_mask`)
join the fix-up: there the in-scattering of a point light peaks within a
pixel and all slices meet, so no interpolation reproduces the pixel-centre
value.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from rectify import unrectify_bilateral

from ..capture import CameraCapture
from ..marching import auto_spacing, march
from .slices_and_samples import EpipolarSamples

#: default relative depth scale of the bilateral weights (module docstring)
DEPTH_SIGMA = 0.03


@dataclass(frozen=True, eq=False)
class Unwarped:
    """Per pixel: the unwarped L_scat, the bilateral weight sum and the
    pixels the fix-up pass re-marched."""
    L: mi.Color3f = field(repr=False)
    weight: mi.Float = field(repr=False)
    fixup: mi.UInt32 = field(repr=False)

    @property
    def fixup_count(self) -> int:
        return dr.width(self.fixup)


def unwarp(samples: EpipolarSamples, values: mi.Color3f, pixel_depth: mi.Float,
           depth_sigma: float = DEPTH_SIGMA):
    """(L per pixel, weight sum per pixel), both flat row-major."""
    S, M = samples.slices.count, samples.count
    frame = samples.frame
    v = mi.TensorXf(dr.ravel(values), shape=(S, M, 3))
    sd = mi.TensorXf(samples.d, shape=(S, M))
    pd = mi.TensorXf(pixel_depth, shape=(frame.height, frame.width))
    img, wsum = unrectify_bilateral(frame, samples.slices, samples.grid, v, sd, pd, depth_sigma)
    flat = img.array
    n = frame.width * frame.height
    i = dr.arange(mi.UInt32, n) * 3
    L = mi.Color3f(dr.gather(mi.Float, flat, i), dr.gather(mi.Float, flat, i + 1),
                   dr.gather(mi.Float, flat, i + 2))
    return L, wsum.array


def fixup(params, cap: CameraCapture, L_pixel: mi.Color3f, weight: mi.Float,
          threshold: float, steps: int, shadow_map=None, also=None) -> Unwarped:
    """Re-march the pixels whose bilateral weight is below ``threshold``,
    and those of the mask ``also`` (camera samples of ``cap``: one per
    pixel, in pixel order)."""
    todo = weight < threshold
    if also is not None:
        todo |= also
    idx = dr.compress(todo)
    L = mi.Color3f(L_pixel)
    if dr.width(idx):
        sub = cap.subset(idx)
        fixed = march(params, sub, steps, shadow_map=shadow_map, spacing=auto_spacing(params))
        dr.scatter(L, fixed, idx)
    return Unwarped(L=L, weight=weight, fixup=idx)

