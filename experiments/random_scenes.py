"""Randomised test scenes for every integrator (issue 13): fixed seeds ->
Mitsuba scene dicts.

Each scene is a homogeneous medium box (an axis-aligned null-BSDF ``cube``
of half-size ``B``) around a perspective camera, with random box-shaped and
spherical occluders, one light (``directional``, ``point``, ``spot`` with or
without a projected checkerboard ``texture``; 1-6 of them, a rotated box
or a sphere as the boundary and the camera outside it in the extended set), an isotropic or
Henyey-Greenstein phase function, σt over six decades of optical depth
(σt·B from 1e-3 to 1e3) and a small image (odd and even sizes down to 1x1).
No integrator is set: pass the one to test to ``mi.render``.

API
---
``random_scene(seed, kind=None) -> SceneSpec``
    The scene of ``seed``; ``kind`` (:data:`KINDS`, :data:`FORCED_KINDS`) forces a case
    class, else the seed picks it (:func:`kind_of_seed`).
``scene_set(n, first_seed=0, extended=False) -> list[SceneSpec]``
    ``n`` consecutive seeds; the case classes recur every
    ``len(KIND_CYCLE)`` seeds.  ``extended``: each scene with 1-6 lights of
    mixed kinds, a box, rotated box or sphere boundary, the camera inside
    or outside it (:func:`extended_scene`; the scene is otherwise the
    seed's own).
``SceneSpec``
    Plain data (JSON-able via :meth:`SceneSpec.as_json`): ``.scene_dict()``
    builds the ``mi.load_dict`` input, ``.load()`` loads it,
    ``.scene_dict(occluders=False)`` the same scene without occluders (its
    peak is the "unoccluded peak" leaks are measured against), ``.name``
    says seed and kind.

Case classes (:data:`KINDS`), the failure classes of issue 13 made explicit:

``random``
    everything random.
``sun_axis``
    the sun within 0.5° of the view axis (epipole on screen) and 8-14
    occluders (issue 13, class 1).
``light_at_eye``
    a point or spot light within ~1e-3·B of the camera, in front of or
    behind it (class 2).
``light_on_pixel``
    a point light on a pixel centre's ray, 1e-2 of a pixel off it (class 3;
    exactly on it the pixel's integral of 1/r² diverges).
``light_near_face``
    a point light 4e-4·B from an occluder box's face (class 4).
``narrow_spot``
    a narrow spot light aimed across the edge of the view so that only a
    few pixels see lit fog (class 5).
``grazing``
    a light grazing the medium box's top face, the camera just under it
    looking away from the light (most light rays leave the box far behind
    the eye).
``thick``
    σt·B in [3, 300] (the scattering comes from the first mean free paths).
``enclosed``
    a point light inside a closed occluder box: the reference is black,
    which measures leaks.
``shafts``
    (:data:`FORCED_KINDS`: only when forced, so the cycle's seeds are
    unchanged) scenes where an error budget matters: σt·B in [0.3, 30],
    3-8 occluders inside the view frustum between the light and the eye,
    and a light that casts their shadows across the screen (a directional
    light 20-160° off the view axis, or a point/spot light inside the
    frustum); the held-out set of ``experiments.error_budget``.

Nothing here runs an integrator; it needs Mitsuba only to place a light on
a pixel's ray (``light_on_pixel``, through the sensor's own ``sample_ray``).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

#: case classes (module doc)
KINDS = ("random", "sun_axis", "light_at_eye", "light_on_pixel", "light_near_face",
         "narrow_spot", "grazing", "thick", "enclosed")
#: case classes drawn only when forced (``random_scene(seed, kind)``), never by the cycle
FORCED_KINDS = ("shafts",)
#: the order :func:`kind_of_seed` cycles through: ``random`` twice as often
KIND_CYCLE = ("random", "sun_axis", "light_at_eye", "random", "light_on_pixel",
              "light_near_face", "random", "narrow_spot", "grazing", "thick", "enclosed")
#: image sizes (width, height) drawn from: odd, even, degenerate
RESOLUTIONS = ((1, 1), (1, 2), (2, 1), (3, 5), (8, 6), (9, 7), (16, 12), (17, 13),
               (24, 18), (32, 24), (33, 25), (61, 17), (17, 61), (40, 30))


@dataclass
class SceneSpec:
    """One random scene as plain data (module doc).  Lengths in world units;
    the medium box is ``[-B, B]³`` (``box_half`` = B)."""
    seed: int
    kind: str
    res: tuple[int, int]
    box_half: float
    origin: list[float]
    target: list[float]
    up: list[float]
    fov: float
    sigma_t: float
    albedo: float
    g: float | None                       # HG asymmetry; None = isotropic
    light: dict                           # type + plain parameters (see light_dict)
    occluders: list[dict] = field(default_factory=list)   # {"shape": "box"/"sphere", ...}
    #: lights besides ``light`` (the extended generator, :func:`extended_scene`)
    more_lights: list[dict] = field(default_factory=list)
    #: the medium's boundary: ``box`` (the cube [-B, B]³), ``rotated_box``
    #: (a cube of half-size √3·B, turned: it holds that cube) or ``sphere``
    #: (radius √3·B, holding the cube)
    boundary: str = "box"
    #: rotation of ``rotated_box``: (axis, degrees)
    boundary_rotation: tuple = ((0.0, 1.0, 0.0), 0.0)
    #: the camera outside the boundary, looking into the fog (no medium on
    #: the sensor)
    camera_outside: bool = False

    @property
    def features(self) -> list[str]:
        """What the extended generator changed: ``lights``, ``rotated_box``,
        ``sphere``, ``camera_outside``."""
        return ((["lights"] if self.more_lights else [])
                + ([self.boundary] if self.boundary != "box" else [])
                + (["camera_outside"] if self.camera_outside else []))

    @property
    def name(self) -> str:
        more = f" +{len(self.more_lights)} lights" if self.more_lights else ""
        shape = "" if self.boundary == "box" else f" {self.boundary}"
        out = " outside" if self.camera_outside else ""
        return (f"seed {self.seed} ({self.kind}, {self.light['type']}{more}{shape}{out}, "
                f"{self.res[0]}x{self.res[1]})")

    @property
    def lights(self) -> list[dict]:
        return [self.light] + list(self.more_lights)

    def at_resolution(self, width: int, height: int) -> "SceneSpec":
        """The same scene rendered at ``width`` x ``height`` (the camera,
        lights and media unchanged; the seed's own ``res`` is untouched)."""
        return replace(self, res=(int(width), int(height)))

    def as_json(self) -> dict:
        return json.loads(json.dumps(asdict(self)))

    def scene_dict(self, occluders: bool = True) -> dict:
        """The ``mi.load_dict`` input (no integrator); ``occluders=False``
        leaves the occluders out."""
        import mitsuba as mi

        T = mi.ScalarTransform4f
        B = self.box_half
        phase = ({"type": "isotropic"} if self.g is None else {"type": "hg", "g": self.g})
        d = {
            "type": "scene",
            "medium": {"type": "homogeneous", "id": "medium", "sigma_t": self.sigma_t,
                       "albedo": self.albedo, "phase": phase},
            "sensor": {"type": "perspective", "fov": self.fov, "near_clip": 1e-4 * B,
                       "far_clip": 100.0 * B,
                       "to_world": T().look_at(origin=self.origin, target=self.target,
                                               up=self.up),
                       "film": {"type": "hdrfilm", "width": self.res[0],
                                "height": self.res[1], "rfilter": {"type": "box"}},
                       # one sample per pixel, at its centre: the stress set's
                       # like-for-like convention (the integrators honour it)
                       "sampler": {"type": "independent", "sample_count": 1},
                       "medium": {"type": "ref", "id": "medium"}},
            "box": self._boundary_dict(),
            "light": light_dict(self.light),
        }
        for i, light in enumerate(self.more_lights):
            d[f"light_{i + 2}"] = light_dict(light)
        if self.camera_outside:
            del d["sensor"]["medium"]
        if occluders:
            for i, o in enumerate(self.occluders):
                d[f"occluder_{i}"] = _occluder_dict(o)
        return d

    def _boundary_dict(self) -> dict:
        import mitsuba as mi

        T = mi.ScalarTransform4f
        B = self.box_half
        inside = {"bsdf": {"type": "null"}, "interior": {"type": "ref", "id": "medium"}}
        if self.boundary == "sphere":
            return {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": math.sqrt(3) * B,
                    **inside}
        if self.boundary == "rotated_box":
            axis, deg = self.boundary_rotation
            return {"type": "cube", "to_world": T().rotate(list(axis), deg).scale(math.sqrt(3) * B),
                    **inside}
        return {"type": "cube", "to_world": T().scale(B), **inside}

    def load(self, occluders: bool = True):
        import mitsuba as mi

        return mi.load_dict(self.scene_dict(occluders))


def light_dict(light: dict) -> dict:
    """The Mitsuba dictionary of a light given as plain data (type,
    direction/position, irradiance/intensity; a spot's cutoff, beam width,
    position, target, up and checkerboard ``texture`` scale)."""
    import mitsuba as mi

    T = mi.ScalarTransform4f
    if light["type"] == "directional":
        return {"type": "directional", "direction": light["direction"],
                "irradiance": light["irradiance"]}
    if light["type"] == "point":
        return {"type": "point", "position": light["position"],
                "intensity": light["intensity"]}
    d = {"type": "spot", "intensity": light["intensity"],
         "cutoff_angle": light["cutoff_angle"], "beam_width": light["beam_width"],
         "to_world": T().look_at(origin=light["position"], target=light["target"],
                                 up=light["up"])}
    if light.get("texture"):
        d["texture"] = {"type": "checkerboard",
                        "color0": {"type": "rgb", "value": [1.0, 0.2, 0.1]},
                        "color1": {"type": "rgb", "value": [0.1, 0.3, 1.0]},
                        "to_uv": mi.ScalarTransform3f().scale(light["texture"])}
    return d


def _occluder_dict(o: dict) -> dict:
    import mitsuba as mi

    T = mi.ScalarTransform4f
    bsdf = {"type": "diffuse", "reflectance": o["reflectance"]}
    if o["shape"] == "sphere":
        return {"type": "sphere", "center": o["center"], "radius": o["radius"], "bsdf": bsdf}
    to_world = (T().translate(o["center"]).rotate(o["axis"], o["angle"])
                .scale(o["half_size"]))
    return {"type": "cube", "to_world": to_world, "bsdf": bsdf}


# --------------------------------------------------------------------------
# Random pieces
# --------------------------------------------------------------------------

def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _random_unit(rng) -> np.ndarray:
    return _unit(rng.normal(size=3))


def _basis(forward, up):
    """(right, up', forward) orthonormal, as ``look_at`` builds it."""
    f = _unit(forward)
    r = _unit(np.cross(up, f))
    return r, np.cross(f, r), f


def _rotate_towards(v, angle_rad: float, rng) -> np.ndarray:
    """``v`` turned by ``angle_rad`` about a random axis perpendicular to it."""
    v = _unit(v)
    p = _unit(np.cross(v, _random_unit(rng)))
    return math.cos(angle_rad) * v + math.sin(angle_rad) * p


def _camera(rng, B: float, spread: float = 0.7):
    origin = rng.uniform(-spread, spread, 3) * B
    forward = _random_unit(rng)
    up = _random_unit(rng)
    while abs(float(np.dot(up, forward))) > 0.9:
        up = _random_unit(rng)
    return origin, forward, up


def _occluders(rng, B: float, n: int, eye, keep_clear: list) -> list[dict]:
    """``n`` boxes and spheres inside the medium box, none containing the
    eye or a point of ``keep_clear`` (with a margin)."""
    out = []
    tries = 0
    while len(out) < n and tries < 50 * n + 50:
        tries += 1
        centre = rng.uniform(-0.9, 0.9, 3) * B
        size = float(B * 10 ** rng.uniform(-1.5, -0.5))
        clear = [eye] + list(keep_clear)
        if min(np.linalg.norm(centre - np.asarray(p)) for p in clear) < 2.0 * size:
            continue
        out.append(_occluder_at(rng, centre, size))
    return out


def _occluder_at(rng, centre, size: float) -> dict:
    """A sphere of radius ``size`` or a randomly turned box of half-sizes
    up to ``size`` at ``centre``, random reflectance."""
    refl = float(rng.uniform(0.1, 0.9))
    if rng.random() < 0.5:
        return {"shape": "sphere", "center": centre.tolist(), "radius": size,
                "reflectance": refl}
    half = (size * rng.uniform(0.2, 1.0, 3)).tolist()
    return {"shape": "box", "center": centre.tolist(), "half_size": half,
            "axis": _random_unit(rng).tolist(), "angle": float(rng.uniform(0, 180)),
            "reflectance": refl}


def _point(position, intensity) -> dict:
    return {"type": "point", "position": [float(x) for x in position],
            "intensity": float(intensity)}


def _spot(rng, position, target, cutoff: float, texture: bool | None = None) -> dict:
    if texture is None:
        texture = rng.random() < 0.5
    aim = _unit(np.asarray(target) - np.asarray(position))
    up = _random_unit(rng)
    while abs(float(np.dot(up, aim))) > 0.9:
        up = _random_unit(rng)
    return {"type": "spot", "position": [float(x) for x in position],
            "target": [float(x) for x in target], "up": up.tolist(),
            "intensity": float(10 ** rng.uniform(0, 2)), "cutoff_angle": float(cutoff),
            "beam_width": float(cutoff * rng.uniform(0.3, 1.0)),
            "texture": float(rng.choice([2.0, 4.0, 8.0])) if texture else 0.0}


def _random_light(rng, B: float):
    kind = rng.choice(["directional", "point", "spot"])
    if kind == "directional":
        return {"type": "directional", "direction": _random_unit(rng).tolist(),
                "irradiance": float(10 ** rng.uniform(-0.5, 0.5))}
    pos = rng.uniform(-1.2, 1.2, 3) * B          # may lie outside the medium box
    intensity = float(10 ** rng.uniform(0, 2)) * B * B
    if kind == "point":
        return _point(pos, intensity)
    light = _spot(rng, pos, rng.uniform(-0.5, 0.5, 3) * B, float(rng.uniform(5, 60)))
    light["intensity"] = intensity
    return light


def _pixel_ray_direction(spec: SceneSpec, i: int, j: int) -> np.ndarray:
    """World direction of the camera ray through pixel (i, j)'s centre (the
    sensor's own ``sample_ray``)."""
    import mitsuba as mi

    sensor = dict(spec.scene_dict(occluders=False)["sensor"])
    sensor.pop("medium")
    sensor = mi.load_dict(sensor)
    W, H = spec.res
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((i + 0.5) / W, (j + 0.5) / H),
                               mi.Point2f(0.5, 0.5))
    return np.array([float(x[0]) for x in (ray.d.x, ray.d.y, ray.d.z)])


