"""The scene suite: one function per scene, each returning a :class:`SceneXML`.

Every function takes ``lit``: ``False`` gives black surfaces (only the
scattered light shows), ``True`` the ``_lit`` variant with coloured diffuse
surfaces.  Units are meters, y is up.  Light directions are the direction
the light *travels*.
"""
from __future__ import annotations

import numpy as np

from . import assets
from .xmlbuild import Medium, Phase, SceneXML


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def sun_direction(elevation: float, azimuth: float) -> np.ndarray:
    """Direction of travel of sunlight from a sun at ``elevation`` degrees
    above the horizon and ``azimuth`` degrees from +z toward +x."""
    e, a = np.radians(elevation), np.radians(azimuth)
    toward_sun = np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
    return -toward_sun


class Palette:
    """Declares the diffuse BSDFs of a scene: black unless ``lit``."""

    def __init__(self, scene: SceneXML, lit: bool):
        self.scene, self.lit = scene, lit

    def __call__(self, ident: str, colour) -> str:
        return self.scene.bsdf(ident, colour if self.lit else 0.0)


# ---------------------------------------------------------------------------
# 1-2. Cathedral nave
# ---------------------------------------------------------------------------
NAVE = dict(half_width=6.0, half_length=20.0, height=18.0, wall=0.8,
            window_z=(-15, -10, -5, 0, 5, 10, 15), window_width=1.4,
            window_y=(5.0, 13.0), pillar_x=4.5, pillar_radius=0.45,
            pillar_top=16.5)
NAVE_SUN = sun_direction(elevation=38.0, azimuth=70.0)


def _nave_geometry(s: SceneXML, paint: Palette) -> None:
    """Floor, two side walls with tall window gaps, end walls, ceiling with
    transverse ribs, and two rows of pillars."""
    n = NAVE
    w, L, H, t = n["half_width"], n["half_length"], n["height"], n["wall"]
    floor = paint("floor_bsdf", (0.45, 0.42, 0.38))
    wall = paint("wall_bsdf", (0.55, 0.50, 0.42))
    pillar = paint("pillar_bsdf", (0.62, 0.57, 0.50))
    ceiling = paint("ceiling_bsdf", (0.35, 0.33, 0.40))
    s.box("floor", floor, (-w - t, -0.5, -L - t), (w + t, 0.0, L + t))
    s.box("ceiling", ceiling, (-w - t, H, -L - t), (w + t, H + t, L + t))
    s.box("end_wall_front", wall, (-w - t, 0, -L - t), (w + t, H, -L))
    s.box("end_wall_back", wall, (-w - t, 0, L), (w + t, H, L + t))
    y0, y1 = n["window_y"]
    half = n["window_width"] / 2
    edges = [-L - t] + [e for z in n["window_z"] for e in (z - half, z + half)] + [L + t]
    for side, x0 in (("left", -w - t), ("right", w)):
        s.box(f"wall_{side}_base", wall, (x0, 0, -L - t), (x0 + t, y0, L + t))
        s.box(f"wall_{side}_top", wall, (x0, y1, -L - t), (x0 + t, H, L + t))
        for k in range(0, len(edges), 2):
            s.box(f"wall_{side}_pier_{k // 2}", wall, (x0, y0, edges[k]),
                  (x0 + t, y1, edges[k + 1]))
    piers = [(a + b) / 2 for a, b in zip(n["window_z"][:-1], n["window_z"][1:])]
    for k, z in enumerate(piers):
        s.box(f"rib_{k}", ceiling, (-w, n["pillar_top"], z - 0.35), (w, H, z + 0.35))
        for side, x in (("left", -n["pillar_x"]), ("right", n["pillar_x"])):
            s.cylinder(f"pillar_{side}_{k}", pillar, (x, 0, z), (x, n["pillar_top"], z),
                       n["pillar_radius"])
    m = 1.5
    s.medium_box((-w - t - m, -0.5 - m, -L - t - m), (w + t + m, H + t + m, L + t + m))


