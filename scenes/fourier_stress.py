"""Scenes that stress ``fourier_filter`` at its defaults (issue 12).

Each reproduces one failure of the filter that the suite of
:mod:`scenes.catalog` did not catch:

- ``sun_room``: thick fog in a room lit by a low sun through two mullioned
  windows (energy lost as the medium thickens; light in the shadowed fog
  between the shafts);
- ``hall``: a long hall lit through side windows, the camera looking along
  it with the roof's underside in view, the medium box reaching far beyond
  the building (light rays cross tens of metres of fog, receivers sit just
  behind their blockers: fog under the roof lit);
- ``sun_behind`` / ``sun_ahead``: the sun exactly behind the camera / in
  front of it, the anti-epipole / epipole at the image centre (streaks
  radiating from the centre);
- ``spot_columns``: a spot light high beside a colonnade shining across a
  row of columns onto the floor (the fog behind the columns and above the
  floor, in their shadows, came out darker than the reference).

Same conventions as the suite (:mod:`scenes`): black surfaces unless ``lit``,
meters, y up, light directions the direction the light travels.
"""
from __future__ import annotations

import numpy as np

from .catalog import Palette, sun_direction
from .xmlbuild import Medium, Phase, SceneXML

#: the sun room: interior half sizes, wall thickness, windows in the x = +X wall
SUN_ROOM = dict(half_x=3.0, height=3.0, half_z=4.0, wall=0.25,
                window_z=((-2.6, -0.6), (0.6, 2.6)), window_y=(0.9, 2.5),
                mullion=0.08)
SUN_ROOM_SUN = sun_direction(elevation=22.0, azimuth=100.0)


def _wall_with_windows(s: SceneXML, paint_id: str, x0: float, x1: float, z_lo: float,
                       z_hi: float, height: float, windows, window_y, mullion: float,
                       prefix: str) -> None:
    """A wall slab x ∈ [x0, x1] from z_lo to z_hi with rectangular window
    openings (z ranges, sill and lintel heights), each split into four
    panes by one vertical and one horizontal mullion."""
    y0, y1 = window_y
    s.box(f"{prefix}_base", paint_id, (x0, 0, z_lo), (x1, y0, z_hi))
    s.box(f"{prefix}_top", paint_id, (x0, y1, z_lo), (x1, height, z_hi))
    edges = [z_lo] + [e for w in windows for e in w] + [z_hi]
    for k in range(0, len(edges), 2):
        s.box(f"{prefix}_pier_{k // 2}", paint_id, (x0, y0, edges[k]), (x1, y1, edges[k + 1]))
    m = mullion / 2
    for k, (a, b) in enumerate(windows if mullion > 0 else ()):
        zc, yc = (a + b) / 2, (y0 + y1) / 2
        s.box(f"{prefix}_mullion_v{k}", paint_id, (x0, y0, zc - m), (x1, y1, zc + m))
        s.box(f"{prefix}_mullion_h{k}", paint_id, (x0, yc - m, a), (x1, yc + m, b))


def sun_room(lit: bool) -> SceneXML:
    """A closed room lit by a low sun through two mullioned windows in its
    right wall; the camera in a corner looks across the shafts to the lit
    floor patches (thick fog: optical depth ~1.2 across the room at the
    default σt, 8 at ``-D sigma_t=1``)."""
    r = SUN_ROOM
    s = SceneXML("Sun room: low sun through two mullioned windows into thick fog")
    s.medium(Medium(sigma_t=0.15, albedo=0.9, phase=Phase("hg", 0.3)))
    X, H, Z, t = r["half_x"], r["height"], r["half_z"], r["wall"]
    s.camera((-2.6, 1.6, -3.6), (1.5, 0.9, 1.2), fov=75.0)
    s.directional(SUN_ROOM_SUN, irradiance=(20.0, 18.0, 15.0))
    paint = Palette(s, lit)
    floor = paint("floor_bsdf", (0.5, 0.42, 0.35))
    wall = paint("wall_bsdf", (0.6, 0.58, 0.55))
    s.box("floor", floor, (-X - t, -t, -Z - t), (X + t, 0, Z + t))
    s.box("ceiling", wall, (-X - t, H, -Z - t), (X + t, H + t, Z + t))
    s.box("wall_left", wall, (-X - t, 0, -Z - t), (-X, H, Z + t))
    s.box("wall_back", wall, (-X, 0, Z), (X, H, Z + t))
    s.box("wall_front", wall, (-X, 0, -Z - t), (X, H, -Z))
    _wall_with_windows(s, wall, X, X + t, -Z - t, Z + t, H, r["window_z"], r["window_y"],
                       r["mullion"], "wall_right")
    s.box("table", paint("table_bsdf", (0.4, 0.3, 0.2)), (-0.6, 0.0, 0.2), (0.4, 0.75, 1.0))
    m = 1.0
    s.medium_box((-X - t - m, -t - m, -Z - t - m), (X + t + m, H + t + m, Z + t + m))
    return s


