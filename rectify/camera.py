"""Pinhole camera model shared by every method and by ``rectify``.

A pixel position ``(x, y)`` in continuous film coordinates (pixel ``(i, j)``
covers ``[i, i+1) x [j, j+1)``, its centre is ``(i+0.5, j+0.5)``; ``y`` grows
downwards) maps to normalised film coordinates ``u = x / width``,
``v = y / height`` and to the (unnormalised) world-space ray direction

    w(u, v) = forward + (2u - 1) * x_axis + (2v - 1) * y_axis

``forward`` is the unit optical axis, ``x_axis``/``y_axis`` are orthogonal to it
and to each other with lengths tan(fov_x/2) and tan(fov_y/2).  This matches
Mitsuba's ``perspective`` sensor exactly (a test checks it against
``sensor.sample_ray``), and it is what the epipolar geometry projects with.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class CameraParams:
    origin: np.ndarray     # (3,) world position of the pinhole
    forward: np.ndarray    # (3,) unit optical axis
    x_axis: np.ndarray     # (3,) toward +x in the film, length tan(fov_x/2)
    y_axis: np.ndarray     # (3,) toward +y (down) in the film, length tan(fov_y/2)
    width: int
    height: int
    near_clip: float = 1e-2

    # -- image <-> world ---------------------------------------------------
    def direction(self, x, y):
        """Unnormalised world direction through film position(s) (x, y) [pixels]."""
        u = np.asarray(x, dtype=np.float64) / self.width
        v = np.asarray(y, dtype=np.float64) / self.height
        return (self.forward + (2 * u - 1)[..., None] * self.x_axis
                + (2 * v - 1)[..., None] * self.y_axis)

    def project(self, p):
        """World point(s) -> (x, y, z): film position in pixels and depth along
        ``forward``.  Points behind the camera get z <= 0 (x, y then refer to
        the mirrored projection, as for an anti-epipole)."""
        q = np.asarray(p, dtype=np.float64) - self.origin
        z = q @ self.forward
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (q @ self.x_axis) / (self.x_axis @ self.x_axis) / z
            b = (q @ self.y_axis) / (self.y_axis @ self.y_axis) / z
        return (0.5 * (a + 1) * self.width, 0.5 * (b + 1) * self.height, z)

    def project_direction(self, w):
        """Vanishing point of world direction(s) w: (x, y, z) like ``project``
        with the camera at the origin; z = w . forward (0: at infinity)."""
        w = np.asarray(w, dtype=np.float64)
        z = w @ self.forward
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (w @ self.x_axis) / (self.x_axis @ self.x_axis) / z
            b = (w @ self.y_axis) / (self.y_axis @ self.y_axis) / z
        return (0.5 * (a + 1) * self.width, 0.5 * (b + 1) * self.height, z)

    @property
    def resolution(self):
        return (self.width, self.height)

    @staticmethod
    def from_mitsuba(sensor) -> "CameraParams":
        """Fit the model to a Mitsuba perspective sensor by sampling its rays."""
        import mitsuba as mi

        size = sensor.film().crop_size()
        w, h = int(size[0]), int(size[1])

        # the centre ray and the rays through the right and bottom edges'
        # centres, traced together: one kernel and one read-back per frame
        r, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f([0.5, 1.0, 0.5], [0.5, 0.5, 1.0]),
                                 mi.Point2f(0.5, 0.5))
        import drjit as dr

        from ._dr import host_array
        dr.eval(r.o, r.d)
        o3 = host_array(r.o).reshape(3, 3).T      # (ray, xyz), no packing kernel
        d3 = host_array(r.d).reshape(3, 3).T
        d3 = d3 / np.linalg.norm(d3, axis=1, keepdims=True)
        o, f, d1, d2 = o3[0], d3[0], d3[1], d3[2]
        x_axis = d1 / (d1 @ f) - f
        y_axis = d2 / (d2 @ f) - f
        # the sampled ray starts on the near plane: recover the pinhole
        near = float(sensor.near_clip()) if hasattr(sensor, "near_clip") else 0.0
        origin = o - f * near
        return CameraParams(origin=origin, forward=f, x_axis=x_axis, y_axis=y_axis,
                            width=w, height=h, near_clip=near)