# --------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------

def kind_of_seed(seed: int) -> str:
    """The case class seed ``seed`` draws when none is forced."""
    return KIND_CYCLE[seed % len(KIND_CYCLE)]


def random_scene(seed: int, kind: str | None = None) -> SceneSpec:
    """The scene of ``seed`` (module doc); ``kind`` forces a case class."""
    kind = kind_of_seed(seed) if kind is None else kind
    kinds = KINDS + FORCED_KINDS
    if kind not in kinds:
        raise ValueError(f"unknown scene kind {kind!r}: use one of {', '.join(kinds)}")
    rng = np.random.default_rng([13, seed, kinds.index(kind)])
    B = float(10 ** rng.uniform(-1, 2))
    res = tuple(int(x) for x in RESOLUTIONS[rng.integers(len(RESOLUTIONS))])
    eye, forward, up = _camera(rng, B)
    spec = SceneSpec(
        seed=seed, kind=kind, res=res, box_half=B, origin=eye.tolist(),
        target=(eye + forward * B).tolist(), up=up.tolist(),
        fov=float(rng.uniform(20, 100)),
        sigma_t=float(10 ** rng.uniform(-3, 1.5)) / B, albedo=float(rng.uniform(0.3, 1.0)),
        g=None if rng.random() < 0.5 else float(rng.uniform(-0.8, 0.8)),
        light=_random_light(rng, B))
    _KIND_BUILDERS[kind](spec, rng, eye, forward, up)
    return spec