#: the hall: interior half width, half length, eaves height, windows along both sides
HALL = dict(half_width=5.0, half_length=18.0, height=7.0, wall=0.4,
            window_z=tuple(range(-14, 15, 4)), window_width=1.6, window_y=(2.0, 5.0),
            margin=40.0)
HALL_SUN = sun_direction(elevation=35.0, azimuth=80.0)


def hall(lit: bool) -> SceneXML:
    """A long hall lit through the windows of its side walls by a sun from
    the right; the camera near the floor looks along the hall and up, so the
    underside of the roof (black fog just below it in the exact image) fills
    the top of the view.  The medium box reaches ``margin`` metres beyond the
    building, so light rays cross tens of metres of fog before the roof."""
    h = HALL
    s = SceneXML("Hall lit through side windows, roof seen from below, "
                 "fog extending far beyond the building")
    s.medium(Medium(sigma_t=0.02, albedo=0.9, phase=Phase("hg", 0.3)))
    w, L, H, t = h["half_width"], h["half_length"], h["height"], h["wall"]
    s.camera((0.8, 1.5, -16.5), (-0.5, 8.5, 0.0), fov=70.0)
    s.directional(HALL_SUN, irradiance=(24.0, 22.0, 19.0))
    paint = Palette(s, lit)
    wall = paint("wall_bsdf", (0.55, 0.5, 0.45))
    roof = paint("roof_bsdf", (0.4, 0.38, 0.42))
    s.box("floor", paint("floor_bsdf", (0.45, 0.42, 0.38)), (-w - t, -0.3, -L - t),
          (w + t, 0, L + t))
    s.box("roof", roof, (-w - t, H, -L - t), (w + t, H + t, L + t))
    s.box("end_front", wall, (-w - t, 0, -L - t), (w + t, H, -L))
    s.box("end_back", wall, (-w - t, 0, L), (w + t, H, L + t))
    half = h["window_width"] / 2
    windows = [(z - half, z + half) for z in h["window_z"]]
    for side, x0 in (("left", -w - t), ("right", w)):
        _wall_with_windows(s, wall, x0, x0 + t, -L - t, L + t, H, windows, h["window_y"],
                           0.0, f"wall_{side}")
    m = h["margin"]
    s.medium_box((-w - t - m, -0.3 - 1.0, -L - t - m), (w + t + m, H + t + m, L + t + m))
    return s


def _axial(lit: bool, toward_sun: bool, comment: str, yaw_deg: float = 0.0) -> SceneXML:
    """Open ground with a grate of posts and a lintel in front of the camera;
    the camera looks exactly along (``toward_sun`` False) or against the
    light's direction of travel, turned by ``yaw_deg`` about the vertical."""
    s = SceneXML(comment)
    s.medium(Medium(sigma_t=0.05, albedo=0.9, phase=Phase("hg", 0.3)))
    travel = sun_direction(elevation=30.0, azimuth=20.0)
    origin = np.array([0.0, 1.6, 0.0])
    view = _yawed(-travel if toward_sun else travel, yaw_deg)
    s.camera(origin, origin + 10.0 * view, fov=60.0)
    s.directional(travel, irradiance=(22.0, 20.0, 17.0))
    paint = Palette(s, lit)
    ground = paint("ground_bsdf", (0.35, 0.33, 0.3))
    post = paint("post_bsdf", (0.5, 0.45, 0.4))
    s.rectangle("ground", ground, (0, 0, 0), normal=(0, 1, 0), up=(0, 0, 1),
                width=120.0, height=120.0)
    # posts on a ring of 8 m around the camera and a lintel toward the sun:
    # shadows of both ends of the view axis
    for k, a in enumerate(np.radians(np.arange(0, 360, 24))):
        p = origin + 8.0 * np.array([np.cos(a), 0.0, np.sin(a)])
        s.cylinder(f"post_{k}", post, (p[0], 0.0, p[2]), (p[0], 7.0, p[2]), 0.35)
    toward = -travel
    centre = origin + 14.0 * toward
    side = np.cross(toward, (0.0, 1.0, 0.0))
    side /= np.linalg.norm(side)
    up = np.cross(side, toward)
    for k, off in enumerate((-2.0, -1.0, 0.0, 1.0, 2.0)):     # a grate across the axis
        c = centre + off * side
        s.cylinder(f"bar_v{k}", post, c - 3.0 * up, c + 3.0 * up, 0.15)
    for k, off in enumerate((-1.5, 0.0, 1.5)):
        c = centre + off * up
        s.cylinder(f"bar_h{k}", post, c - 3.0 * side, c + 3.0 * side, 0.12)
    s.medium_box((-60, -1, -60), (60, 30, 60))
    return s


