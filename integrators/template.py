"""The one render template every episcatter integrator shares (DESIGN §3).

``render()`` = check the variant (:func:`check_variant`), validate the scene
(:class:`SceneParams`), capture the camera G-buffer, call the method's
:meth:`EpiscatterIntegrator.scattering` hook, and compose
``L = T_cam · L_surface + L_scat`` with a box pixel filter.  Each stage is
timed (``dr.eval`` + ``dr.sync_thread``) into the render's
:class:`RenderResult` (``.timings``, seconds) so benchmarks can report
scattering-only and end-to-end times; what a method wants to report about
one render (counts, the path it took) goes into ``.stats``
(:meth:`EpiscatterIntegrator.record`).  Nothing about a render is kept on the
integrator.

Partial renders: ``render_layers(..., samples=mask)`` computes only the camera
samples of a boolean mask (index ``pixel*spp + k``, capture order), widened by
the method's :meth:`EpiscatterIntegrator.widen_samples` hook to what it can
compute alone; the other samples are 0 in every layer, and
``RenderResult.samples`` says which samples were computed.

Common properties (every method):

=====================  ======================================================
``output``             ``full`` (default): what volpath ``max_depth=2``
                       converges to; ``scattering``: L_scat alone.
``samples_per_pixel``  camera samples per pixel (box filter, default 1); the
                       ``spp`` argument of ``mi.render`` overrides it.
``jitter_pixels``      jitter camera samples inside the pixel (default: true
                       when more than one sample per pixel).
=====================  ======================================================

``render_layers()`` returns a :class:`RenderResult`, a mapping of every layer
(``full``, ``scattering``, ``surface``, ``distance``); ``mi.render`` returns the
``output`` layer (RGB; one channel in ``*_mono`` variants).
"""
from __future__ import annotations

import contextvars
import math
import time
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from .capture import CameraCapture, capture_camera
from .scene_params import SceneParams

OUTPUTS = ("full", "scattering")
#: the Mitsuba variants the integrators run on: Dr.Jit JIT backends (LLVM or
#: CUDA) with RGB or monochrome colour
SUPPORTED_VARIANTS = ("llvm_ad_rgb", "llvm_rgb", "llvm_ad_mono", "llvm_mono",
                      "cuda_ad_rgb", "cuda_rgb", "cuda_ad_mono", "cuda_mono")


def check_variant(variant: str | None = None) -> str:
    """The active Mitsuba variant, or a ValueError naming the supported ones
    (scalar variants have no Dr.Jit kernels; spectral ones are not modelled)."""
    variant = mi.variant() if variant is None else variant
    if variant not in SUPPORTED_VARIANTS:
        raise ValueError(
            f"episcatter integrators do not support the Mitsuba variant '{variant}'; "
            f"use one of {list(SUPPORTED_VARIANTS)} (mi.set_variant('llvm_ad_rgb')).")
    return variant


@dataclass
class RenderRecord:
    """What one render accumulates while it runs (seed, stage times, stats)."""
    seed: int = 0
    timings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


#: the record of the render running in this thread/context
_RECORD: contextvars.ContextVar = contextvars.ContextVar("episcatter_render_record")


@dataclass(frozen=True)
class RenderResult(Mapping):
    """One render: ``layers`` (name -> TensorXf; the result is also a mapping
    of them), ``timings`` (stage -> seconds), ``stats`` (what the method
    recorded), ``samples`` (mi.Bool over the camera samples that were
    computed; None: all of them)."""
    layers: dict
    timings: dict
    stats: dict
    samples: object = None

    def __getitem__(self, name):
        return self.layers[name]

    def __iter__(self):
        return iter(self.layers)

    def __len__(self):
        return len(self.layers)


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


def to_image(values, width, height, mono=False):
    """Per-pixel Color3f/Float -> TensorXf (height, width, channels); with
    ``mono`` a Color3f keeps its first channel (the methods compute in
    Color3f; in a ``*_mono`` variant its three channels are equal)."""
    if isinstance(values, mi.Color3f):
        if mono:
            return mi.TensorXf(values.x, shape=(height, width, 1))
        flat = dr.ravel(values)
        return mi.TensorXf(flat, shape=(height, width, 3))
    return mi.TensorXf(values, shape=(height, width, 1))


def sample_mask(samples, count: int) -> mi.Bool:
    """A partial render's sample mask (mi.Bool or NumPy bool array of
    ``count`` = pixels × spp entries) as an mi.Bool."""
    import numpy as np
    if not isinstance(samples, mi.Bool):
        arr = np.asarray(samples)
        if arr.dtype != np.bool_:
            raise ValueError(f"samples: expected a boolean mask, got dtype {arr.dtype}; "
                             "pass e.g. numpy.zeros(pixels * spp, bool) with True where to render.")
        samples = mi.Bool(arr.ravel())
    if dr.width(samples) != count:
        raise ValueError(f"samples: the mask has {dr.width(samples)} entries but the render "
                         f"has {count} camera samples (pixels × spp, index pixel*spp + k).")
    return samples


