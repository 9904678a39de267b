"""The one render template every episcatter integrator shares (DESIGN §3).

``render()`` = validate the scene (:class:`SceneParams`), capture the camera
G-buffer, call the method's :meth:`EpiscatterIntegrator.scattering` hook, and
compose ``L = T_cam · L_surface + L_scat`` with a box pixel filter.  Each stage
is timed (``dr.eval`` + ``dr.sync_thread``) into ``integrator.timings``
(seconds) so benchmarks can report scattering-only and end-to-end times.

Common properties (every method):

=====================  ======================================================
``output``             ``full`` (default): what volpath ``max_depth=2``
                       converges to; ``scattering``: L_scat alone.
``samples_per_pixel``  camera samples per pixel (box filter, default 1); the
                       ``spp`` argument of ``mi.render`` overrides it.
``jitter_pixels``      jitter camera samples inside the pixel (default: true
                       when more than one sample per pixel).
=====================  ======================================================

``render_layers()`` returns every layer (``full``, ``scattering``,
``surface``, ``distance``); ``mi.render`` returns the ``output`` layer (RGB).
"""
from __future__ import annotations

import math
import time
from contextlib import contextmanager

import drjit as dr
import mitsuba as mi

from .capture import CameraCapture, capture_camera
from .scene_params import SceneParams

OUTPUTS = ("full", "scattering")


def read_choice(props, name, default, choices):
    value = props.get(name, default)
    if value not in choices:
        raise ValueError(f"Property '{name}' = '{value}' is not one of {list(choices)}.")
    return value


def read_number(props, name, default, minimum=None, maximum=None, integer=False):
    value = props.get(name, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"Property '{name}' = {value!r} must be a finite number.")
    if integer and int(value) != value:
        raise ValueError(f"Property '{name}' = {value} must be an integer.")
    if minimum is not None and value < minimum:
        raise ValueError(f"Property '{name}' = {value} must be >= {minimum}.")
    if maximum is not None and value > maximum:
        raise ValueError(f"Property '{name}' = {value} must be <= {maximum}.")
    return int(value) if integer else float(value)


def read_bool(props, name: str, default: bool) -> bool:
    value = props.get(name, default)
    if not isinstance(value, bool):
        raise ValueError(f"Property '{name}' = {value!r} must be a boolean.")
    return value


def pixel_average(values, pixel, n_pixels, spp):
    """Box filter: mean of each pixel's ``spp`` consecutive samples."""
    if spp == 1:
        return values
    out = dr.zeros(type(values), n_pixels)
    dr.scatter_reduce(dr.ReduceOp.Add, out, values, pixel)
    return out * (1.0 / spp)


def to_image(values, width, height):
    """Per-pixel Color3f/Float -> TensorXf (height, width, channels)."""
    if isinstance(values, mi.Color3f):
        flat = dr.ravel(values)
        return mi.TensorXf(flat, shape=(height, width, 3))
    return mi.TensorXf(values, shape=(height, width, 1))


class EpiscatterIntegrator(mi.SamplingIntegrator):
    """Base class; subclasses implement :meth:`scattering` (and may read
    their own properties in :meth:`read_properties`)."""

    #: stages the template times; methods may add their own via self.stage()
    def __init__(self, props):
        super().__init__(props)
        self.output = read_choice(props, "output", "full", OUTPUTS)
        self.samples_per_pixel = read_number(props, "samples_per_pixel", 1, minimum=1,
                                             integer=True)
        self.jitter_pixels = props.get("jitter_pixels", None)
        self.timings: dict[str, float] = {}
        self.render_seed = 0
        self.read_properties(props)

    # -- hooks ------------------------------------------------------------------
    def read_properties(self, props) -> None:
        """Read and validate method properties (hook)."""

    def scattering(self, params: SceneParams, cap: CameraCapture) -> mi.Color3f:
        """L_scat per camera sample of ``cap`` (hook)."""
        raise NotImplementedError

    # -- timing -----------------------------------------------------------------
    @contextmanager
    def stage(self, name):
        """Time a block; results appended to the yielded list are evaluated
        (and waited for) before the clock stops."""
        t0 = time.perf_counter()
        out = []
        yield out
        dr.eval(*out) if out else None
        dr.sync_thread()
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0

    # -- the template -------------------------------------------------------------
    def render_layers(self, scene, sensor=0, seed=0, spp=0):
        self.timings = {}
        self.render_seed = int(seed)
        t_start = time.perf_counter()
        with self.stage("validate"):
            params = SceneParams.from_scene(scene, sensor)
        spp = int(spp) if spp else self.samples_per_pixel
        jitter = self.jitter_pixels if self.jitter_pixels is not None else spp > 1
        with self.stage("capture") as keep:
            cap = capture_camera(params, spp=spp, jitter=bool(jitter), seed=int(seed),
                                 surface=self.output == "full")
            keep.append(cap.d)
        with self.stage("scattering") as keep:
            L_scat = self.scattering(params, cap)
            keep.append(L_scat)
        with self.stage("compose") as keep:
            n_pix = cap.width * cap.height
            scat = pixel_average(L_scat, cap.pixel, n_pix, spp)
            surf = pixel_average(cap.T_cam * cap.L_surface, cap.pixel, n_pix, spp)
            dist = pixel_average(cap.d, cap.pixel, n_pix, spp)
            full = surf + scat
            keep.extend([scat, surf, dist, full])
        self.timings["total"] = time.perf_counter() - t_start
        w, h = cap.width, cap.height
        return {"full": to_image(full, w, h), "scattering": to_image(scat, w, h),
                "surface": to_image(surf, w, h), "distance": to_image(dist, w, h)}

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if not develop:
            raise ValueError(f"{type(self).__name__} only supports develop=True.")
        return self.render_layers(scene, sensor, seed, spp)[self.output]

    def to_string(self):
        return f"{type(self).__name__}[output={self.output}]"