def _random_case(spec, rng, eye, forward, up):
    keep = [spec.light["position"]] if "position" in spec.light else []
    spec.occluders = _occluders(rng, spec.box_half, int(rng.integers(0, 9)), eye, keep)


def _sun_axis(spec, rng, eye, forward, up):
    """Sun within 0.5° of the view axis, 8-14 occluders (class 1)."""
    toward = _rotate_towards(forward, math.radians(rng.uniform(0, 0.5)), rng)
    spec.light = {"type": "directional", "direction": (-toward).tolist(),
                  "irradiance": float(10 ** rng.uniform(-0.5, 0.5))}
    if rng.random() < 0.5:
        spec.res = (61, 17)
    spec.occluders = _occluders(rng, spec.box_half, int(rng.integers(8, 15)), eye, [])


def _light_at_eye(spec, rng, eye, forward, up):
    """A point or spot light within ~1e-3·B of the eye, in front or behind (class 2)."""
    B = spec.box_half
    sign = 1.0 if rng.random() < 0.5 else -1.0
    offset = sign * forward + 0.3 * _rotate_towards(forward, math.pi / 2, rng)
    pos = eye + float(10 ** rng.uniform(-3.5, -2.5)) * B * _unit(offset)
    intensity = float(10 ** rng.uniform(-2, 0)) * B * B
    if rng.random() < 0.5:
        spec.light = _point(pos, intensity)
    else:
        spec.light = _spot(rng, pos, pos + _rotate_towards(forward, rng.uniform(0, 0.5), rng),
                           float(rng.uniform(20, 70)))
        spec.light["intensity"] = intensity
    spec.occluders = _occluders(rng, B, int(rng.integers(2, 9)), eye, [pos])


