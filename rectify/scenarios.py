"""Camera/light configurations for tests and experiments, including the
degenerate ones the epipolar geometry must survive: epipole on a pixel
centre, on the image border or a corner, just off each edge, at infinity
(light parallel to the image plane), behind the camera, light along the
optical axis.  Plain functions of numbers (no test framework needed; the
tests' hypothesis strategy over them is ``tests/strategies.py``)."""
from __future__ import annotations

import math

import numpy as np

from rectify.camera import CameraParams

from .epipole import LightGeometry, make_camera


def rotated_camera(origin=(0.0, 0.0, 0.0), yaw_deg: float = 0.0, pitch_deg: float = 0.0,
                   roll_deg: float = 0.0, fov_x_deg: float = 60.0, width: int = 32,
                   height: int = 24) -> CameraParams:
    """Camera at ``origin`` looking along +z rotated by yaw (about y), pitch
    (about x), then rolled about its optical axis."""
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    f = np.array([math.sin(y) * math.cos(p), math.sin(p), math.cos(y) * math.cos(p)])
    up0 = np.array([0.0, 1.0, 0.0]) if abs(f[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    side = np.cross(f, up0)
    side /= np.linalg.norm(side)
    up0 = np.cross(side, f)
    up = math.cos(r) * up0 + math.sin(r) * side
    return make_camera(origin, f, up=up, fov_x_deg=fov_x_deg, width=width, height=height)


def light_toward_pixel(camera: CameraParams, x: float, y: float, kind: str = "directional",
                       behind: bool = False, distance: float = 10.0) -> LightGeometry:
    """A light whose epipole (or anti-epipole if ``behind``) is film point (x, y)."""
    d = camera.direction(x, y)
    d = d / np.linalg.norm(d)
    if behind:
        d = -d
    if kind == "directional":
        return LightGeometry("directional", direction=tuple(d))
    return LightGeometry(kind, position=tuple(camera.origin + distance * d))


def light_parallel_to_image(camera: CameraParams, angle_deg: float, kind: str = "directional",
                            distance: float = 10.0) -> LightGeometry:
    """A light in the plane through the eye parallel to the film: epipole at
    infinity in film direction ``angle_deg``."""
    a = math.radians(angle_deg)
    xa = camera.x_axis / np.linalg.norm(camera.x_axis)
    ya = camera.y_axis / np.linalg.norm(camera.y_axis)
    d = math.cos(a) * xa + math.sin(a) * ya
    if kind == "directional":
        return LightGeometry("directional", direction=tuple(d))
    return LightGeometry(kind, position=tuple(camera.origin + distance * d))


def nasty_epipoles(width: int, height: int) -> dict:
    """Named film positions for the epipole."""
    W, H = float(width), float(height)
    return {
        "centre": (W / 2, H / 2),
        "pixel_centre": (math.floor(W / 3) + 0.5, math.floor(H / 2) + 0.5),
        "border_left": (0.0, H / 2 + 0.5),
        "border_right": (W, H / 3),
        "border_top": (W / 3 + 0.5, 0.0),
        "border_bottom": (2 * W / 3, H),
        "corner_tl": (0.0, 0.0),
        "corner_br": (W, H),
        "near_corner": (0.3, 0.7),
        "off_left": (-0.25, H / 2),
        "off_right": (W + 0.25, H / 2 + 0.5),
        "off_top": (W / 2 + 0.5, -0.25),
        "off_bottom": (W / 4, H + 0.25),
        "off_corner": (-0.2, H + 0.3),
        "far_off": (-7 * W, 2 * H),
        "very_far_off": (3e7 * W, -1e7 * H),
    }


def scenario(camera: CameraParams, mode: str, kind: str = "directional", *, name: str = "centre",
             behind: bool = False, angle_deg: float = 0.0, direction=(0.0, 0.0, 1.0),
             distance: float = 10.0) -> LightGeometry:
    """The light of one configuration ``mode``: ``nasty`` (epipole at
    ``nasty_epipoles()[name]``), ``infinity`` (parallel to the film),
    ``axis`` (along the optical axis) or ``random`` (``direction``: the
    direction toward the light, scaled by ``distance`` for point/spot)."""
    if mode == "nasty":
        x, y = nasty_epipoles(camera.width, camera.height)[name]
        return light_toward_pixel(camera, x, y, kind, behind, distance)
    if mode == "infinity":
        return light_parallel_to_image(camera, angle_deg, kind, distance)
    if mode == "axis":
        x, y = 0.5 * camera.width, 0.5 * camera.height
        return light_toward_pixel(camera, x, y, kind, behind, distance)
    if mode == "random":
        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        if kind == "directional":
            return LightGeometry("directional", direction=tuple(d))
        return LightGeometry(kind, position=tuple(camera.origin + distance * d))
    raise ValueError(f"unknown mode {mode!r}")