def _yawed(v, yaw_deg: float) -> np.ndarray:
    """Direction ``v`` turned by ``yaw_deg`` about the y axis (to the left
    for positive angles when looking along ``v``)."""
    a = np.radians(yaw_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


def sun_beside(lit: bool, yaw_deg: float) -> SceneXML:
    """``sun_ahead`` with the camera turned ``yaw_deg`` away from the sun:
    the epipole off screen at a chosen distance (Klehm §4.2's projective
    rectification needs it far from the image)."""
    return _axial(lit, True, f"Camera turned {yaw_deg:g} deg from the sun (epipole off "
                             "screen)", yaw_deg=yaw_deg)


def sun_behind(lit: bool) -> SceneXML:
    """The sun exactly behind the camera: the anti-epipole at the image
    centre, the shadows of the posts converge on it."""
    return _axial(lit, False, "Sun exactly behind the camera (anti-epipole at the centre)")


def sun_ahead(lit: bool) -> SceneXML:
    """The camera looks straight at the sun: the epipole at the image centre,
    the shafts between the bars radiate from it."""
    return _axial(lit, True, "Camera looking straight at the sun (epipole at the centre)")


#: scene name -> builder, the stress scenes of issue 12
def spot_columns(lit: bool) -> SceneXML:
    """A colonnade: two rows of five round columns under a flat ceiling, a
    spot light high beside the left row aimed down across it at the aisle's
    floor, so the columns between the light and the floor cast shadows
    through the lit fog and onto the floor; the camera stands at one end of
    the aisle looking along it."""
    s = SceneXML("Spot light shining across a row of columns onto the floor of a colonnade")
    s.medium(Medium(sigma_t=0.12, albedo=0.9, phase=Phase("hg", 0.3)))
    s.camera((0.5, 1.6, -6.5), (0.0, 1.8, 3.0), fov=70.0)
    light, aim = np.array([-4.0, 5.5, 0.5]), np.array([0.8, 0.0, -0.5])
    s.spot(light, aim, intensity=2500.0, cutoff_angle=35.0, beam_width=30.0)
    s.medium_box((-4.6, -0.3, -7.2), (4.6, 6.4, 7.2))
    paint = Palette(s, lit)
    s.box("floor", paint("floor_bsdf", (0.45, 0.42, 0.38)), (-4.5, -0.2, -7.0), (4.5, 0.0, 7.0))
    s.box("ceiling", paint("ceiling_bsdf", (0.5, 0.5, 0.5)), (-4.5, 6.0, -7.0), (4.5, 6.2, 7.0))
    stone = paint("column_bsdf", (0.6, 0.58, 0.52))
    for row, x in enumerate((-1.6, 1.6)):
        for k, z in enumerate(np.linspace(4.0, -4.0, 5)):
            s.cylinder(f"column_{row}_{k}", stone, (x, 0.0, z), (x, 6.0, z), 0.3)
    s.box("lintel_left", stone, (-1.9, 5.4, -4.3), (-1.3, 6.0, 4.3))
    s.box("lintel_right", stone, (1.3, 5.4, -4.3), (1.9, 6.0, 4.3))
    return s


SCENES = {
    "sun_room": sun_room,
    "hall": hall,
    "sun_behind": sun_behind,
    "sun_ahead": sun_ahead,
    "spot_columns": spot_columns,
}
#: emitter plugin of each stress scene
EMITTER_TYPE = {**{name: "directional" for name in SCENES}, "spot_columns": "spot"}
