"""A small builder for Mitsuba 3 scene XML that follows the suite's conventions.

Every scene of the suite has the same skeleton (see the docstring of
:mod:`scenes`): ``-D``-overridable defaults for the film
size, the sample count and the medium; a ``volpath`` integrator with
``max_depth=2``; one perspective sensor inside a homogeneous medium; one
axis-aligned null-BSDF ``cube`` (id ``medium_box``) bounding that medium; one
emitter (several in :mod:`scenes.several_lights`: ids ``light``, ``light_2``,
...); and diffuse shapes.  :class:`SceneXML` writes exactly that, with
numbers formatted deterministically so that regenerating a scene yields the
same bytes.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Sequence

import numpy as np

Vec = Sequence[float]


def fmt(x: float) -> str:
    """A float as short, deterministic text (6 significant digits, no ``-0``)."""
    s = f"{float(x):.6g}"
    return "0" if s in ("-0", "0") else s


def fmt_vec(v: Vec) -> str:
    """A vector as ``"x, y, z"``."""
    return ", ".join(fmt(c) for c in v)


@dataclass(frozen=True)
class Phase:
    """A phase function: ``kind`` is ``hg``, ``isotropic`` or ``rayleigh``;
    ``g`` is the default asymmetry written as ``<default name="g">`` (hg only)."""
    kind: str = "hg"
    g: float = 0.3


@dataclass(frozen=True)
class Medium:
    """Defaults of the homogeneous medium (``sigma_t`` per meter)."""
    sigma_t: float
    albedo: float = 0.9
    phase: Phase = Phase()


class SceneXML:
    """Builds one scene document.

    Call :meth:`medium`, :meth:`camera`, :meth:`medium_box`, one or more
    emitter methods and any number of shape methods, then :meth:`to_string`.  Element
    order in the output is fixed: defaults, integrator, medium, sensor, BSDFs,
    emitters, shapes.
    """

    def __init__(self, comment: str = ""):
        self.comment = comment
        self._defaults: list[tuple[str, str]] = [
            ("res_x", "320"), ("res_y", "240"), ("spp", "64")]
        self._medium: ET.Element | None = None
        self._sensor: ET.Element | None = None
        self._bsdfs: dict[str, ET.Element] = {}
        self._emitters: list[ET.Element] = []
        self._shapes: list[ET.Element] = []
        self._ids: set[str] = set()

    # -- skeleton ---------------------------------------------------------
    def medium(self, m: Medium) -> None:
        """The homogeneous medium ``medium`` with ``$sigma_t``/``$albedo``/``$g``."""
        self._defaults += [("sigma_t", fmt(m.sigma_t)), ("albedo", fmt(m.albedo))]
        med = ET.Element("medium", type="homogeneous", id="medium")
        ET.SubElement(med, "float", name="sigma_t", value="$sigma_t")
        ET.SubElement(med, "rgb", name="albedo", value="$albedo")
        phase = ET.SubElement(med, "phase", type=m.phase.kind)
        if m.phase.kind == "hg":
            self._defaults.append(("g", fmt(m.phase.g)))
            ET.SubElement(phase, "float", name="g", value="$g")
        self._medium = med

    def camera(self, origin: Vec, target: Vec, up: Vec = (0, 1, 0),
               fov: float = 60.0) -> None:
        """The perspective sensor (horizontal ``fov`` in degrees) in the medium."""
        sensor = ET.Element("sensor", type="perspective", id="camera")
        ET.SubElement(sensor, "float", name="fov", value=fmt(fov))
        tw = ET.SubElement(sensor, "transform", name="to_world")
        ET.SubElement(tw, "lookat", origin=fmt_vec(origin), target=fmt_vec(target),
                      up=fmt_vec(up))
        sampler = ET.SubElement(sensor, "sampler", type="independent")
        ET.SubElement(sampler, "integer", name="sample_count", value="$spp")
        film = ET.SubElement(sensor, "film", type="hdrfilm")
        ET.SubElement(film, "integer", name="width", value="$res_x")
        ET.SubElement(film, "integer", name="height", value="$res_y")
        ET.SubElement(film, "rfilter", type="box")
        ET.SubElement(film, "string", name="pixel_format", value="rgb")
        ET.SubElement(sensor, "ref", id="medium")
        self._sensor = sensor

    def medium_box(self, lo: Vec, hi: Vec) -> None:
        """The medium boundary: an axis-aligned null-BSDF cube from ``lo`` to ``hi``."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        shape = self._shape("cube", "medium_box")
        ET.SubElement(shape, "bsdf", type="null")
        _transform(shape, scale=(hi - lo) / 2, translate=(hi + lo) / 2)
        ET.SubElement(shape, "ref", name="interior", id="medium")
        self._shapes.insert(0, self._shapes.pop())

    # -- materials ----------------------------------------------------------
    def bsdf(self, ident: str, reflectance: Vec | float) -> str:
        """A named diffuse BSDF; returns its id for the shape methods."""
        if ident in self._bsdfs:
            raise ValueError(f"duplicate BSDF id {ident!r}")
        el = ET.Element("bsdf", type="diffuse", id=ident)
        refl = [reflectance] if np.isscalar(reflectance) else list(reflectance)
        ET.SubElement(el, "rgb", name="reflectance", value=fmt_vec(refl))
        self._bsdfs[ident] = el
        return ident

    # -- emitters -----------------------------------------------------------
    def directional(self, direction: Vec, irradiance: Vec | float) -> None:
        """A distant light; ``direction`` is the direction the light travels."""
        em = self._new_emitter("directional")
        ET.SubElement(em, "vector", name="direction", value=fmt_vec(direction))
        ET.SubElement(em, "rgb", name="irradiance", value=_colour(irradiance))

    def point(self, position: Vec, intensity: Vec | float) -> None:
        """An isotropic point light (``intensity`` in W/sr)."""
        em = self._new_emitter("point")
        ET.SubElement(em, "point", name="position", value=fmt_vec(position))
        ET.SubElement(em, "rgb", name="intensity", value=_colour(intensity))

    def spot(self, origin: Vec, target: Vec, intensity: Vec | float,
             cutoff_angle: float, beam_width: float, texture: str | None = None,
             up: Vec = (0, 1, 0)) -> None:
        """A spot light at ``origin`` aimed at ``target``, optionally projecting
        the bitmap ``texture`` (a path relative to the scene file)."""
        em = self._new_emitter("spot")
        tw = ET.SubElement(em, "transform", name="to_world")
        ET.SubElement(tw, "lookat", origin=fmt_vec(origin), target=fmt_vec(target),
                      up=fmt_vec(up))
        ET.SubElement(em, "rgb", name="intensity", value=_colour(intensity))
        ET.SubElement(em, "float", name="cutoff_angle", value=fmt(cutoff_angle))
        ET.SubElement(em, "float", name="beam_width", value=fmt(beam_width))
        if texture is not None:
            tex = ET.SubElement(em, "texture", type="bitmap", name="texture")
            ET.SubElement(tex, "string", name="filename", value=texture)

    # -- shapes -------------------------------------------------------------
    def box(self, ident: str, bsdf: str, lo: Vec, hi: Vec,
            rotate_y: float = 0.0) -> None:
        """A solid box from ``lo`` to ``hi``, optionally turned about its
        vertical axis by ``rotate_y`` degrees."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        shape = self._shape("cube", ident, bsdf)
        _transform(shape, scale=(hi - lo) / 2, rotate_y=rotate_y,
                   translate=(hi + lo) / 2)

    def rectangle(self, ident: str, bsdf: str, center: Vec, normal: Vec,
                  up: Vec, width: float, height: float) -> None:
        """A one-sided ``width`` x ``height`` rectangle facing ``normal``;
        its height runs along ``up``."""
        shape = self._shape("rectangle", ident, bsdf)
        _oriented(shape, center, normal, up, (width / 2, height / 2, 1))

    def disk(self, ident: str, bsdf: str, center: Vec, normal: Vec,
             radius: float, up: Vec = (0, 1, 0)) -> None:
        """A one-sided disk of ``radius`` facing ``normal``."""
        shape = self._shape("disk", ident, bsdf)
        _oriented(shape, center, normal, up, (radius, radius, 1))

    def sphere(self, ident: str, bsdf: str, center: Vec, radius: float) -> None:
        """A sphere."""
        shape = self._shape("sphere", ident, bsdf)
        ET.SubElement(shape, "point", name="center", value=fmt_vec(center))
        ET.SubElement(shape, "float", name="radius", value=fmt(radius))

    def cylinder(self, ident: str, bsdf: str, p0: Vec, p1: Vec, radius: float) -> None:
        """An open cylinder (no caps) from ``p0`` to ``p1``."""
        shape = self._shape("cylinder", ident, bsdf)
        ET.SubElement(shape, "point", name="p0", value=fmt_vec(p0))
        ET.SubElement(shape, "point", name="p1", value=fmt_vec(p1))
        ET.SubElement(shape, "float", name="radius", value=fmt(radius))

    def ply(self, ident: str, bsdf: str, filename: str) -> None:
        """A PLY mesh (``filename`` relative to the scene file)."""
        shape = self._shape("ply", ident, bsdf)
        ET.SubElement(shape, "string", name="filename", value=filename)

    # -- output -------------------------------------------------------------
    def to_string(self) -> str:
        """The document as text (deterministic: same calls, same bytes)."""
        missing = [n for n, el in (("medium", self._medium), ("camera", self._sensor),
                                   ("emitter", self._emitters or None)) if el is None]
        if missing or "medium_box" not in self._ids:
            raise ValueError(f"scene is incomplete: missing {missing or ['medium_box']}")
        root = ET.Element("scene", version="3.0.0")
        for name, value in self._defaults:
            ET.SubElement(root, "default", name=name, value=value)
        integ = ET.SubElement(root, "integrator", type="volpath")
        ET.SubElement(integ, "integer", name="max_depth", value="2")
        root.extend([self._medium, self._sensor, *self._bsdfs.values(),
                     *self._emitters, *self._shapes])
        ET.indent(root, space="    ")
        body = ET.tostring(root, encoding="unicode")
        head = '<?xml version="1.0" encoding="utf-8"?>\n'
        if self.comment:
            head += f"<!-- {self.comment} -->\n"
        return head + body + "\n"

    # -- helpers ------------------------------------------------------------
    def _new_emitter(self, kind: str) -> ET.Element:
        """The next emitter: ids ``light``, ``light_2``, ``light_3``, ..."""
        n = len(self._emitters) + 1
        self._emitters.append(ET.Element("emitter", type=kind,
                                         id="light" if n == 1 else f"light_{n}"))
        return self._emitters[-1]

    def _shape(self, kind: str, ident: str, bsdf: str | None = None) -> ET.Element:
        if ident in self._ids:
            raise ValueError(f"duplicate shape id {ident!r}")
        if bsdf is not None and bsdf not in self._bsdfs:
            raise ValueError(f"shape {ident!r} uses undeclared BSDF {bsdf!r}")
        self._ids.add(ident)
        shape = ET.Element("shape", type=kind, id=ident)
        if bsdf is not None:
            ET.SubElement(shape, "ref", id=bsdf)
        self._shapes.append(shape)
        return shape


def _colour(value: Vec | float) -> str:
    return fmt(value) if np.isscalar(value) else fmt_vec(value)


def _transform(parent: ET.Element, scale: Vec, translate: Vec,
               rotate_y: float = 0.0) -> None:
    """``to_world`` = translate * rotate_y * scale."""
    tw = ET.SubElement(parent, "transform", name="to_world")
    x, y, z = (fmt(c) for c in scale)
    ET.SubElement(tw, "scale", x=x, y=y, z=z)
    if rotate_y:
        ET.SubElement(tw, "rotate", y="1", angle=fmt(rotate_y))
    x, y, z = (fmt(c) for c in translate)
    ET.SubElement(tw, "translate", x=x, y=y, z=z)


def _oriented(parent: ET.Element, center: Vec, normal: Vec, up: Vec,
              scale: Vec) -> None:
    """``to_world`` mapping local +z to ``normal`` and local +y to ``up``.

    Mitsuba's ``lookat`` sends local +x to ``cross(up, dir)`` and local +y to
    ``cross(dir, left)``, i.e. ``up`` projected orthogonal to the normal.
    """
    center = np.asarray(center, float)
    tw = ET.SubElement(parent, "transform", name="to_world")
    x, y, z = (fmt(c) for c in scale)
    ET.SubElement(tw, "scale", x=x, y=y, z=z)
    ET.SubElement(tw, "lookat", origin=fmt_vec(center),
                  target=fmt_vec(center + np.asarray(normal, float)), up=fmt_vec(up))
