"""The hybrid ray marcher of Wyman & Ramsey 2008 (the baseline of Lin et al.
Table 1): trace visibility only where a camera ray can be in shadow.

Every occluder of the scene (:func:`integrators.core.shadow_volumes.occluders`) is
covered by boxes (its bounding box, or ``clusters`` boxes of its triangles)
and each box is extruded away from the light into a bounded shadow volume
(:mod:`integrators.partial.change_mask`).  Outside the union of the volumes no
light ray can be blocked, so ``V = 1`` there exactly; the marcher
(:func:`~integrators.core.marching.march` with ``shadow_range``) traces its
ray tests only at the steps inside the hull ``[t_lo, t_hi]`` of the pieces
of the camera segment inside a volume (Wyman & Ramsey march between the
first and the last shadow-volume face a ray crosses) and evaluates the lit
rest with the same quadrature without visibility queries.  The result is
the plain marcher's with exact visibility, step for step.
"""
from __future__ import annotations

from .shadow_volumes import ShadowVolumes, clip_segments, occluders, shape_boxes


def occluder_volumes(params, clusters: int = 1) -> ShadowVolumes:
    """Bounded shadow volumes of every occluder of the scene, ``clusters``
    boxes per mesh (more boxes: tighter volumes, more planes per ray)."""
    return ShadowVolumes.from_sets([shape_boxes(s, clusters) for s in occluders(params)], params)


def shadow_range(params, cap, clusters: int = 1):
    """``(t_lo, t_hi)`` per camera sample of ``cap``: the hull of its segment's
    pieces inside the occluders' shadow volumes (empty: ``t_lo > t_hi``)."""
    _, lo, hi = clip_segments(occluder_volumes(params, clusters), cap.o, cap.omega, cap.d)
    return lo, hi
