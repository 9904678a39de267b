"""Moving objects of an animation: per-frame geometry of named shapes,
applied through ``mi.traverse`` (Lin et al. animate objects under a fixed
camera and light).

A :class:`Motion` maps the animation phase ``f ∈ [0, 1]`` (frame k of N:
``f = k / (N - 1)``) to a rigid 4×4 transform of the shape's rest pose, or
(:class:`Deform`) to new vertex positions.  :class:`ShapeAnimator` applies
the motions of every moving shape for a frame:

* meshes (``<shape type="ply|obj|cube|...">`` with ``vertex_positions``):
  rigid motions and deformations of the vertex positions (Mitsuba
  recomputes the vertex normals);
* other shapes with a ``to_world`` (``sphere``, ...): rigid motions only.

Motion strings (CLI ``--move SHAPE_ID:SPEC``):

===================================  ======================================
``translate=x,y,z``                  moves by ``f·(x, y, z)``
``rotate=ax,ay,az,deg[,px,py,pz]``   turns by ``f·deg`` about the axis
                                     through the pivot (default: the rest
                                     bounding-box centre)
``swing=ax,ay,az,deg[,px,py,pz]``    pendulum: ``deg·sin(2πf)``
``path=FILE``                        row k of FILE (whitespace or commas):
                                     3 numbers (translation) or 12/16
                                     (row-major 3×4 / 4×4 matrix)
``wave=dx,dy,dz,wavelength``         deforms a mesh: each vertex moves by
                                     ``(dx,dy,dz)·sin(2π(r/wavelength − f))``,
                                     r = distance to the rest centre
===================================  ======================================
"""
from __future__ import annotations

from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np


def rotation(axis, degrees, pivot) -> np.ndarray:
    """4×4 rotation by ``degrees`` about the line through ``pivot`` along ``axis``."""
    axis = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(axis)
    if not np.isfinite(n) or n == 0:
        raise ValueError(f"Rotation axis {axis.tolist()} is zero or not finite: give a direction.")
    k = axis / n
    a = np.radians(degrees)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = np.asarray(pivot, dtype=np.float64) - R @ np.asarray(pivot, dtype=np.float64)
    return M


