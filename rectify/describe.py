"""A summary of the epipolar geometry of a camera and a light (for the CLI)."""
from __future__ import annotations

from .epipole import epipolar_frame
from .projective import frustum_axis_angle, projective_rectification
from .ring import DEFAULT_RING_DEG, ring_pixel_count
from .slices import max_distance_to_slices, sinh_slices, uniform_slices


def describe(camera, light, ring_deg: float = DEFAULT_RING_DEG) -> dict:
    """Epipole position and case, slice counts (``sinh`` and uniform 1-px
    border spacing), the largest pixel-to-slice distance of each, the number
    of pixels in the epipole ring, and whether Klehm's projective
    rectification is usable (it does not depend on the far plane).  Plain
    Python values only."""
    frame = epipolar_frame(camera, light)
    s_sinh, s_unif = sinh_slices(frame), uniform_slices(frame)
    _, projective = projective_rectification(frame, far=1.0, near=1e-3)
    return {
        "width": frame.width,
        "height": frame.height,
        "light_kind": frame.light_kind,
        "case": frame.case,
        "epipole_px": [float(frame.epipole[0]), float(frame.epipole[1])],
        "epipole_in_image": frame.in_image,
        "direction_px": [float(frame.direction[0]), float(frame.direction[1])],
        "slices_sinh": s_sinh.count,
        "slices_uniform": s_unif.count,
        "sinh_saving": 1.0 - s_sinh.count / max(1, s_unif.count),
        "max_distance_px_sinh": max_distance_to_slices(frame, s_sinh),
        "max_distance_px_uniform": max_distance_to_slices(frame, s_unif),
        "ring_deg": float(ring_deg),
        "ring_pixels": ring_pixel_count(frame, ring_deg),
        "min_view_light_angle_deg": frustum_axis_angle(frame),
        "projective": projective,
    }
