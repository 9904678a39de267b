"""Scenes written the way users write them, generated from a seed: the
held-out set of ``quality="auto"`` (``experiments.error_budget --kind
user``), apart from the suite its rules were fitted on and from the
stability generator's boxes (:mod:`experiments.random_scenes`).

``user_scene(seed) -> UserScene`` (``.name``, ``.at_resolution(w, h)``,
``.load()``, ``.scene_dict()``); the seed picks one of :data:`ARCHETYPES`
in turn, then everything else:

``window_room``
    a closed room (walls, floor, ceiling), the sun through a window of
    mullions and transoms in one wall, the camera inside looking across
    the shafts.
``bar_lattice``
    a spot light, textured (a checkerboard gobo) half of the time, above a
    lattice of thin bars; the camera looks across the barred beam.
``light_in_view``
    a point light inside the view among columns, its shadows radiating
    across the screen.
``colonnade``
    a low sun behind a row of columns, beams between them toward the
    camera or across the view.
``canopy``
    the sun from high above through a canopy of leaves (small discs and
    spheres) over a floor.

Media: σt·S log-uniform over [0.1, 10] (S the room's size: thin haze to
thick fog), albedo in [0.3, 1], a coloured σt one time in four, and an
isotropic or Henyey-Greenstein phase function (g up to 0.6).  The fog
fills a box around the whole scene (the camera inside it).

Nothing here runs an integrator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from experiments.random_scenes import light_dict


#: the scene archetypes (module doc), in the order the seeds take them
ARCHETYPES = ("window_room", "bar_lattice", "light_in_view", "colonnade", "canopy")
#: the room's half size (world units)
S = 2.0


@dataclass
class UserScene:
    """One generated user-style scene as a Mitsuba scene dictionary
    (without its film's size: :meth:`at_resolution`)."""
    seed: int
    archetype: str
    shapes: dict
    light: dict
    medium: dict
    camera: dict
    fov: float
    width: int = 160
    height: int = 120
    notes: list = field(default_factory=list)

    @property
    def name(self) -> str:
        return f"user {self.seed} ({self.archetype}{', ' if self.notes else ''}" \
               f"{', '.join(self.notes)})"

    def at_resolution(self, width: int, height: int) -> "UserScene":
        return replace(self, width=int(width), height=int(height))

    def scene_dict(self) -> dict:
        import mitsuba as mi

        T = mi.ScalarTransform4f
        d = {"type": "scene",
             "medium": {"type": "homogeneous", "id": "fog", **self.medium},
             "sensor": {"type": "perspective", "fov": self.fov,
                        "to_world": T().look_at(**self.camera),
                        "film": {"type": "hdrfilm", "width": self.width, "height": self.height,
                                 "rfilter": {"type": "box"}},
                        "medium": {"type": "ref", "id": "fog"},
                        "sampler": {"type": "independent", "sample_count": 1}},
             "fog_volume": {"type": "cube", "to_world": T().scale(1.5 * S),
                            "bsdf": {"type": "null"}, "interior": {"type": "ref", "id": "fog"}},
             "light": light_dict(self.light)}
        for k, shape in self.shapes.items():
            d[k] = _shape_dict(shape)
        return d

    def load(self):
        import mitsuba as mi

        return mi.load_dict(self.scene_dict())


def user_scene(seed: int) -> UserScene:
    """The user-style scene of ``seed`` (module doc)."""
    rng = np.random.default_rng([seed, 7001])
    archetype = ARCHETYPES[seed % len(ARCHETYPES)]
    medium, notes = _medium(rng)
    shapes, light, camera, fov, more = _BUILDERS[archetype](rng)
    return UserScene(seed, archetype, shapes, light, medium, camera, fov, notes=notes + more)


def _medium(rng) -> tuple[dict, list]:
    optical = math.exp(rng.uniform(math.log(0.1), math.log(10.0)))     # σt·S
    sigma_t = optical / S
    notes = [f"σt·S {optical:.2g}"]
    scale = 1.0
    if rng.random() < 0.25:
        tint = rng.uniform(0.6, 1.4, 3)
        # an RGB value in [0, 1] (Mitsuba's) times the medium's scale
        sigma = {"type": "rgb", "value": [float(t / tint.max()) for t in tint]}
        scale = float(sigma_t * tint.max())
        notes.append("coloured σt")
    else:
        sigma = float(sigma_t)
    albedo = float(rng.uniform(0.3, 1.0))
    if rng.random() < 0.5:
        phase = {"type": "isotropic"}
    else:
        g = float(rng.uniform(0.1, 0.6))
        phase = {"type": "hg", "g": g}
        notes.append(f"hg {g:.2f}")
    return {"sigma_t": sigma, "scale": scale, "albedo": albedo, "phase": phase}, notes


def _box(centre, half, reflectance=0.5) -> dict:
    return {"kind": "box", "centre": [float(c) for c in centre],
            "half": [float(h) for h in half], "reflectance": float(reflectance)}


def _bar(p0, p1, radius, reflectance=0.4) -> dict:
    return {"kind": "bar", "p0": [float(c) for c in p0], "p1": [float(c) for c in p1],
            "radius": float(radius), "reflectance": float(reflectance)}


def _room_walls(skip=None, window=None) -> dict:
    """Floor, ceiling and four walls of the room [-S, S]³ (``skip``: the
    wall ``"+x"`` etc. that ``window`` replaces by four slabs around an
    opening (y0, y1, z0, z1))."""
    t = 0.05
    walls = {"floor": _box([0, -S - t, 0], [S, t, S], 0.5),
             "ceiling": _box([0, S + t, 0], [S, t, S], 0.6)}
    for name, axis, sign in (("+x", 0, 1), ("-x", 0, -1), ("+z", 2, 1), ("-z", 2, -1)):
        centre, half = [0.0, 0.0, 0.0], [S, S, S]
        centre[axis], half[axis] = sign * (S + t), t
        if name != skip:
            walls[f"wall{name}"] = _box(centre, half, 0.55)
            continue
        y0, y1, z0, z1 = window          # the opening, in the wall's (y, other) coordinates
        o = 2 - axis if axis != 1 else 0  # the wall's other horizontal axis
        for part, (ylo, yhi, olo, ohi) in {"below": (-S, y0, -S, S), "above": (y1, S, -S, S),
                                           "left": (y0, y1, -S, z0),
                                           "right": (y0, y1, z1, S)}.items():
            if yhi - ylo <= 1e-3 or ohi - olo <= 1e-3:
                continue
            c, h = list(centre), list(half)
            c[1], h[1] = 0.5 * (ylo + yhi), 0.5 * (yhi - ylo)
            c[o], h[o] = 0.5 * (olo + ohi), 0.5 * (ohi - olo)
            walls[f"wall{name}_{part}"] = _box(c, h, 0.55)
    return walls


def _window_room(rng):
    y0, y1 = rng.uniform(-0.6, 0.2) * S, rng.uniform(0.5, 0.9) * S
    z0, z1 = rng.uniform(-0.7, -0.2) * S, rng.uniform(0.2, 0.7) * S
    shapes = _room_walls(skip="+x", window=(y0, y1, z0, z1))
    x = S + 0.05
    mullions, transoms = int(rng.integers(1, 5)), int(rng.integers(0, 3))
    r = float(rng.uniform(0.01, 0.04)) * S
    for i in range(mullions):
        z = z0 + (i + 1) * (z1 - z0) / (mullions + 1)
        shapes[f"mullion_{i}"] = _bar([x, y0, z], [x, y1, z], r)
    for i in range(transoms):
        y = y0 + (i + 1) * (y1 - y0) / (transoms + 1)
        shapes[f"transom_{i}"] = _bar([x, y, z0], [x, y, z1], r)
    elevation = math.radians(rng.uniform(15, 60))
    azimuth = math.radians(rng.uniform(-35, 35))
    direction = [-math.cos(elevation) * math.cos(azimuth), -math.sin(elevation),
                 math.cos(elevation) * math.sin(azimuth)]
    light = {"type": "directional", "direction": direction,
             "irradiance": float(rng.uniform(2, 8))}
    eye = [rng.uniform(-0.8, -0.3) * S, rng.uniform(-0.5, 0.3) * S, rng.uniform(-0.6, 0.6) * S]
    target = [rng.uniform(0.0, 0.8) * S, rng.uniform(-0.6, 0.0) * S, rng.uniform(-0.5, 0.5) * S]
    camera = {"origin": eye, "target": target, "up": [0, 1, 0]}
    return shapes, light, camera, float(rng.uniform(45, 75)), \
        [f"{mullions}x{transoms} window bars"]


def _bar_lattice(rng):
    shapes = {"floor": _box([0, -S - 0.05, 0], [S, 0.05, S], 0.5)}
    n = int(rng.integers(4, 11))
    r = float(rng.uniform(0.005, 0.02)) * S
    h = rng.uniform(0.2, 0.6) * S
    for i in range(n):
        x = -0.6 * S + 1.2 * S * i / (n - 1)
        shapes[f"bar_{i}"] = _bar([x, h, -0.8 * S], [x, h, 0.8 * S], r)
        shapes[f"cross_{i}"] = _bar([-0.8 * S, h + 2.5 * r, x], [0.8 * S, h + 2.5 * r, x], r)
    pos = [rng.uniform(-0.3, 0.3) * S, rng.uniform(0.8, 1.2) * S, rng.uniform(-0.3, 0.3) * S]
    cutoff = float(rng.uniform(20, 45))
    light = {"type": "spot", "intensity": float(rng.uniform(10, 40)), "cutoff_angle": cutoff,
             "beam_width": 0.8 * cutoff, "position": pos,
             "target": [rng.uniform(-0.3, 0.3) * S, -S, rng.uniform(-0.3, 0.3) * S],
             "up": [0, 0, 1]}
    notes = [f"{n} bars"]
    if rng.random() < 0.5:
        light["texture"] = float(rng.uniform(2, 8))
        notes.append("textured spot")
    eye = [rng.uniform(0.6, 0.95) * S, rng.uniform(-0.6, 0.2) * S, rng.uniform(0.6, 0.95) * S]
    camera = {"origin": eye, "target": [0, rng.uniform(-0.6, 0.0) * S, 0], "up": [0, 1, 0]}
    return shapes, light, camera, float(rng.uniform(50, 75)), notes


def _light_in_view(rng):
    shapes = {"floor": _box([0, -S - 0.05, 0], [S, 0.05, S], 0.5)}
    n = int(rng.integers(3, 9))
    for i in range(n):
        a = 2 * math.pi * (i + rng.uniform(-0.3, 0.3)) / n
        rad = rng.uniform(0.3, 0.7) * S
        c = [rad * math.cos(a), rad * math.sin(a)]
        shapes[f"column_{i}"] = _bar([c[0], -S, c[1]], [c[0], rng.uniform(0.0, 0.8) * S, c[1]],
                                     rng.uniform(0.03, 0.1) * S)
    eye = np.array([rng.uniform(-0.2, 0.2) * S, rng.uniform(-0.3, 0.2) * S, 0.95 * S])
    pos = [rng.uniform(-0.25, 0.25) * S, rng.uniform(-0.3, 0.4) * S, rng.uniform(-0.3, 0.3) * S]
    light = {"type": "point", "position": pos, "intensity": float(rng.uniform(3, 15))}
    camera = {"origin": eye.tolist(),
              "target": [pos[0] + rng.uniform(-0.2, 0.2), pos[1] + rng.uniform(-0.2, 0.2),
                         pos[2]], "up": [0, 1, 0]}
    return shapes, light, camera, float(rng.uniform(50, 80)), [f"{n} columns"]


def _colonnade(rng):
    shapes = {"floor": _box([0, -S - 0.05, 0], [S, 0.05, S], 0.5)}
    n = int(rng.integers(4, 9))
    r = float(rng.uniform(0.04, 0.12)) * S
    x = rng.uniform(-0.2, 0.2) * S
    for i in range(n):
        z = -0.9 * S + 1.8 * S * i / (n - 1)
        shapes[f"column_{i}"] = _bar([x, -S, z], [x, 0.9 * S, z], r)
    shapes["lintel"] = _box([x, 0.95 * S, 0], [1.5 * r, 0.05 * S, S], 0.5)
    elevation = math.radians(rng.uniform(8, 40))
    azimuth = math.radians(rng.uniform(-60, 60))
    direction = [math.cos(elevation) * math.cos(azimuth), -math.sin(elevation),
                 math.cos(elevation) * math.sin(azimuth)]
    light = {"type": "directional", "direction": direction,
             "irradiance": float(rng.uniform(2, 8))}
    side = 1.0 if rng.random() < 0.5 else -1.0     # toward the sun (beams at the camera) or away
    eye = [side * rng.uniform(0.6, 0.95) * S, rng.uniform(-0.5, 0.3) * S,
           rng.uniform(-0.8, 0.8) * S]
    camera = {"origin": eye, "target": [x, rng.uniform(-0.5, 0.2) * S, rng.uniform(-0.4, 0.4) * S],
              "up": [0, 1, 0]}
    return shapes, light, camera, float(rng.uniform(50, 75)), \
        [f"{n} columns", "facing the sun" if side > 0 else "sun behind"]


def _canopy(rng):
    shapes = {"floor": _box([0, -S - 0.05, 0], [S, 0.05, S], 0.5)}
    n = int(rng.integers(30, 90))
    for i in range(n):
        c = [rng.uniform(-0.95, 0.95) * S, rng.uniform(0.6, 0.95) * S,
             rng.uniform(-0.95, 0.95) * S]
        if rng.random() < 0.5:
            shapes[f"leaf_{i}"] = {"kind": "sphere", "centre": c,
                                   "radius": float(rng.uniform(0.03, 0.12) * S),
                                   "reflectance": 0.3}
        else:
            shapes[f"leaf_{i}"] = _box(c, [rng.uniform(0.03, 0.15) * S, 0.01 * S,
                                          rng.uniform(0.03, 0.15) * S], 0.3)
    for i in range(int(rng.integers(2, 6))):
        c = [rng.uniform(-0.8, 0.8) * S, rng.uniform(-0.8, 0.8) * S]
        shapes[f"trunk_{i}"] = _bar([c[0], -S, c[1]], [c[0], 0.7 * S, c[1]],
                                    rng.uniform(0.03, 0.08) * S)
    elevation = math.radians(rng.uniform(45, 85))
    azimuth = rng.uniform(0, 2 * math.pi)
    direction = [math.cos(elevation) * math.cos(azimuth), -math.sin(elevation),
                 math.cos(elevation) * math.sin(azimuth)]
    light = {"type": "directional", "direction": direction,
             "irradiance": float(rng.uniform(2, 8))}
    eye = [rng.uniform(-0.9, 0.9) * S, rng.uniform(-0.8, -0.3) * S, rng.uniform(-0.9, 0.9) * S]
    camera = {"origin": eye, "target": [0, rng.uniform(-0.2, 0.6) * S, 0], "up": [0, 1, 0]}
    return shapes, light, camera, float(rng.uniform(55, 80)), [f"{n} leaves"]


_BUILDERS = {"window_room": _window_room, "bar_lattice": _bar_lattice,
             "light_in_view": _light_in_view, "colonnade": _colonnade, "canopy": _canopy}


def _shape_dict(shape: dict) -> dict:
    import mitsuba as mi

    T = mi.ScalarTransform4f
    bsdf = {"type": "diffuse", "reflectance": shape["reflectance"]}
    if shape["kind"] == "box":
        return {"type": "cube", "bsdf": bsdf,
                "to_world": T().translate(shape["centre"]).scale(shape["half"])}
    if shape["kind"] == "sphere":
        return {"type": "sphere", "center": shape["centre"], "radius": shape["radius"],
                "bsdf": bsdf}
    return {"type": "cylinder", "p0": shape["p0"], "p1": shape["p1"], "radius": shape["radius"],
            "bsdf": bsdf}
