"""Rows and texels of ``fourier_filter`` on small images.

Baran's slice bound (§8: every pixel centre within half a pixel of a slice)
and the light-ray count (the image diagonal) are stated in pixels.  A camera
sample is answered on its nearest slice's plane with that slice's blockers,
so on an image of a few pixels "half a pixel" is a large angle: the sample
reads the shadows of a plane far from its own ray (1×1: half the field of
view), and a few dozen light rays resolve the shadows along a ray that
crosses the whole scene.  The rows and texels are therefore chosen for an
image of at least ``MIN_IMAGE_SIDE`` pixels on its long side: the slice
spacing shrinks, and the light rays grow, by the same factor.  Only slices
that hold a sample become rows, so a tiny image still has as many rows as
samples at most; the cost is texels per row.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify.epipole import EpipolarFrame
from rectify.projective import (DEFAULT_MIN_ANGLE_DEG, ProjectiveRectification, ProjectiveRows,
                                frustum_axis_angle, projective_rectification, projective_rows)

from ..core.opaque import vector
from ..epipolar.frame import epipolar_frame_of
from ..epipolar.light_models import light_model
from ..epipolar.light_rays.directional import auto_light_rays


#: the rectification of an image is at least as fine as for this long side [px]
MIN_IMAGE_SIDE = 32


def small_image_scale(width: int, height: int) -> float:
    """The factor ≤ 1 by which a small image's slice spacing shrinks
    (1 for images of at least ``MIN_IMAGE_SIDE`` pixels on the long side)."""
    return min(1.0, max(int(width), int(height), 1) / MIN_IMAGE_SIDE)


def row_spacing(spacing: float, width: int, height: int) -> float:
    """Slice spacing [px] for the automatic (sinh) slices of a width × height image."""
    return float(spacing) * small_image_scale(width, height)


def rectified_size(width: int, height: int) -> tuple[float, float]:
    """(width, height) [px] the light-ray count is chosen for."""
    s = small_image_scale(width, height)
    return width / s, height / s


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------

#: default texels per row: this many times epipolar_tree's light rays ...
TEXEL_FACTOR = 4
#: ... but not above this (unless epipolar_tree's own count is larger)
MAX_AUTO_TEXELS = 1024


@dataclass(eq=False)
class ProjectivePlan:
    """The projective rectification of one render (Klehm §4.2): the frame,
    the matrix and the rows (:func:`~rectify.projective.projective_rows`)."""
    frame: EpipolarFrame
    rect: ProjectiveRectification
    rows: ProjectiveRows


def far_depth(params, cap) -> float:
    """Largest depth along the optical axis of a camera ray's end point
    (the frustum's far plane for the projective matrix)."""
    cam = params.camera
    o = vector(cam.origin)
    f = vector(cam.forward / np.linalg.norm(cam.forward))
    end = mi.Vector3f(cap.o) + cap.omega * cap.d - o
    far = float(dr.max(dr.dot(end, f))[0]) if dr.width(cap.d) else 0.0
    near = cam.near_clip if cam.near_clip > 0 else 1e-4 * params.scene_extent
    return max(far, 10.0 * near)


def texel_size(rays):
    """Width of every texel (projective map), or 1 (equal widths per row,
    which cancel in a weighted average)."""
    return rays.texel_weights()


def auto_texels(params, queries, cap) -> int:
    """Default texels (light rays) per row.  ``epipolar_tree`` resolves each
    light ray into ``prefilter`` = 4 sub-rays (Baran §7); a rectified shadow
    map has one depth per texel, so it takes ``TEXEL_FACTOR`` times its
    light rays (:func:`~integrators.epipolar.light_rays.directional.auto_light_rays`), up to
    ``MAX_AUTO_TEXELS`` (Klehm §5 uses 1024 for 1920×1080).  The length
    over which the medium's mean free paths are counted: the widest row's
    γ_max (directional), the longest camera path (point/spot, as
    ``epipolar_tree``)."""
    cam = params.camera
    length = light_model(params).light_length(params, queries, cap)
    width, height = rectified_size(cam.width, cam.height)
    d = auto_light_rays(width, height, float(np.max(params.medium.sigma_t)), length)
    return max(d, min(TEXEL_FACTOR * d, MAX_AUTO_TEXELS))


#: ``rectification="projective"`` is refused closer than this [deg]
#: (rectify.projective's default: the map degenerates, Klehm's fallback)
PROJECTIVE_FLOOR = DEFAULT_MIN_ANGLE_DEG


def projective_plan(params, cap, rectification: str, min_angle: float,
                    slices: int) -> ProjectivePlan | None:
    """The projective map's frame, matrix and rows, or None for the
    epipolar rectification: ``epipolar``; ``auto`` with a point/spot
    light or a view ray closer than ``min_angle`` [deg] to the light
    direction (:func:`~rectify.projective.frustum_axis_angle`).
    ``projective`` refuses (ValueError naming the problem and the fix)
    a point/spot light, an on-screen (anti-)epipole and view rays closer
    than :data:`PROJECTIVE_FLOOR` to the light direction."""
    if rectification == "epipolar":
        return None
    explicit = rectification == "projective"
    if not light_model(params).projective:
        if explicit:
            raise ValueError(
                f"fourier_filter: rectification='projective' supports directional "
                f"lights only, the scene's light is a {params.light.kind} light; use "
                "rectification='epipolar' or 'auto' (which takes the epipolar "
                "rectification for point and spot lights).")
        return None
    frame = epipolar_frame_of(params)
    if not explicit and frustum_axis_angle(frame) < min_angle:
        return None
    rect, reason = projective_rectification(frame, far_depth(params, cap),
                                            min_angle_deg=PROJECTIVE_FLOOR)
    if rect is None:
        if explicit:
            raise ValueError(
                f"fourier_filter: rectification='projective' is impossible here: "
                f"{reason}; use rectification='epipolar' or 'auto' (which takes the "
                "epipolar slices in this view).")
        return None
    return ProjectivePlan(frame, rect, projective_rows(frame, rect, slices))
