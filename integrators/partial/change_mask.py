"""Bounded shadow volumes and the temporal change mask (Lin et al. §3;
Wyman & Ramsey 2008 for the volumes).

A camera sample's single scattering ``L_scat = ∫_0^d ... V(x(t)) dt``
depends on the scene only through its segment ``[0, d]`` and the visibility
``V`` of the points on it.  When an object moves between two frames (camera,
light and medium fixed), ``V(x)`` can change only where the light ray from
``x`` meets the object in one of the two frames, i.e. inside the object's
*shadow volume* there; ``d`` changes only where the camera ray meets it.
So a sample is *dirty* (must be recomputed) when its segment meets the
shadow volume of a moving object in the previous or the current frame
(which also catches every sample whose ``d`` changes, :func:`change_mask`);
every other sample keeps its value exactly.

The shadow volumes are :mod:`integrators.core.shadow_volumes`'s.

:func:`change_mask_reference` is the slow, obvious NumPy twin: dense points
along each segment, each tested by a slab test of its own light ray against
the boxes.  :func:`whole_frame_changes` detects (never assumes) a moved
camera, light or changed medium, which makes every sample dirty.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from ..core.shadow_volumes import Boxes, ShadowVolumes, clip_segments, in_shadow_volume_reference


def change_mask_of_lights(cap, sets, params) -> mi.Bool:
    """:func:`change_mask` for the moving objects' box ``sets`` under every
    light of ``params``: a sample is dirty when its segment meets the
    shadow volume of a moving object from any light."""
    mask = None
    for one in params.per_light():
        m = change_mask(cap, ShadowVolumes.from_sets(sets, one))
        mask = m if mask is None else mask | m
    return mask


def change_mask(cap, volumes: ShadowVolumes) -> mi.Bool:
    """Dirty camera samples (module doc) from the *previous* frame's capture
    ``cap``: its segment ``[0, d_prev]`` meets one of ``volumes`` (the moving
    objects' boxes in the previous and the current frame).  No new capture
    is needed: if the current camera ray stops earlier, at a moving object,
    that point lies on ``[0, d_prev]`` inside the object's current box; if
    it stops later, the previous stop was on the object, inside its previous
    box; otherwise the segment is the same."""
    return clip_segments(volumes, cap.o, cap.omega, cap.d, first_hit=True)[0]


# -- whole-frame changes -----------------------------------------------------------
def frame_invariants(params) -> dict:
    """What every sample depends on besides the occluders: camera, light and
    medium parameters as NumPy arrays (compared by :func:`whole_frame_changes`)."""
    cam, med = params.camera, params.medium
    ph = mi.traverse(med.phase)
    lights = []
    for light in params.lights:
        em = mi.traverse(light.emitter)
        lights += [np.ravel(np.array(em[k], dtype=np.float64)) for k in sorted(em.keys())
                   if _numeric(em[k])] + [[len(light.kind)]]
    return {
        "camera": np.concatenate([cam.origin, cam.forward, cam.x_axis, cam.y_axis,
                                  [cam.width, cam.height, cam.near_clip]]),
        "light": np.concatenate(lights),
        "medium": np.concatenate([med.sigma_t, med.albedo, med.bounds_min, med.bounds_max,
                                  np.ravel(med.to_local if med.to_local is not None else []),
                                  np.ravel(med.planes if med.planes is not None else [])]
                                 + [np.ravel(np.array(ph[k], dtype=np.float64))
                                    for k in sorted(ph.keys()) if _numeric(ph[k])]),
    }


def _numeric(value) -> bool:
    try:
        np.array(value, dtype=np.float64)
        return True
    except (TypeError, ValueError):
        return False


def whole_frame_changes(previous: dict | None, current: dict) -> list[str]:
    """Names (``camera``, ``light``, ``medium``) whose parameters differ
    between two :func:`frame_invariants`; all of them for the first frame."""
    if previous is None:
        return sorted(current)
    return [k for k in sorted(current)
            if previous[k].shape != current[k].shape or not np.array_equal(previous[k], current[k])]


def change_mask_reference(o, omega, d, boxes: Boxes, light, samples: int = 512) -> np.ndarray:
    """Dense-sampling oracle of the shadow-volume part of :func:`change_mask`:
    ``samples`` points on each segment ``o + t·ω``, ``t ∈ [0, d]`` (both ends
    included), each tested by
    :func:`~integrators.core.shadow_volumes.in_shadow_volume_reference`."""
    o, omega, d = (np.asarray(v, dtype=np.float64) for v in (o, omega, d))
    t = np.linspace(0.0, 1.0, samples)
    out = np.zeros(len(d), dtype=bool)
    for k in range(0, len(d), 256):
        sl = slice(k, k + 256)
        x = o[sl, None] + omega[sl, None] * (d[sl, None, None] * t[None, :, None])
        out[sl] = in_shadow_volume_reference(x.reshape(-1, 3), boxes, light).reshape(-1, samples).any(1)
    return out
