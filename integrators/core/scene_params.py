"""Reading and validating a Mitsuba scene (DESIGN §3 ``SceneParams``).

This is the only module that queries Mitsuba scene objects for their
parameters.  :func:`SceneParams.from_scene` returns frozen dataclasses for the
camera, the homogeneous medium attached to the sensor (with its box boundary)
and the lights (one or several directional, point and spot emitters), or raises :class:`ValueError` naming the offending object
and what to change.  Nothing unsupported renders silently wrong.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace

import mitsuba as mi
import numpy as np

from rectify._dr import host_array
from rectify.camera import CameraParams


SUPPORTED_PHASES = {
    "IsotropicPhaseFunction": "isotropic",
    "HGPhaseFunction": "hg",
    "RayleighPhaseFunction": "rayleigh",
    "BlendPhaseFunction": "blendphase",
}
SUPPORTED_EMITTERS = {
    "DirectionalEmitter": "directional",
    "PointLight": "point",
    "SpotLight": "spot",
}


def _name(obj) -> str:
    """A user-facing name for a Mitsuba object: its id and plugin class."""
    ident = obj.id() if hasattr(obj, "id") else ""
    cls = obj.class_name() if hasattr(obj, "class_name") else type(obj).__name__
    return f"{cls} '{ident}'" if ident else cls


def _vec(value, n=3) -> np.ndarray:
    """Mitsuba scalar/colour/point parameter -> float64 numpy array of length
    n (read component by component: no kernel, :func:`~rectify._dr.host_array`)."""
    arr = host_array(value)
    if arr.size == 1:
        arr = np.repeat(arr, n)
    return arr[:n]


def _param(obj, *keys):
    """First of ``keys`` present in ``mi.traverse(obj)``."""
    params = mi.traverse(obj)
    for k in keys:
        if k in params:
            return params[k]
    raise ValueError(f"{_name(obj)}: cannot read any of {keys}; "
                     "episcatter needs constant (non-textured) values here.")


def _check_finite_nonneg(what: str, values: np.ndarray, fix: str) -> None:
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{what} is not finite ({values.tolist()}): {fix}")
    if np.any(values < 0):
        raise ValueError(f"{what} is negative ({values.tolist()}): {fix}")


@dataclass(frozen=True, eq=False)
class MediumParams:
    """Homogeneous medium (DESIGN §1): σt, σs = albedo·σt per unit length (RGB),
    the phase function and the convex shape that bounds the medium.

    ``bounds_min``/``bounds_max``: the boundary's axis-aligned bounding box
    (the boundary itself when ``to_local`` is None).  ``to_local`` (3×4,
    ``u = A x + b``): the affine map taking the boundary to the cube
    ``[-1, 1]³`` (``boundary = "box"``: a rotated, scaled or sheared cube)
    or to the unit sphere (``boundary = "sphere"``); ``planes``: the face
    planes of a closed convex mesh (``boundary = "convex"``).  Rays are
    clipped to it by
    :func:`~integrators.core.light_transport.medium_interval`."""
    sigma_t: np.ndarray
    albedo: np.ndarray
    phase_kind: str
    bounds_min: np.ndarray
    bounds_max: np.ndarray
    phase: object = field(repr=False, default=None)
    medium: object = field(repr=False, default=None)
    boundary: str = "box"
    to_local: np.ndarray | None = None
    #: ``boundary = "convex"``: the closed convex mesh's face planes (k×4,
    #: outward unit normal n and offset c: inside where n·x <= c)
    planes: np.ndarray | None = None
    #: the phase function's class and parameter values, read on the host:
    #: two frames with equal ones have the same phase function (tables of
    #: it may be kept from one frame to the next)
    phase_signature: tuple = ()

    @property
    def sigma_s(self) -> np.ndarray:
        return self.albedo * self.sigma_t

    @property
    def axis_aligned(self) -> bool:
        """Whether the boundary is an axis-aligned box (its bounds)."""
        return self.to_local is None and self.planes is None

    def contains(self, p, rel_eps=1e-6) -> bool:
        p = np.asarray(p, dtype=np.float64)
        if self.planes is not None:
            ext = float(np.max(self.bounds_max - self.bounds_min))
            return bool(np.all(self.planes[:, :3] @ p <= self.planes[:, 3] + rel_eps * ext))
        if self.to_local is not None:
            u = self.to_local[:, :3] @ p + self.to_local[:, 3]
            if self.boundary == "sphere":
                return bool(np.linalg.norm(u) < 1 + rel_eps)
            return bool(np.all(np.abs(u) < 1 + rel_eps))
        ext = float(np.max(self.bounds_max - self.bounds_min))
        eps = rel_eps * ext
        return bool(np.all(p > self.bounds_min - eps) and np.all(p < self.bounds_max + eps))


@dataclass(frozen=True, eq=False)
class LightParams:
    """One emitter of the scene.  ``direction`` (directional lights) points
    from the scene *toward* the light; ``position`` is set for point/spot."""
    kind: str                       # 'directional' | 'point' | 'spot'
    radiance: np.ndarray            # irradiance (directional) or intensity (RGB)
    direction: np.ndarray | None = None
    position: np.ndarray | None = None
    spot_axis: np.ndarray | None = None
    cutoff_angle: float = 0.0       # degrees (spot)
    beam_width: float = 0.0         # degrees (spot)
    textured: bool = False
    emitter: object = field(repr=False, default=None)


@dataclass(frozen=True, eq=False)
class SceneParams:
    """The camera, the medium and the lights of one render.

    Single scattering and direct surface lighting are linear in the light:
    a scene with several emitters renders as the sum over its lights, each
    with its own epipolar geometry, on one shared camera capture.  The
    methods see one light at a time (:meth:`per_light`); :attr:`light` is
    that light, and asking a several-light ``SceneParams`` for it is an
    error (a stage that forgot the sum would otherwise render one light)."""
    camera: CameraParams
    medium: MediumParams
    lights: tuple
    scene: object = field(repr=False, default=None)
    sensor: object = field(repr=False, default=None)
    #: the camera sits outside the medium (the sensor has no medium): each
    #: view ray's integral starts where it enters the medium
    #: (``CameraCapture.t_in``)
    camera_outside: bool = False

    @property
    def light(self) -> LightParams:
        """The light of a one-light ``SceneParams`` (see :meth:`per_light`)."""
        if len(self.lights) != 1:
            raise RuntimeError(
                f"SceneParams has {len(self.lights)} lights: a per-light stage must be called "
                "on each of params.per_light() and its results summed.")
        return self.lights[0]

    def per_light(self) -> tuple["SceneParams", ...]:
        """One ``SceneParams`` per light (``self`` for a one-light scene),
        sharing the camera, the medium and the caches that do not depend on
        the light."""
        if len(self.lights) == 1:
            return (self,)
        cache = self.__dict__.setdefault("_near_boundary", {})
        out = []
        for light in self.lights:
            one = replace(self, lights=(light,))
            one.__dict__["_near_boundary"] = cache
            out.append(one)
        return tuple(out)

    @property
    def scene_extent(self) -> float:
        """Diagonal of the medium box: the length scale for relative epsilons."""
        return float(np.linalg.norm(self.medium.bounds_max - self.medium.bounds_min))

    def surfaces_near_boundary(self, margin: float):
        """(lo, hi): the bounding box of every non-null surface whose bounding
        box comes within ``margin`` of the medium box's boundary (inside or
        outside it), or None if none does; computed once per ``margin``.

        Shadow rays are traced in pieces that stop short of the box
        (:func:`~integrators.core.light_transport.box_segments`): only such a
        surface can hide in the gaps around a box crossing."""
        cache = self.__dict__.setdefault("_near_boundary", {})
        if margin not in cache:
            lo = self.medium.bounds_min - margin
            hi = self.medium.bounds_max + margin
            ilo = self.medium.bounds_min + margin
            ihi = self.medium.bounds_max - margin
            near = []
            for shape in self.scene.shapes() if self.scene is not None else []:
                bsdf = shape.bsdf()
                if bsdf is not None and mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null):
                    continue
                box = shape.bbox()
                smin, smax = _vec(box.min), _vec(box.max)
                touches = np.all(smax >= lo) and np.all(smin <= hi)
                # well inside an axis-aligned boundary; any other boundary
                # crosses its bounding box's inside, so nothing is
                inside = (self.medium.axis_aligned and np.all(smin > ilo)
                          and np.all(smax < ihi))
                if touches and not inside:
                    near.append((smin, smax))
            cache[margin] = None if not near else (
                np.min([a for a, _ in near], axis=0) - margin,
                np.max([b for _, b in near], axis=0) + margin)
        return cache[margin]

    @staticmethod
    def from_scene(scene, sensor=None) -> "SceneParams":
        if sensor is None or isinstance(sensor, int):
            sensors = scene.sensors()
            if not sensors:
                raise ValueError("The scene has no sensor: add a <sensor type=\"perspective\">.")
            sensor = sensors[sensor or 0]
        camera = read_camera(sensor)
        medium = read_medium(scene, sensor)
        inside = medium.contains(camera.origin)
        if sensor.get_medium() is not None and not inside:
            raise ValueError(
                f"The camera at {camera.origin.tolist()} lies outside the boundary of the "
                f"medium (bounding box [{medium.bounds_min.tolist()}, "
                f"{medium.bounds_max.tolist()}]) although the medium is attached to the "
                "sensor: enlarge the boundary so it encloses the camera, or -- to look at the "
                "fog from outside -- remove the medium <ref> from the <sensor>.")
        if sensor.get_medium() is None and inside:
            raise ValueError(
                f"The camera at {camera.origin.tolist()} lies inside the boundary of medium "
                f"{_name(medium.medium)} but the sensor has no medium (volpath would see no "
                "fog at all): put <ref id=\"...\"/> of that medium inside the <sensor>.")
        lights = read_lights(scene)
        return SceneParams(camera=camera, medium=medium, lights=lights,
                           scene=scene, sensor=sensor, camera_outside=not inside)


# ---------------------------------------------------------------------------
def read_camera(sensor) -> CameraParams:
    if sensor.class_name() != "PerspectiveCamera":
        raise ValueError(
            f"Sensor {_name(sensor)} is not supported: episcatter renders with a "
            "pinhole <sensor type=\"perspective\"> only (no thin lens, orthographic "
            "or other sensors).")
    film = sensor.film()
    size, crop_size = np.array(film.size()), np.array(film.crop_size())
    if np.any(size != crop_size) or np.any(np.array(film.crop_offset()) != 0):
        raise ValueError(f"Film {_name(film)} has a crop window: render the full "
                         "film (remove crop_width/crop_height/crop_offset_*).")
    if film.rfilter().class_name() != "BoxFilter":
        warnings.warn(
            f"Film {_name(film)} uses a {film.rfilter().class_name()}: episcatter "
            "integrators always use a box pixel filter; add <rfilter type=\"box\"/> "
            "so volpath references match.", stacklevel=3)
    cam = CameraParams.from_mitsuba(sensor)
    for v in (cam.origin, cam.forward, cam.x_axis, cam.y_axis):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"Sensor {_name(sensor)} has a non-finite transform or fov.")
    return cam


def scene_medium(scene, sensor):
    """The medium to render: the sensor's (the camera inside it), else the
    one medium that null-BSDF shapes of the scene bound as their
    ``interior`` (the camera outside it), or a ValueError naming what to
    change."""
    med = sensor.get_medium()
    if med is not None:
        return med
    media = {}
    for shape in scene.shapes():
        inner = shape.interior_medium()
        if inner is not None:
            media.setdefault(inner.ptr, inner)
    if not media:
        raise ValueError(
            f"Sensor {_name(sensor)} has no medium and no shape bounds one: episcatter "
            "renders single scattering in a homogeneous medium. Bound it with a null-BSDF "
            "<shape type=\"cube\"> whose interior is that medium (<ref name=\"interior\" "
            "id=\"your_medium\"/>), and put <ref id=\"your_medium\"/> inside the <sensor> "
            "if the camera sits in it.")
    if len(media) > 1:
        names = ", ".join(_name(m) for m in media.values())
        raise ValueError(f"The scene bounds {len(media)} media ({names}): episcatter renders "
                         "one homogeneous medium; merge them into one.")
    return next(iter(media.values()))


def read_medium(scene, sensor) -> MediumParams:
    med = scene_medium(scene, sensor)
    if med.class_name() != "HomogeneousMedium" or not med.is_homogeneous():
        raise ValueError(
            f"Medium {_name(med)} is not supported: only <medium "
            "type=\"homogeneous\"> (constant sigma_t and albedo) can be rendered.")
    scale = float(_param(med, "scale"))
    sigma_t = _vec(_param(med, "sigma_t.value.value", "sigma_t.value")) * scale
    albedo = _vec(_param(med, "albedo.value.value", "albedo.value"))
    _check_finite_nonneg(f"Medium {_name(med)}: sigma_t*scale", sigma_t,
                         "set sigma_t and scale to finite values >= 0.")
    _check_finite_nonneg(f"Medium {_name(med)}: albedo", albedo,
                         "set albedo to a value in [0, 1].")
    if np.any(albedo > 1):
        raise ValueError(f"Medium {_name(med)}: albedo {albedo.tolist()} exceeds 1: "
                         "set albedo to a value in [0, 1].")
    phase = med.phase_function()
    kind, signature = _check_phase(phase, med)
    bmin, bmax, boundary, to_local, planes = _read_boundary(scene, med)
    return MediumParams(sigma_t=sigma_t, albedo=albedo, phase_kind=kind,
                        bounds_min=bmin, bounds_max=bmax, phase=phase, medium=med,
                        boundary=boundary, to_local=to_local, planes=planes,
                        phase_signature=signature)


def _check_phase(phase, med) -> tuple[str, tuple]:
    """(kind, signature) of a supported phase function (``signature``: its
    class and every parameter's values, :attr:`MediumParams.phase_signature`);
    a ValueError naming what to change otherwise."""
    cls = phase.class_name()
    if cls not in SUPPORTED_PHASES:
        raise ValueError(
            f"Medium {_name(med)} uses phase function {cls}, which is not "
            f"supported: use one of {sorted(SUPPORTED_PHASES.values())}.")
    params = mi.traverse(phase)
    signature = [cls]
    for key in params.keys():
        val = host_array(params[key])
        signature.append((key, tuple(np.asarray(val, np.float64).ravel().tolist())))
        if key.endswith(".g") or key == "g":
            if not np.all(np.isfinite(val)) or np.any(np.abs(val) >= 1):
                raise ValueError(f"Medium {_name(med)}: HG asymmetry g = {val.tolist()} "
                                 "must be finite and inside (-1, 1).")
        if "weight" in key and (not np.all(np.isfinite(val)) or np.any(val < 0) or np.any(val > 1)):
            raise ValueError(f"Medium {_name(med)}: blendphase weight {val.tolist()} "
                             "must be in [0, 1].")
    return SUPPORTED_PHASES[cls], tuple(signature)


def _same(a, b) -> bool:
    return a is not None and b is not None and a.ptr == b.ptr


def _read_boundary(scene, med):
    """(bounds_min, bounds_max, boundary, to_local) of the one null-BSDF
    shape whose interior is ``med`` (see :class:`MediumParams`): a ``cube``
    (or a mesh whose vertices are the corners of a box) with any
    ``to_world`` -- axis-aligned (``to_local`` None) or rotated, scaled,
    sheared -- or a ``sphere``."""
    boundary = [s for s in scene.shapes() if _same(s.interior_medium(), med)]
    fix = ("bound the medium with exactly one <shape type=\"cube\"> (any to_world: "
           "translated, scaled, rotated), <shape type=\"sphere\"> or closed convex mesh "
           f"(at most {MAX_PLANES} face planes) with <bsdf type=\"null\"/> and "
           "<ref name=\"interior\" id=\"...\"/>.")
    if not boundary:
        raise ValueError(f"Medium {_name(med)} has no boundary shape: {fix}")
    if len(boundary) > 1:
        names = ", ".join(_name(s) for s in boundary)
        raise ValueError(f"Medium {_name(med)} has {len(boundary)} boundary shapes ({names}): {fix}")
    shape = boundary[0]
    bsdf = shape.bsdf()
    if bsdf is None or not mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null) or \
            bsdf.class_name() not in ("Null", "NullBSDF"):
        raise ValueError(f"Boundary {_name(shape)} of medium {_name(med)} must have "
                         f"<bsdf type=\"null\"/>: {fix}")
    bbox = shape.bbox()
    bmin, bmax = _vec(bbox.min), _vec(bbox.max)
    if not (np.all(np.isfinite(bmin)) and np.all(np.isfinite(bmax)) and np.all(bmax > bmin)):
        raise ValueError(f"Boundary {_name(shape)} has a degenerate bounding box: {fix}")
    if shape.class_name() == "Sphere":
        to_world = host_array(mi.traverse(shape)["to_world"].matrix).reshape(4, 4)
        inverse = np.linalg.inv(to_world)
        return bmin, bmax, "sphere", inverse[:3, :].copy(), None
    if not shape.is_mesh():
        raise ValueError(f"Boundary {_name(shape)} of medium {_name(med)} is a "
                         f"{shape.class_name()}, not a box, a sphere or a closed convex "
                         f"mesh: {fix}")
    params = mi.traverse(shape)
    pos = np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)
    tol = 1e-4 * float(np.max(bmax - bmin))
    if np.all(np.all((np.abs(pos - bmin) < tol) | (np.abs(pos - bmax) < tol), axis=1)):
        return bmin, bmax, "box", None, None
    to_local = _box_frame(pos, tol)
    if to_local is not None:
        return bmin, bmax, "box", to_local, None
    faces = np.array(params["faces"], dtype=np.int64).reshape(-1, 3)
    planes, why = convex_planes(pos, faces, tol)
    if planes is None:
        raise ValueError(f"Boundary {_name(shape)} of medium {_name(med)} is a mesh that "
                         f"{why}: {fix}")
    return bmin, bmax, "convex", None, planes


#: most distinct face planes of a convex mesh boundary (each is a term of
#: every ray-boundary test)
MAX_PLANES = 32


def convex_planes(pos: np.ndarray, faces: np.ndarray, tol: float):
    """(planes, None) of a closed, consistently and outward wound, convex
    triangle mesh -- its distinct face planes (k×4: outward unit normal,
    offset), at most :data:`MAX_PLANES` -- or (None, why not)."""
    # vertices may be split (per-face normals, uv seams): weld them first
    weld = {}
    keys = np.round(pos / max(tol, 1e-12)).astype(np.int64)
    ids = np.array([weld.setdefault(tuple(k), len(weld)) for k in keys])
    directed = {}
    for f in ids[faces]:
        for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            if e[0] != e[1]:
                directed[e] = directed.get(e, 0) + 1
    if not directed or any(n != 1 or directed.get((b, a)) != 1 for (a, b), n in directed.items()):
        return None, ("is not closed, or its faces are not wound consistently (every edge "
                      "must join two faces that run it in opposite directions)")
    tri = pos[faces]
    volume = float(np.sum(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])))) / 6
    if volume < 0:
        return None, ("has faces whose normals point inward (Mitsuba takes the side a face's "
                      "normal points to as outside the medium): flip the faces' winding so "
                      "the normals point out of the fog")
    planes = []
    for t in tri:
        n = np.cross(t[1] - t[0], t[2] - t[0])
        norm = np.linalg.norm(n)
        if norm < tol * tol:
            continue
        n = n / norm
        c = float(n @ t[0])
        if not any(np.linalg.norm(n - q[:3]) < 1e-6 and abs(c - q[3]) < tol for q in planes):
            planes.append(np.array([*n, c]))
    planes = np.array(planes)
    if np.any(pos @ planes[:, :3].T > planes[:, 3] + tol):
        return None, "is not convex (a closed non-convex mesh is not supported)"
    if len(planes) > MAX_PLANES:
        return None, (f"has {len(planes)} distinct face planes (at most {MAX_PLANES}: use "
                      "<shape type=\"sphere\"> for a round fog volume)")
    return planes, None


def _box_frame(pos: np.ndarray, tol: float) -> np.ndarray | None:
    """The map ``u = A x + b`` taking a box's corners ``pos`` (vertices,
    repeated) to the cube ``[-1, 1]³``, or None if the vertices are not the
    8 corners of a parallelepiped."""
    corners = []
    for p in pos:
        if all(np.linalg.norm(p - q) > tol for q in corners):
            corners.append(p)
        if len(corners) > 8:
            return None
    if len(corners) != 8:
        return None
    corners = np.array(corners)
    v0, others = corners[0], corners[1:]
    for i in range(7):
        for j in range(i + 1, 7):
            for k in range(j + 1, 7):
                E = np.stack([others[i] - v0, others[j] - v0, others[k] - v0], axis=1)
                if abs(np.linalg.det(E)) < tol ** 3:
                    continue
                combos = np.array([v0 + E @ np.array([a, b, c]) for a in (0, 1)
                                   for b in (0, 1) for c in (0, 1)])
                if all(np.min(np.linalg.norm(combos - q, axis=1)) < tol for q in corners):
                    A = 2.0 * np.linalg.inv(E)
                    centre = v0 + E @ np.full(3, 0.5)
                    return np.concatenate([A, (-A @ centre)[:, None]], axis=1)
    return None


#: what a scene's emitters must be, in every refusal
LIGHTS_FIX = ("use <emitter> elements of type directional, point or spot (one or several); "
              "area lights, environment maps and constant backgrounds produce no shafts in "
              "this model -- render those scenes with Mitsuba's volpath.")


def read_lights(scene) -> tuple[LightParams, ...]:
    """Every emitter of the scene, each a supported kind, or a ValueError
    naming the ones that are not (and the scene without any)."""
    emitters = list(scene.emitters())
    if scene.environment() is not None and all(e is not scene.environment() for e in emitters):
        emitters.append(scene.environment())
    if not emitters:
        raise ValueError(f"The scene has no emitter: {LIGHTS_FIX}")
    bad = [e for e in emitters if e.class_name() not in SUPPORTED_EMITTERS]
    if bad:
        names = ", ".join(_name(e) for e in bad)
        raise ValueError(f"The scene's emitter{'s' if len(bad) > 1 else ''} {names} "
                         f"{'are' if len(bad) > 1 else 'is'} not supported: {LIGHTS_FIX}")
    return tuple(read_light(e) for e in emitters)


def read_light(em) -> LightParams:
    """One supported emitter's parameters (validated)."""
    kind = SUPPORTED_EMITTERS[em.class_name()]
    params = mi.traverse(em)
    if kind == "directional":
        radiance = _vec(params["irradiance.value"])
        to_world = host_array(params["to_world"].matrix).reshape(4, 4)
        d = to_world[:3, :3] @ np.array([0.0, 0.0, 1.0])   # propagation direction
        n = np.linalg.norm(d)
        if not np.isfinite(n) or n == 0:
            raise ValueError(f"Emitter {_name(em)}: direction is zero or not finite.")
        light = LightParams(kind=kind, radiance=radiance, direction=-d / n, emitter=em)
    elif kind == "point":
        radiance = _vec(params["intensity.value"])
        light = LightParams(kind=kind, radiance=radiance,
                            position=_vec(params["position"]), emitter=em)
    else:
        radiance = _vec(params["intensity.value"])
        to_world = host_array(params["to_world"].matrix).reshape(4, 4)
        axis = to_world[:3, :3] @ np.array([0.0, 0.0, 1.0])
        cutoff = float(host_array(params["cutoff_angle"])[0])
        beam = float(host_array(params["beam_width"])[0])
        if not (np.isfinite(cutoff) and 0 < cutoff <= 90):
            raise ValueError(f"Emitter {_name(em)}: cutoff_angle {cutoff} must be in (0, 90] degrees.")
        # Mitsuba lists a uniform ``texture.value`` for a spot light without
        # a texture; only other ``texture.*`` parameters mean a projected one
        textured = any(k.startswith("texture.") and k != "texture.value" for k in params.keys())
        light = LightParams(kind=kind, radiance=radiance, position=to_world[:3, 3].copy(),
                            spot_axis=axis / np.linalg.norm(axis), cutoff_angle=cutoff,
                            beam_width=beam, textured=textured, emitter=em)
    label = "irradiance" if kind == "directional" else "intensity"
    _check_finite_nonneg(f"Emitter {_name(em)}: {label}", light.radiance,
                         f"set {label} to finite values >= 0.")
    if light.position is not None and not np.all(np.isfinite(light.position)):
        raise ValueError(f"Emitter {_name(em)}: position is not finite.")
    if not math.isfinite(float(np.sum(light.radiance))):
        raise ValueError(f"Emitter {_name(em)}: radiance is not finite.")
    return light