def _light_on_pixel(spec, rng, eye, forward, up):
    """A point light on a pixel centre's ray, 1e-2 px off it (class 3)."""
    B = spec.box_half
    if spec.res[0] * spec.res[1] < 4:
        spec.res = (9, 7)
    W, H = spec.res
    i, j = int(rng.integers(W)), int(rng.integers(H))
    w = _pixel_ray_direction(spec, i, j)
    dist = float(rng.uniform(0.05, 0.5)) * B
    # 1e-2 of a pixel off the ray: on the ray itself the integral of 1/r²
    # diverges and float32 rounding alone decides the pixel's value
    pixel = 2.0 * math.tan(math.radians(spec.fov) / 2) / W
    pos = eye + dist * (w + 1e-2 * pixel * _unit(np.cross(w, _random_unit(rng))))
    spec.light = _point(pos, float(10 ** rng.uniform(0, 2)) * B * B)
    spec.occluders = _occluders(rng, B, int(rng.integers(0, 6)), eye, [pos])


def _light_near_face(spec, rng, eye, forward, up):
    """A point light 4e-4·B outside an occluder box's face (class 4)."""
    B = spec.box_half
    occ = _occluders(rng, B, int(rng.integers(3, 9)), eye, [])
    boxes = [o for o in occ if o["shape"] == "box"]
    if not boxes:
        occ.append({"shape": "box", "center": (eye + 0.3 * B * forward).tolist(),
                    "half_size": [0.05 * B] * 3, "axis": [0.0, 0.0, 1.0], "angle": 0.0,
                    "reflectance": 0.5})
        boxes = occ[-1:]
    box = boxes[int(rng.integers(len(boxes)))]
    face_axis = int(rng.integers(3))
    side = 1.0 if rng.random() < 0.5 else -1.0
    local = np.zeros(3)
    local[face_axis] = side * (box["half_size"][face_axis] + 4e-4 * B)
    other = [a for a in range(3) if a != face_axis]
    for a in other:
        local[a] = rng.uniform(-0.8, 0.8) * box["half_size"][a]
    pos = np.asarray(box["center"]) + _rotation(box["axis"], box["angle"]) @ local
    spec.light = _point(pos, float(10 ** rng.uniform(0, 2)) * B * B)
    spec.occluders = occ


