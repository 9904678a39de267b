"""Partial renders: the boolean mask of camera samples a render is asked
for, the capture of only those samples, and the merge of a partial capture
and scattering into the previous frame's (DESIGN §4).
"""
from __future__ import annotations

from dataclasses import replace

import drjit as dr
import mitsuba as mi

from ..core.capture import CameraCapture


def sample_mask(samples, count: int) -> mi.Bool:
    """A partial render's sample mask (mi.Bool or NumPy bool array of
    ``count`` = pixels × spp entries) as an mi.Bool."""
    import numpy as np
    if not isinstance(samples, mi.Bool):
        arr = np.asarray(samples)
        if arr.dtype != np.bool_:
            raise ValueError(f"samples: expected a boolean mask, got dtype {arr.dtype}; "
                             "pass e.g. numpy.zeros(pixels * spp, bool) with True where to render.")
        samples = mi.Bool(arr.ravel())
    if dr.width(samples) != count:
        raise ValueError(f"samples: the mask has {dr.width(samples)} entries but the render "
                         f"has {count} camera samples (pixels × spp, index pixel*spp + k).")
    return samples


def empty_capture(params, spp: int) -> CameraCapture:
    """The capture of no camera sample (a partial render of an empty mask)."""
    u, f = dr.zeros(mi.UInt32, 0), dr.zeros(mi.Float, 0)
    c = dr.zeros(mi.Color3f, 0)
    return CameraCapture(width=params.camera.width, height=params.camera.height, spp=spp,
                         pixel=u, o=dr.zeros(mi.Point3f, 0), omega=dr.zeros(mi.Vector3f, 0),
                         d=f, T_cam=c, L_surface=mi.Color3f(c), hit=dr.zeros(mi.Bool, 0),
                         sample=mi.UInt32(u),
                         t_in=mi.Float(f) if params.camera_outside else None)


def merge_capture(known: CameraCapture, part: CameraCapture) -> CameraCapture:
    """The full capture ``known`` with the samples of the subset capture
    ``part`` (indices ``part.sample``) replaced by ``part``'s values."""
    if part.sample is None:
        return part
    idx = part.sample

    def put(old, new):
        out = type(old)(old)
        if dr.width(idx):
            dr.scatter(out, new, idx)
        return out
    cap = replace(known, d=put(known.d, part.d), T_cam=put(known.T_cam, part.T_cam),
                  L_surface=put(known.L_surface, part.L_surface), hit=put(known.hit, part.hit),
                  sample=None, parent=None,
                  t_in=None if known.t_in is None or part.t_in is None
                  else put(known.t_in, part.t_in))
    dr.eval(cap.d, cap.T_cam, cap.L_surface, cap.hit, *(() if cap.t_in is None else (cap.t_in,)))
    return cap


def masked_scattering(scattering, params, cap, computed: mi.Bool):
    """L_scat of the ``computed`` samples of ``cap`` (0 elsewhere): the
    method's ``scattering`` runs on the subset capture alone (which keeps
    the full one as ``parent`` for frame-wide choices)."""
    index = dr.compress(computed)
    out = dr.zeros(mi.Color3f, cap.count)
    if dr.width(index):
        dr.scatter(out, scattering(params, cap.subset(index)), index)
    return out
