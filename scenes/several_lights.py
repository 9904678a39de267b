"""Scenes lit by several lights at once: what users' scenes usually are.

- ``six_spots``: a hall lit by six coloured spot lights hanging in two rows
  of three, each shining down through a grille of bars onto the floor
  (after the six-spot-light test scene of Klehm et al. 2014);
- ``window_lamp``: a room lit by a low sun through a mullioned window and a
  lamp (a point light) beside a bookcase-like stack of boxes.

Same conventions as the suite (:mod:`scenes`): black surfaces unless ``lit``,
meters, y up, light directions the direction the light travels; the
emitters' ids are ``light``, ``light_2``, ...
"""
from __future__ import annotations

import numpy as np

from .catalog import Palette, _room, sun_direction
from .xmlbuild import Medium, Phase, SceneXML


#: the spots' colours (linear RGB intensity, W/sr), front row then back row
SPOT_COLOURS = ((60.0, 20.0, 12.0), (20.0, 55.0, 20.0), (15.0, 25.0, 70.0),
                (50.0, 45.0, 15.0), (45.0, 15.0, 50.0), (15.0, 45.0, 50.0))


def six_spots(lit: bool, count: int = 6) -> SceneXML:
    """Six spot lights in two rows under the ceiling of a hall, each aimed
    down through a grille of thin bars; the camera looks along the rows.
    ``count`` < 6 keeps the first ``count`` lights (the grilles stay): the
    cost-per-light experiment's scenes."""
    if not 1 <= count <= 6:
        raise ValueError(f"count = {count}: six_spots has 1 to 6 lights")
    s = SceneXML("Hall lit by six coloured spot lights through grilles "
                 "(after Klehm et al. 2014's six-spot scene)")
    s.medium(Medium(sigma_t=0.12, albedo=0.9, phase=Phase("hg", 0.2)))
    s.camera((0.0, 1.6, -6.5), (0.0, 1.2, 2.0), fov=70.0)
    paint = Palette(s, lit)
    _room(s, paint, half_x=4.0, height=4.5, half_z=7.5)
    metal = paint("grille_bsdf", (0.3, 0.3, 0.32))
    k = 0
    for row, z in enumerate((-1.0, 3.5)):
        for col, x in enumerate((-2.4, 0.0, 2.4)):
            light = np.array([x, 4.2, z])
            aim = np.array([x + 0.4 * (col - 1), 0.0, z + 0.8])
            if k < count:
                s.spot(light, aim, intensity=SPOT_COLOURS[k], cutoff_angle=28.0,
                       beam_width=22.0)
            y = 3.5                                     # the grille below the lamp
            for b in range(-3, 4):
                p = light + np.array([0.15 * b, 0.0, 0.0])
                s.cylinder(f"bar_{k}_{b + 3}", metal, (p[0], y, z - 0.5), (p[0], y, z + 0.5),
                           0.025)
            k += 1
    obj = paint("plinth_bsdf", (0.5, 0.4, 0.3))
    s.box("plinth_0", obj, (-2.9, 0.0, 0.2), (-1.9, 1.1, 1.2), rotate_y=20.0)
    s.sphere("sphere_0", obj, (0.2, 0.6, 4.6), 0.6)
    return s


def window_lamp(lit: bool) -> SceneXML:
    """A room lit by a low sun through a window with a mullion cross and by
    a lamp (a point light) in the far corner behind a stack of boxes."""
    s = SceneXML("Room lit by the sun through a window and by a lamp")
    s.medium(Medium(sigma_t=0.15, albedo=0.9, phase=Phase("hg", 0.3)))
    s.camera((-2.2, 1.5, -3.3), (0.8, 1.2, 1.5), fov=75.0)
    paint = Palette(s, lit)
    hx, height, hz, t = 3.0, 3.0, 4.0, 0.25
    floor = paint("floor_bsdf", (0.5, 0.45, 0.4))
    wall = paint("wall_bsdf", (0.55, 0.55, 0.55))
    X, Z = hx + t, hz + t
    s.box("floor", floor, (-X, -t, -Z), (X, 0, Z))
    s.box("ceiling", wall, (-X, height, -Z), (X, height + t, Z))
    s.box("wall_left", wall, (-X, 0, -Z), (-hx, height, Z))
    s.box("wall_back", wall, (-hx, 0, hz), (hx, height, Z))
    s.box("wall_front", wall, (-hx, 0, -Z), (hx, height, -hz))
    # the x = +hx wall with one window z in [-1, 1], y in [1, 2.4] and a mullion cross
    s.box("wall_right_a", wall, (hx, 0, -Z), (X, height, -1.0))
    s.box("wall_right_b", wall, (hx, 0, 1.0), (X, height, Z))
    s.box("wall_right_c", wall, (hx, 0, -1.0), (X, 1.0, 1.0))
    s.box("wall_right_d", wall, (hx, 2.4, -1.0), (X, height, 1.0))
    s.box("mullion_v", wall, (hx, 1.0, -0.04), (X, 2.4, 0.04))
    s.box("mullion_h", wall, (hx, 1.66, -1.0), (X, 1.74, 1.0))
    s.directional(sun_direction(elevation=25.0, azimuth=100.0), irradiance=(40.0, 36.0, 30.0))
    s.point((-2.3, 2.2, 3.2), intensity=(6.0, 4.5, 2.5))
    obj = paint("box_bsdf", (0.45, 0.3, 0.2))
    s.box("box_0", obj, (-2.0, 0.0, 2.2), (-1.2, 0.8, 3.0), rotate_y=15.0)
    s.box("box_1", obj, (-1.9, 0.8, 2.4), (-1.3, 1.5, 3.0), rotate_y=-10.0)
    s.sphere("ball", obj, (0.6, 0.35, 0.5), 0.35)
    m = 1.0
    s.medium_box((-X - m, -t - m, -Z - m), (X + m, height + t + m, Z + m))
    return s


SCENES = {"six_spots": six_spots, "window_lamp": window_lamp}
#: emitter plugins of each scene, in document order
EMITTER_TYPES = {"six_spots": ("spot",) * 6, "window_lamp": ("directional", "point")}