def _rotation(axis, angle_deg: float) -> np.ndarray:
    """Rodrigues' rotation matrix (as ``ScalarTransform4f.rotate``)."""
    a = _unit(axis)
    t = math.radians(angle_deg)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * K + (1 - math.cos(t)) * (K @ K)


def _narrow_spot(spec, rng, eye, forward, up):
    """A narrow spot aimed across the edge of the view: a few pixels lit (class 5)."""
    B = spec.box_half
    half_fov = math.radians(spec.fov / 2)
    r, u, f = _basis(forward, up)
    edge = _unit(f + math.tan(half_fov) * (r if rng.random() < 0.5 else -r))
    target = eye + 0.5 * B * edge
    pos = target + 0.5 * B * _random_unit(rng)
    spec.light = _spot(rng, pos, target, float(rng.uniform(0.5, 3.0)))
    spec.light["intensity"] = float(10 ** rng.uniform(0, 2)) * B * B
    spec.occluders = _occluders(rng, B, int(rng.integers(0, 4)), eye, [pos])


def _grazing(spec, rng, eye, forward, up):
    """Light grazing the box's top face, the camera just under it looking away."""
    B = spec.box_half
    eye = np.array([0.0, 0.975 * B, 0.0]) + np.array([1, 0, 1]) * rng.uniform(-0.3, 0.3, 3) * B
    away = _unit([1.0, -rng.uniform(0.05, 0.3), rng.uniform(-0.3, 0.3)])
    spec.origin, spec.target, spec.up = eye.tolist(), (eye + B * away).tolist(), [0.0, 1.0, 0.0]
    elev = math.radians(rng.uniform(2, 10))
    spec.sigma_t = float(10 ** rng.uniform(-1, 1)) / B * 4
    if rng.random() < 0.5:
        spec.light = {"type": "directional",
                      "direction": [math.cos(elev), -math.sin(elev), 0.0], "irradiance": 2.0}
    else:
        dist = float(rng.uniform(1.25, 8)) * B
        pos = [-dist * math.cos(elev), B + dist * math.sin(elev), 0.0]
        spec.light = _point(pos, 600.0 * B * B)
    spec.occluders = _occluders(rng, B, int(rng.integers(0, 5)), eye, [])