def masked_scattering(scattering, params, cap, computed: mi.Bool):
    """L_scat of the ``computed`` samples of ``cap`` (0 elsewhere): the
    method's ``scattering`` runs on the subset capture alone."""
    index = dr.compress(computed)
    out = dr.zeros(mi.Color3f, cap.count)
    if dr.width(index):
        dr.scatter(out, scattering(params, cap.subset(index)), index)
    return out


class EpiscatterIntegrator(mi.SamplingIntegrator):
    """Base class; subclasses implement :meth:`scattering` (and may read
    their own properties in :meth:`read_properties`)."""

    #: stages the template times; methods may add their own via self.stage()
    def __init__(self, props):
        check_variant()
        super().__init__(props)
        self.output = read_choice(props, "output", "full", OUTPUTS)
        self.samples_per_pixel = read_number(props, "samples_per_pixel", 1, minimum=1,
                                             integer=True)
        self.jitter_pixels = props.get("jitter_pixels", None)
        self.read_properties(props)

    # -- hooks ------------------------------------------------------------------
    def read_properties(self, props) -> None:
        """Read and validate method properties (hook)."""

    def scattering(self, params: SceneParams, cap: CameraCapture) -> mi.Color3f:
        """L_scat per camera sample of ``cap`` (hook)."""
        raise NotImplementedError

    def widen_samples(self, params: SceneParams, cap: CameraCapture, mask: mi.Bool) -> mi.Bool:
        """The camera samples to compute for a partial render of ``mask``
        (hook): the smallest superset the method computes exactly as in a
        full render.  Default: ``mask`` itself (per-sample methods)."""
        return mask

    # -- per-render record and timing --------------------------------------------
    @property
    def render_record(self) -> RenderRecord:
        """The record of the render in progress (seed, timings, stats)."""
        try:
            return _RECORD.get()
        except LookupError:
            raise RuntimeError(f"{type(self).__name__}: no render is in progress "
                               "(call render_layers or mi.render).") from None

    def record(self, **stats) -> None:
        """Add named values to the running render's ``RenderResult.stats``."""
        self.render_record.stats.update(stats)

    @contextmanager
    def stage(self, name):
        """Time a block; results appended to the yielded list are evaluated
        (and waited for) before the clock stops."""
        t0 = time.perf_counter()
        out = []
        yield out
        dr.eval(*out) if out else None
        dr.sync_thread()
        timings = self.render_record.timings
        timings[name] = timings.get(name, 0.0) + time.perf_counter() - t0

    # -- the template -------------------------------------------------------------
    def render_layers(self, scene, sensor=0, seed=0, spp=0, samples=None) -> RenderResult:
        """Every layer of one render (see the module doc; ``samples``: an
        optional boolean mask over the camera samples, mi.Bool or NumPy)."""
        variant = check_variant()
        record = RenderRecord(seed=int(seed))
        token = _RECORD.set(record)
        try:
            return self._render_layers(scene, sensor, seed, spp, samples, record, variant)
        finally:
            _RECORD.reset(token)

    def _render_layers(self, scene, sensor, seed, spp, samples, record, variant):
        t_start = time.perf_counter()
        with self.stage("validate"):
            params = SceneParams.from_scene(scene, sensor)
        spp = int(spp) if spp else self.samples_per_pixel
        jitter = self.jitter_pixels if self.jitter_pixels is not None else spp > 1
        with self.stage("capture") as keep:
            cap = capture_camera(params, spp=spp, jitter=bool(jitter), seed=int(seed),
                                 surface=self.output == "full")
            keep.append(cap.d)
        computed = None
        if samples is not None:
            with self.stage("widen") as keep:
                computed = self.widen_samples(params, cap, sample_mask(samples, cap.count))
                keep.append(computed)
        with self.stage("scattering") as keep:
            if computed is None:
                L_scat = self.scattering(params, cap)
            else:
                L_scat = masked_scattering(self.scattering, params, cap, computed)
            keep.append(L_scat)
        with self.stage("compose") as keep:
            n_pix = cap.width * cap.height
            T_L, d = cap.T_cam * cap.L_surface, cap.d
            if computed is not None:
                T_L, d = dr.select(computed, T_L, 0.0), dr.select(computed, d, 0.0)
            scat = pixel_average(L_scat, cap.pixel, n_pix, spp)
            surf = pixel_average(T_L, cap.pixel, n_pix, spp)
            dist = pixel_average(d, cap.pixel, n_pix, spp)
            full = surf + scat
            keep.extend([scat, surf, dist, full])
        record.timings["total"] = time.perf_counter() - t_start
        w, h = cap.width, cap.height
        mono = "mono" in variant
        layers = {"full": to_image(full, w, h, mono), "scattering": to_image(scat, w, h, mono),
                  "surface": to_image(surf, w, h, mono), "distance": to_image(dist, w, h)}
        return RenderResult(layers=layers, timings=dict(record.timings),
                            stats=dict(record.stats), samples=computed)

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if not develop:
            raise ValueError(f"{type(self).__name__} only supports develop=True.")
        return self.render_layers(scene, sensor, seed, spp)[self.output]

    def to_string(self):
        return f"{type(self).__name__}[output={self.output}]"