@dataclass(frozen=True)
class Motion:
    """A rigid motion of shape ``shape_id``: ``kind`` in translate, rotate,
    swing, path; ``values`` its numbers (path: one row per frame)."""
    shape_id: str
    kind: str
    values: np.ndarray = field(repr=False)

    def matrix(self, f: float, frame: int, centre) -> np.ndarray:
        v = self.values
        if self.kind == "translate":
            M = np.eye(4)
            M[:3, 3] = f * v
            return M
        if self.kind in ("rotate", "swing"):
            pivot = v[4:7] if len(v) == 7 else centre
            deg = f * v[3] if self.kind == "rotate" else v[3] * np.sin(2 * np.pi * f)
            return rotation(v[:3], deg, pivot)
        if frame >= len(v):
            raise ValueError(f"Motion path of '{self.shape_id}' has {len(v)} rows but frame "
                             f"{frame} was asked for: add rows or render fewer frames.")
        row = v[frame]
        M = np.eye(4)
        if row.size == 3:
            M[:3, 3] = row
        else:
            M[: row.size // 4] = row.reshape(-1, 4)
        return M


@dataclass(frozen=True)
class Deform:
    """A deformation of mesh ``shape_id``: ``fn(rest_vertices (n, 3), f) ->
    vertices``."""
    shape_id: str
    fn: object = field(repr=False)


def wave(displacement, wavelength, centre):
    """The ``wave=`` deformation (module doc) about ``centre``."""
    disp = np.asarray(displacement, dtype=np.float64)
    centre = np.asarray(centre, dtype=np.float64)

    def fn(v, f):
        r = np.linalg.norm(v - centre, axis=1)
        return v + disp[None] * np.sin(2 * np.pi * (r / wavelength - f))[:, None]
    return fn


_COUNTS = {"translate": (3,), "rotate": (4, 7), "swing": (4, 7), "wave": (4,)}


def parse_motion(text: str):
    """``SHAPE_ID:kind=values`` -> :class:`Motion`, or ``("wave", id,
    values)`` for a deformation (built once the rest pose is known)."""
    fix = ("write SHAPE_ID:translate=x,y,z, SHAPE_ID:rotate=ax,ay,az,deg[,px,py,pz], "
           "SHAPE_ID:swing=..., SHAPE_ID:path=FILE or SHAPE_ID:wave=dx,dy,dz,wavelength")
    if ":" not in text or "=" not in text.split(":", 1)[1]:
        raise ValueError(f"Motion '{text}' is not of the form SHAPE_ID:kind=values: {fix}.")
    shape_id, spec = text.split(":", 1)
    kind, value = spec.split("=", 1)
    if kind == "path":
        try:
            rows = np.loadtxt(value, delimiter=None if "," not in open(value).read() else ",",
                              ndmin=2)
        except OSError as err:
            raise ValueError(f"Motion path file '{value}' cannot be read ({err}).") from err
        if rows.shape[1] not in (3, 12, 16):
            raise ValueError(f"Motion path file '{value}' has {rows.shape[1]} numbers per row: "
                             "give 3 (translation), 12 or 16 (row-major matrix).")
        return Motion(shape_id, kind, rows)
    if kind not in _COUNTS:
        raise ValueError(f"Motion kind '{kind}' of '{text}' is unknown: {fix}.")
    try:
        values = np.array([float(x) for x in value.split(",")])
    except ValueError as err:
        raise ValueError(f"Motion '{text}': '{value}' is not a list of numbers: {fix}.") from err
    if len(values) not in _COUNTS[kind] or not np.all(np.isfinite(values)):
        raise ValueError(f"Motion '{text}' needs {' or '.join(map(str, _COUNTS[kind]))} finite "
                         f"numbers, got {len(values)}: {fix}.")
    if kind == "wave":
        if values[3] <= 0:
            raise ValueError(f"Motion '{text}': the wavelength must be positive.")
        return ("wave", shape_id, values)
    return Motion(shape_id, kind, values)


class ShapeAnimator:
    """Applies the motions of the moving shapes of ``scene`` for a frame;
    remembers each shape's rest pose (its geometry when constructed)."""

    def __init__(self, scene, motions):
        self.params = mi.traverse(scene)
        shapes = {s.id(): s for s in scene.shapes()}
        self.motions: dict[str, list] = {}
        self.rest: dict[str, np.ndarray] = {}
        self.centre: dict[str, np.ndarray] = {}
        self.shapes = {}
        for m in motions:
            sid = m[1] if isinstance(m, tuple) else m.shape_id
            if sid not in shapes:
                raise ValueError(f"Moving shape '{sid}' is not in the scene (shapes with ids: "
                                 f"{sorted(k for k in shapes if k)}): give the shape an id, and load the "
                                 "scene with mi.load_file(..., optimize=False) (Mitsuba merges "
                                 "meshes with identical BSDFs).")
            if sid not in self.rest:
                self._remember(sid, shapes[sid])
            if isinstance(m, tuple):
                m = Deform(sid, wave(m[2][:3], m[2][3], self.centre[sid]))
            if isinstance(m, Deform) and not self._is_mesh(sid):
                raise ValueError(f"Shape '{sid}' is not a mesh: only meshes deform; "
                                 "use a rigid motion (translate, rotate, swing, path).")
            self.motions.setdefault(sid, []).append(m)

    def _is_mesh(self, sid) -> bool:
        return f"{sid}.vertex_positions" in self.params

    def _remember(self, sid, shape):
        self.shapes[sid] = shape
        bb = shape.bbox()
        self.centre[sid] = 0.5 * (np.array(bb.min, dtype=np.float64) + np.array(bb.max, dtype=np.float64))
        if self._is_mesh(sid):
            self.rest[sid] = np.array(self.params[f"{sid}.vertex_positions"], dtype=np.float64).reshape(-1, 3)
        elif f"{sid}.to_world" in self.params:
            self.rest[sid] = np.array(self.params[f"{sid}.to_world"].matrix, dtype=np.float64).reshape(4, 4)
        else:
            raise ValueError(f"Shape '{sid}' has neither vertex positions nor a to_world "
                             "transform Mitsuba lets us change: use a mesh.")

    @property
    def moving_shapes(self):
        return [self.shapes[s] for s in self.motions]

    def apply(self, frame: int, frames: int) -> None:
        """Set every moving shape to its pose at ``frame`` of ``frames``."""
        f = frame / (frames - 1) if frames > 1 else 0.0
        for sid, motions in self.motions.items():
            M = np.eye(4)
            v = self.rest[sid]
            for m in motions:
                if isinstance(m, Deform):
                    v = m.fn(v, f)
                else:
                    M = m.matrix(f, frame, self.centre[sid]) @ M
            if self._is_mesh(sid):
                out = v @ M[:3, :3].T + M[:3, 3]
                self.params[f"{sid}.vertex_positions"] = mi.Float(out.astype(np.float32).ravel())
            else:
                self.params[f"{sid}.to_world"] = mi.ScalarTransform4f((M @ v).tolist())
        self.params.update()