def _thick(spec, rng, eye, forward, up):
    """σt·B in [3, 300]."""
    spec.sigma_t = float(10 ** rng.uniform(0.5, 2.5)) / spec.box_half
    _random_case(spec, rng, eye, forward, up)


def _enclosed(spec, rng, eye, forward, up):
    """A point light inside a closed box occluder: the reference is black."""
    B = spec.box_half
    centre = eye + 0.4 * B * _rotate_towards(forward, rng.uniform(0, 0.6), rng)
    half = 0.05 * B
    spec.light = _point(centre + rng.uniform(-0.5, 0.5, 3) * half,
                        float(10 ** rng.uniform(0, 2)) * B * B)
    spec.occluders = [{"shape": "box", "center": centre.tolist(), "half_size": [half] * 3,
                       "axis": _random_unit(rng).tolist(), "angle": float(rng.uniform(0, 90)),
                       "reflectance": 0.5}]


def _in_frustum(rng, eye, forward, up, fov_deg: float, dist: float, margin: float = 0.8):
    """A point at distance ``dist`` from the eye along a ray inside
    ``margin`` of the (square) field of view."""
    r, u, f = _basis(forward, up)
    t = math.tan(math.radians(fov_deg) / 2) * margin
    x, y = rng.uniform(-t, t, 2)
    return eye + dist * _unit(f + x * r + y * u)