def _nave(lit: bool, origin, target, fov: float, comment: str) -> SceneXML:
    s = SceneXML(comment)
    s.medium(Medium(sigma_t=0.04, albedo=0.9, phase=Phase("hg", 0.3)))
    s.camera(origin, target, fov=fov)
    s.directional(NAVE_SUN, irradiance=(26.0, 24.0, 20.0))
    _nave_geometry(s, Palette(s, lit))
    return s


def nave_offscreen(lit: bool) -> SceneXML:
    """Looking down the nave; the sun shines in across the view through the
    right-hand windows, its direction and the opposite both project far off
    the screen (epipole off-screen)."""
    return _nave(lit, origin=(0.5, 1.7, -18.5), target=(-0.5, 6.0, 20.0), fov=70.0,
                 comment="Cathedral nave, low sun through the side windows, "
                         "epipole off-screen (cf. Baran 2010 SIBENIK)")


def nave_onscreen(lit: bool) -> SceneXML:
    """Looking up toward a window the sun shines through: the direction to the
    sun projects on screen and the shafts converge on it."""
    toward_sun = -NAVE_SUN
    # place the camera so that the ray toward the sun leaves through the
    # middle of the window at z = 0; aim a little off it so the epipole sits
    # off-centre
    x0, x_wall = -3.5, NAVE["half_width"] + NAVE["wall"] / 2
    t = (x_wall - x0) / toward_sun[0]
    origin = np.array([x0, 1.7, 0.0 - t * toward_sun[2]])
    target = origin + 10 * toward_sun + np.array([-0.8, -1.2, 2.0])
    return _nave(lit, origin=origin, target=target, fov=70.0,
                 comment="Cathedral nave looking toward the sun through a window: "
                         "epipole on-screen (cf. Baran 2010 SIBENIK)")


# ---------------------------------------------------------------------------
# 3. Grove
# ---------------------------------------------------------------------------
def grove(lit: bool) -> SceneXML:
    """Trees with clumped leaf crowns on a ground plane under a low sun that
    shines from the front left through the canopy (epipole off-screen)."""
    s = SceneXML("Grove of trees under a low sun: complex visibility "
                 "(cf. Baran 2010 TREES)")
    s.medium(Medium(sigma_t=0.03, albedo=0.9, phase=Phase("hg", 0.5)))
    s.camera((0.0, 1.6, -10.0), (0.0, 4.5, 12.0), fov=65.0)
    s.directional(sun_direction(elevation=42.0, azimuth=-60.0), irradiance=(24.0, 22.0, 18.0))
    paint = Palette(s, lit)
    ground = paint("ground_bsdf", (0.25, 0.32, 0.14))
    bark = paint("bark_bsdf", (0.30, 0.22, 0.15))
    leaves = paint("leaves_bsdf", (0.20, 0.45, 0.12))
    s.rectangle("ground", ground, (0, 0, 0), normal=(0, 1, 0), up=(0, 0, 1),
                width=100.0, height=100.0)
    for k, tree in enumerate(assets.grove_trees()):
        s.cylinder(f"trunk_{k}", bark, tree.base, tree.crown_center, tree.trunk_radius)
    s.ply("leaves", leaves, "meshes/grove_leaves.ply")
    s.medium_box((-52, -1, -52), (52, 26, 52))
    return s


# ---------------------------------------------------------------------------
# 4. Terrain
# ---------------------------------------------------------------------------
def terrain(lit: bool) -> SceneXML:
    """A 1.2 km mountain heightfield (~1M triangles); the camera stands low at
    the mouth of a valley looking up it, the low sun from the left casts the
    ridges' shadows across the hazy valley."""
    s = SceneXML("Mountain terrain under a low sun (cf. Baran 2010 LANDSCAPE)")
    s.medium(Medium(sigma_t=0.0025, albedo=0.9, phase=Phase("hg", 0.6)))
    cx, cz = 0.0, -560.0
    ground = assets.terrain_height_at(cx, cz)
    s.camera((cx, ground + 25.0, cz), (0.0, ground + 50.0, 300.0), fov=70.0)
    s.directional(sun_direction(elevation=6.0, azimuth=40.0), irradiance=(25.0, 22.0, 18.0))
    paint = Palette(s, lit)
    rock = paint("terrain_bsdf", (0.36, 0.33, 0.27))
    s.ply("terrain", rock, "meshes/terrain.ply")
    half = assets.TERRAIN["size"] / 2 + 10.0
    top = float(assets.terrain_heights().max()) + 120.0
    s.medium_box((-half, -10.0, -half), (half, top, half))
    return s


