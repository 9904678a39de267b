"""Epipolar geometry for single scattering: pure array functions.

This package is the contract between the scene capture and the epipolar
methods (``epipolar_tree``, ``fourier_filter``, ``minmax_epipolar``).  Every
fast function is Dr.Jit on the active Mitsuba variant (never assumes LLVM)
and has a float64 NumPy oracle ``*_reference`` beside it.

Conventions
-----------
Pixels
    Continuous film coordinates of :class:`rectify.camera.CameraParams`:
    pixel ``(i, j)`` covers ``[i, i+1) x [j, j+1)``, centre ``(i+.5, j+.5)``,
    ``y`` down.  Per-pixel Dr.Jit results are flat arrays of ``W*H`` entries,
    row-major (``index = y*W + x``); NumPy oracles return ``(H, W)`` arrays;
    images from :func:`unrectify` are ``mi.TensorXf`` ``(H, W[, C])``.
Lights
    Directional: ``w_l`` the unit direction *toward* the light (Mitsuba's
    ``directional`` stores the opposite).  Point/spot: position ``p_l``.
    ``axis`` = unit vector from the eye ``o`` toward the light (``w_l``, or
    ``(p_l - o)/|p_l - o|``).
Epipole (:class:`EpipolarFrame`)
    The image of ``axis``; ``case`` in ``on_screen | off_screen | at_infinity
    | behind``.  ``frame.epipole`` is the finite pixel point the epipolar lines
    converge on (the anti-epipole = image of ``-axis`` when ``behind``; a
    stand-in 1e9 px away along ``frame.direction`` at infinity);
    ``frame.epipole_h`` the same in homogeneous pixels ``(X, Y, W>=0)``.
Rectified coordinates (Baran 2010 §3, §9; :mod:`rectify.coords`)
    ``alpha`` slice = angle of the half-plane bounded by the camera-light axis,
    ``atan2(q.b2, q.b1)`` in ``(-pi, pi]`` (``alpha = 0`` through the image
    centre); ``beta`` = angle between the view ray and ``axis`` in
    ``[0, pi]``; ``t`` = distance along the view ray.  Directional light:
    ``gamma`` = distance of the light ray from the eye (= from the axis),
    ``u = (p - o).axis = gamma cot(beta)``.  Point/spot: ``gamma`` = angle at
    the light between the light ray and the direction light -> eye,
    ``u = |p - p_l|``.
Slices (:mod:`rectify.slices`)
    :class:`Slices`: ``alpha`` sorted increasing, one border end point each,
    ``wraps`` when the epipole is strictly inside the image.  ``sinh``
    (Baran §8, Eq. 5) or ``uniform`` (1 px border spacing); both keep every
    pixel centre within 0.5 px of a slice line.  A pixel's fractional slice
    index is ``s = k0 + f`` between slices ``k0`` and ``k1 = k0+1 (mod S)``,
    linear in ``alpha``; its position along the slice is its ``beta``
    (:func:`pixel_to_slice`; inverse :func:`slice_to_pixel`).
Grid (:mod:`rectify.grid`)
    Rectified values are ``(S, M[, C])``: slice ``k`` (rows, order of
    ``slices.alpha``), sample ``j`` at ``beta = grid.start[k] + j grid.step[k]``.
    :func:`grid_directions` gives the view direction of every sample.
Ring (Baran §6)
    Pixels whose view ray is within ``ring_deg`` (default 2) of ``+-axis``.
Projective rectification (Klehm 2014 §4.2)
    :func:`projective_rectification` -> ``(matrix holder, "ok")`` or
    ``(None, reason)``; NDC ``x`` = along view rays (increasing), ``y`` = slice
    row, ``z`` = depth, constant along view rays, growing away from the light.
"""
# Pick a usable LLVM before Dr.Jit is first imported (rectify.llvm imports
# neither), then set the default variant when none is active.
from . import llvm as _llvm  # noqa: E402  isort:skip

_llvm.configure()
_llvm.set_default_variant()

from .coords import (alpha_beta_to_direction, alpha_beta_to_direction_reference,
                     alpha_beta_to_pixel, alpha_beta_to_pixel_reference,
                     direction_to_alpha_beta, direction_to_alpha_beta_reference,
                     film_direction, light_coords_to_world, light_coords_to_world_reference,
                     light_to_view, light_to_view_reference, pixel_to_alpha_beta,
                     pixel_to_alpha_beta_reference, project_direction, ray_meeting_t,
                     ray_meeting_t_reference, view_coords_to_world,
                     view_coords_to_world_reference, view_to_light, view_to_light_reference,
                     world_to_light_coords, world_to_light_coords_reference,
                     world_to_view_coords, world_to_view_coords_reference)
from .describe import describe
from .epipole import (CASES, FAR_PX, EpipolarFrame, LightGeometry, directional_frame,
                      epipolar_frame, make_camera, point_frame)
from .grid import (BetaGrid, grid_directions, grid_directions_reference, per_slice_beta_grid,
                   pixel_angle, shared_beta_grid, slice_beta_ranges)
from .projective import (ProjectiveRectification, frustum_axis_angle, projective_apply,
                         projective_apply_reference, projective_rectification)
from .ring import DEFAULT_RING_DEG, ring_mask, ring_mask_reference, ring_pixel_count
from .slices import (SliceLines, Slices, alpha_to_slice, distance_to_slices,
                     distance_to_slices_reference, make_slices, max_distance_to_slices,
                     max_distance_to_slices_reference, pixel_to_slice, pixel_to_slice_reference,
                     sinh_slices, slice_lines, slice_segments, slice_to_alpha, slice_to_pixel,
                     slice_to_pixel_reference, slices_from_points, uniform_slices)
from .unrectify import (MIN_WEIGHT, unrectify, unrectify_bilateral,
                        unrectify_bilateral_reference, unrectify_reference)

import types as _types  # noqa: E402

__all__ = sorted(name for name, obj in globals().items()
                 if not name.startswith("_") and not isinstance(obj, _types.ModuleType))