def _shafts(spec, rng, eye, forward, up):
    """σt·B in [0.3, 30], 3-8 occluders in the frustum (for a point or spot
    light: between it and a point in view), shadows on screen."""
    B = spec.box_half
    spec.sigma_t = float(10 ** rng.uniform(math.log10(0.3), math.log10(30.0))) / B
    spec.fov = float(rng.uniform(35, 80))
    light_kind = rng.choice(["directional", "point", "spot"])
    pos = None
    if light_kind == "directional":
        toward = _rotate_towards(forward, math.radians(rng.uniform(20, 160)), rng)
        spec.light = {"type": "directional", "direction": (-toward).tolist(),
                      "irradiance": float(10 ** rng.uniform(-0.5, 0.5))}
    else:
        pos = np.clip(_in_frustum(rng, eye, forward, up, spec.fov,
                                  float(rng.uniform(0.4, 1.0)) * B, 0.6), -0.95 * B, 0.95 * B)
        intensity = float(10 ** rng.uniform(0, 2)) * B * B
        if light_kind == "point":
            spec.light = _point(pos, intensity)
        else:
            aim = _in_frustum(rng, eye, forward, up, spec.fov, float(rng.uniform(0.5, 1.5)) * B,
                              0.5)
            spec.light = _spot(rng, pos, aim, float(rng.uniform(30, 80)))
            spec.light["intensity"] = intensity
    n = int(rng.integers(3, 9))
    occ, tries = [], 0
    while len(occ) < n and tries < 200:
        tries += 1
        p = _in_frustum(rng, eye, forward, up, spec.fov, float(rng.uniform(0.2, 1.2)) * B)
        if pos is not None:
            p = pos + rng.uniform(0.2, 0.7) * (p - pos)
        c = np.clip(p, -0.95 * B, 0.95 * B)
        size = float(np.linalg.norm(c - eye) * 10 ** rng.uniform(-1.2, -0.6))
        if min(np.linalg.norm(c - np.asarray(q)) for q in [eye] + ([pos] if pos is not None
                                                                  else [])) < 2.0 * size:
            continue
        occ.append(_occluder_at(rng, c, size))
    spec.occluders = occ


_KIND_BUILDERS = {"random": _random_case, "sun_axis": _sun_axis, "light_at_eye": _light_at_eye,
                  "light_on_pixel": _light_on_pixel, "light_near_face": _light_near_face,
                  "narrow_spot": _narrow_spot, "grazing": _grazing, "thick": _thick,
                  "enclosed": _enclosed, "shafts": _shafts}


#: most lights of an extended scene
MAX_LIGHTS = 6


#: how often the extended generator draws each boundary, and the camera outside
BOUNDARY_ODDS = {"box": 0.5, "rotated_box": 0.25, "sphere": 0.25}
OUTSIDE_ODDS = 0.25


def extended_scene(spec: SceneSpec) -> SceneSpec:
    """The extended generator's scene of ``spec``, drawn from a generator
    of its own (the rest of the scene is ``spec``'s): 1-:data:`MAX_LIGHTS`
    lights of mixed kinds (``spec``'s own plus 0-5 random ones), the
    boundary a box, a rotated box or a sphere (:data:`BOUNDARY_ODDS`; each
    holds the cube [-B, B]³, so the occluders stay inside), and the camera
    outside it (:data:`OUTSIDE_ODDS`: moved back 3.5·B along its view, out
    of every boundary, still looking at the fog).  An ``enclosed`` scene is
    left as it is (its black reference measures leaks)."""
    if spec.kind == "enclosed":
        return spec
    rng = np.random.default_rng([35, spec.seed])
    more = [_random_light(rng, spec.box_half) for _ in range(int(rng.integers(0, MAX_LIGHTS)))]
    boundary = str(rng.choice(list(BOUNDARY_ODDS), p=list(BOUNDARY_ODDS.values())))
    rotation = (tuple(float(x) for x in _random_unit(rng)), float(rng.uniform(10, 80)))
    outside = bool(rng.random() < OUTSIDE_ODDS)
    out = replace(spec, more_lights=more, boundary=boundary, boundary_rotation=rotation,
                  camera_outside=outside)
    if outside:
        eye, target = np.asarray(spec.origin), np.asarray(spec.target)
        back = _unit(target - eye) * 3.5 * spec.box_half
        out = replace(out, origin=(eye - back).tolist(), target=(target - back).tolist())
    return out


def scene_set(n: int, first_seed: int = 0, extended: bool = False) -> list[SceneSpec]:
    """Scenes of seeds ``first_seed .. first_seed + n - 1`` (``extended``:
    through :func:`extended_scene`)."""
    specs = [random_scene(s) for s in range(first_seed, first_seed + n)]
    return [extended_scene(x) for x in specs] if extended else specs
