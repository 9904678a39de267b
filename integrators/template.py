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
``samples_per_pixel``  camera samples per pixel (box filter); default: the
                       sensor's sampler's ``sample_count`` (Mitsuba's
                       convention); the ``spp`` argument of ``mi.render``
                       overrides both.
``jitter_pixels``      jitter camera samples inside the pixel (default: true
                       when more than one sample per pixel).
=====================  ======================================================

Boolean properties accept Mitsuba's ``<boolean>`` and the strings
``true/false``, ``yes/no``, ``on/off``, ``1/0`` (any case); anything else is
refused (:func:`read_bool`).

``render_layers()`` returns every layer (``full``, ``scattering``,
``surface``, ``distance``); ``mi.render`` returns the ``output`` layer (RGB)
and, as Mitsuba's integrators do, develops every layer into the sensor's
film (``film.bitmap()``, ``film.write()``; the layers other than the
output are the film's AOVs, :meth:`EpiscatterIntegrator.aov_names`).
``mi.traverse(integrator)`` lists the properties (read-only: build a new
integrator to change one).  The methods render whole images, so there is
no per-ray ``sample()`` (Mitsuba's ``aov`` integrator cannot wrap them: use
the film's AOVs) and no derivatives (``render_forward``/``render_backward``
refuse).
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
#: the layers of render_layers() and their channels (film AOV names)
LAYERS = ("full", "scattering", "surface", "distance")
LAYER_CHANNELS = {"full": "RGB", "scattering": "RGB", "surface": "RGB", "distance": "Y"}
NO_DERIVATIVES = ("{} is not differentiable: derivatives are not supported (the epipolar "
                  "and filtered methods have no adjoint). For gradients render with one of "
                  "Mitsuba's differentiable integrators, e.g. 'prbvolpath'.")


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


#: the strings read_bool accepts (compared in lower case)
BOOL_STRINGS = {"true": True, "yes": True, "on": True, "1": True,
                "false": False, "no": False, "off": False, "0": False}


def read_bool(props, name: str, default: bool) -> bool:
    """A boolean property: Mitsuba's ``<boolean>``, or one of
    :data:`BOOL_STRINGS` (a ``<string>`` property, ``-p name=no``); anything
    else is a ``ValueError`` (``bool("false")`` would be True)."""
    value = props.get(name, default)
    if isinstance(value, str) and value.strip().lower() in BOOL_STRINGS:
        return BOOL_STRINGS[value.strip().lower()]
    if not isinstance(value, bool):
        raise ValueError(f"Property '{name}' = {value!r} must be a boolean "
                         f"(<boolean name=\"{name}\" value=\"true\"/>, or one of "
                         f"{sorted(BOOL_STRINGS)}).")
    return value


def sensor_of(scene, sensor=0):
    """``mi.render``'s ``sensor`` argument (an index or a Sensor) as a Sensor."""
    return scene.sensors()[sensor] if isinstance(sensor, int) else sensor


def scalar_seed(seed) -> int:
    """``mi.render``'s seed as a Python int (Mitsuba may pass a Dr.Jit
    ``UInt32`` of width 1)."""
    if dr.is_array_v(seed):
        if dr.width(seed) != 1:
            raise ValueError(f"seed must be one number, got {dr.width(seed)} values.")
        seed = seed[0]
    return int(seed)


def develop_into_film(film, layers: dict, output: str, aovs: list) -> None:
    """Write the rendered layers into ``film``'s storage as Mitsuba's own
    integrators leave it after ``mi.render`` (``film.prepare`` + one image
    block): ``output`` as the colour, weight 1 (the box filter's pixel
    averages are final), alpha 1, then the ``aovs`` ("layer.C")."""
    channels = film.prepare(aovs)
    base = int(film.base_channels_count())
    if base not in (3, 4) or channels != base + 1 + len(aovs):
        raise ValueError(f"film '{film.class_name()}' with {base} base channels is not "
                         "supported: use an RGB(A) hdrfilm.")
    h, w = layers[output].shape[0], layers[output].shape[1]
    columns = [layers[output][..., c] for c in range(3)]
    ones = dr.full(mi.TensorXf, 1.0, (h, w))
    columns += [ones] * (base - 3) + [ones]          # alpha, weight
    for name in aovs:
        layer, channel = name.split(".")
        columns.append(layers[layer][..., LAYER_CHANNELS[layer].index(channel)])
    block = mi.ImageBlock(mi.TensorXf(dr.ravel(dr.stack(columns, axis=-1)),
                                      (h, w, channels)),
                          offset=film.crop_offset(), rfilter=film.rfilter(), border=False)
    film.put_block(block)


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
        self.samples_per_pixel = (read_number(props, "samples_per_pixel", 1, minimum=1,
                                              integer=True)
                                  if "samples_per_pixel" in props else None)
        self.jitter_pixels = (read_bool(props, "jitter_pixels", False)
                              if "jitter_pixels" in props else None)
        self.read_properties(props)
        #: what mi.traverse lists: the properties as read (plain values)
        self.property_names = tuple(k for k, v in vars(self).items()
                                    if not k.startswith("_") and
                                    isinstance(v, (bool, int, float, str, type(None))))
        self.timings: dict[str, float] = {}
        self.render_seed = 0

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

    # -- Mitsuba conventions ------------------------------------------------------
    def sample_count(self, scene, sensor=0, spp=0) -> int:
        """Camera samples per pixel of a render: ``spp`` if > 0, else the
        ``samples_per_pixel`` property if given, else the sensor's sampler's
        ``sample_count`` (what Mitsuba's integrators do)."""
        if isinstance(spp, bool) or int(spp) != spp or spp < 0:
            raise ValueError(f"spp = {spp!r} must be a whole number >= 0 "
                             "(0: the integrator's samples_per_pixel or the sensor's sampler).")
        if spp:
            return int(spp)
        if self.samples_per_pixel is not None:
            return self.samples_per_pixel
        return int(sensor_of(scene, sensor).sampler().sample_count())

    def jitters(self, spp: int) -> bool:
        """Whether camera samples are jittered inside the pixel at ``spp``
        samples per pixel (else: at the pixel centre, for spp = 1)."""
        return bool(self.jitter_pixels if self.jitter_pixels is not None else spp > 1)

    def aov_names(self):
        """The layers besides the output, developed into the film as AOVs."""
        return [f"{layer}.{c}" for layer in LAYERS if layer != self.output
                for c in LAYER_CHANNELS[layer]]

    def traverse(self, callback):
        """The properties, read-only (``mi.traverse``)."""
        for name in self.property_names:
            callback.put(name, getattr(self, name), mi.ParamFlags.ReadOnly)

    def sample(self, scene, sampler, ray, medium=None, active=True):
        raise NotImplementedError(
            f"{type(self).__name__} renders whole images (epipolar/filtered methods have no "
            "per-ray sample()), so Mitsuba's 'aov' integrator cannot wrap it: its layers "
            "(scattering, surface, distance) are AOVs of the film after mi.render, or "
            "integrator.render_layers(scene).")

    def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
        raise NotImplementedError(NO_DERIVATIVES.format(type(self).__name__))

    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        raise NotImplementedError(NO_DERIVATIVES.format(type(self).__name__))

    # -- the template -------------------------------------------------------------
    def render_layers(self, scene, sensor=0, seed=0, spp=0):
        self.timings = {}
        self.render_seed = seed = scalar_seed(seed)
        t_start = time.perf_counter()
        with self.stage("validate"):
            params = SceneParams.from_scene(scene, sensor)
        spp = self.sample_count(scene, sensor, spp)
        jitter = self.jitters(spp)
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
        layers = self.render_layers(scene, sensor, seed, spp)
        develop_into_film(sensor_of(scene, sensor).film(), layers, self.output,
                          self.aov_names())
        return layers[self.output]

    def to_string(self):
        return f"{type(self).__name__}[output={self.output}]"