# ---------------------------------------------------------------------------
# 5. Spot room with stained glass
# ---------------------------------------------------------------------------
def _room(s: SceneXML, paint: Palette, half_x: float, height: float, half_z: float,
          colours=None) -> None:
    """A closed box room (inner faces visible) from walls of thickness 0.3 m."""
    t = 0.3
    colours = colours or {}
    floor = paint("floor_bsdf", colours.get("floor", (0.5, 0.45, 0.4)))
    wall = paint("wall_bsdf", colours.get("wall", (0.55, 0.55, 0.55)))
    ceiling = paint("ceiling_bsdf", colours.get("ceiling", (0.45, 0.45, 0.5)))
    X, Z = half_x + t, half_z + t
    s.box("floor", floor, (-X, -t, -Z), (X, 0, Z))
    s.box("ceiling", ceiling, (-X, height, -Z), (X, height + t, Z))
    s.box("wall_left", wall, (-X, 0, -Z), (-half_x, height, Z))
    s.box("wall_right", wall, (half_x, 0, -Z), (X, height, Z))
    s.box("wall_back", wall, (-half_x, 0, half_z), (half_x, height, Z))
    s.box("wall_front", wall, (-half_x, 0, -Z), (half_x, height, -half_z))
    m = 1.0
    s.medium_box((-X - m, -t - m, -Z - m), (X + m, height + t + m, Z + m))


def spot_room(lit: bool) -> SceneXML:
    """A room lit by a spot light high in a corner that projects a stained
    glass texture diagonally across the room; a sphere, a bar and a box sit
    in the beam."""
    s = SceneXML("Room with a stained-glass spot light and occluders in the beam")
    s.medium(Medium(sigma_t=0.1, albedo=0.9, phase=Phase("hg", 0.25)))
    s.camera((-4.5, 1.4, -3.6), (0.0, 1.3, 0.8), fov=75.0)
    light, aim = np.array([-4.4, 3.6, 3.4]), np.array([1.0, 0.0, -1.2])
    s.spot(light, aim, intensity=1500.0, cutoff_angle=24.0, beam_width=20.0,
           texture="textures/stained_glass.png")
    paint = Palette(s, lit)
    _room(s, paint, half_x=5.0, height=4.0, half_z=4.0)
    obj = paint("occluder_bsdf", (0.6, 0.25, 0.2))
    axis = aim - light
    s.sphere("sphere", obj, light + 0.33 * axis + np.array([0.25, 0.0, 0.2]), 0.35)
    bar_c = light + 0.55 * axis
    bar_d = 1.6 * _unit(np.cross(axis, (0, 1, 0)))
    s.cylinder("bar", obj, bar_c - bar_d, bar_c + bar_d, 0.08)
    s.box("crate", obj, aim + np.array([-0.9, 0.0, 0.3]), aim + np.array([-0.1, 0.8, 1.1]),
          rotate_y=25.0)
    return s


# ---------------------------------------------------------------------------
# 6. Point light in thick fog
# ---------------------------------------------------------------------------
def point_fog(lit: bool) -> SceneXML:
    """A point light among pillars, boxes and spheres in thick isotropic fog
    (optical depth ~3 across the room); the light is in view."""
    s = SceneXML("Point light among occluders in thick fog (isotropic phase)")
    s.medium(Medium(sigma_t=0.25, albedo=0.9, phase=Phase("isotropic")))
    s.camera((-5.0, 1.7, -5.2), (0.6, 2.3, 1.0), fov=70.0)
    light = np.array([0.0, 2.4, 1.0])
    s.point(light, intensity=(150.0, 135.0, 110.0))
    paint = Palette(s, lit)
    _room(s, paint, half_x=6.0, height=5.0, half_z=6.0,
          colours={"floor": (0.4, 0.38, 0.35), "wall": (0.5, 0.5, 0.52)})
    stone = paint("pillar_bsdf", (0.6, 0.58, 0.52))
    obj = paint("object_bsdf", (0.25, 0.35, 0.6))
    for k, a in enumerate(np.radians([20, 95, 170, 250, 320])):
        p = light + 1.8 * np.array([np.cos(a), 0, np.sin(a)])
        s.cylinder(f"pillar_{k}", stone, (p[0], 0, p[2]), (p[0], 5.0, p[2]), 0.22)
    s.sphere("sphere_0", obj, light + (0.7, 0.6, -0.4), 0.25)
    s.sphere("sphere_1", obj, light + (-0.6, -0.5, -0.5), 0.2)
    s.sphere("sphere_2", obj, light + (0.2, 1.2, 0.6), 0.3)
    s.box("box_0", obj, light + (-1.0, -2.4, -1.6), light + (0.0, -1.6, -0.6), rotate_y=30)
    s.box("box_1", obj, light + (1.0, -2.4, 0.4), light + (1.8, -0.8, 1.2), rotate_y=-15)
    return s


# ---------------------------------------------------------------------------
# 7. Narrow beam onto a plane
# ---------------------------------------------------------------------------
def beam(lit: bool) -> SceneXML:
    """A dark room whose ceiling has one small square opening: the sun makes
    a thin shaft down onto the floor, seen against the floor plane (Baran
    2010 Fig. 13)."""
    s = SceneXML("Narrow beam of sunlight through a ceiling hole onto the floor "
                 "(cf. Baran 2010 Fig. 13)")
    s.medium(Medium(sigma_t=0.08, albedo=0.9, phase=Phase("hg", 0.3)))
    s.camera((0.0, 1.8, -4.6), (0.0, 0.4, 2.0), fov=60.0)
    s.directional(sun_direction(elevation=65.0, azimuth=70.0), irradiance=300.0)
    paint = Palette(s, lit)
    hx, hz, height, t = 5.0, 5.0, 5.0, 0.3
    floor = paint("floor_bsdf", (0.55, 0.52, 0.48))
    wall = paint("wall_bsdf", (0.45, 0.45, 0.5))
    board = paint("board_bsdf", (0.4, 0.35, 0.3))
    X, Z = hx + t, hz + t
    s.rectangle("floor", floor, (0, 0, 0), normal=(0, 1, 0), up=(0, 0, 1),
                width=2 * X, height=2 * Z)
    s.box("wall_left", wall, (-X, 0, -Z), (-hx, height, Z))
    s.box("wall_right", wall, (hx, 0, -Z), (X, height, Z))
    s.box("wall_back", wall, (-hx, 0, hz), (hx, height, Z))
    s.box("wall_front", wall, (-hx, 0, -Z), (hx, height, -hz))
    # the board: the ceiling as four slabs around a 0.4 m square hole
    (h0x, h0z), size = (1.6, 2.4), 0.4
    y0, y1 = height, height + t
    s.box("board_west", board, (-X, y0, -Z), (h0x, y1, Z))
    s.box("board_east", board, (h0x + size, y0, -Z), (X, y1, Z))
    s.box("board_south", board, (h0x, y0, -Z), (h0x + size, y1, h0z))
    s.box("board_north", board, (h0x, y0, h0z + size), (h0x + size, y1, Z))
    m = 1.0
    s.medium_box((-X - m, -1.0, -Z - m), (X + m, y1 + m, Z + m))
    return s


#: scene name -> builder, in suite order
SCENES = {
    "nave_offscreen": nave_offscreen,
    "nave_onscreen": nave_onscreen,
    "grove": grove,
    "terrain": terrain,
    "spot_room": spot_room,
    "point_fog": point_fog,
    "beam": beam,
}
