"""The one render template every episcatter integrator shares (DESIGN §3).

``render()`` = check the variant (:func:`check_variant`), validate the scene
(:class:`~integrators.core.scene_params.SceneParams`), capture the camera G-buffer, call the
method's
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
compute exactly as the full render does; the other samples are 0 in every
layer, ``RenderResult.samples`` says which samples were computed, and
``RenderResult.capture`` / ``.L_scat`` hold the computed samples' G-buffer
and L_scat (an animation keeps the previous frame's values for the others,
:mod:`episcatter.sequence`).  A method whose samples depend on their own
rays alone (:meth:`EpiscatterIntegrator.samples_alone`) captures the masked
samples alone; the others capture the whole frame (their rows, maps and
kernels are chosen from it) and compute a subset of it
(:meth:`EpiscatterIntegrator.partial_scattering`).  ``moved``: boxes
(:class:`integrators.core.shadow_volumes.Boxes`) bounding the scene objects that
moved since the frame whose values the caller keeps: a method that shares
blockers between samples (a slice's light rays) widens the mask to the
samples whose shared blockers meet them.

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
``quality``            ``explicit`` (default) or ``auto``: choose the
                       method's settings for ``error_budget`` (relMSE,
                       pixel centres) with a probe of the scene
                       (:mod:`integrators.core.quality_auto`).
=====================  ======================================================

``render_layers()`` returns a :class:`RenderResult`, a mapping of every layer
(``full``, ``scattering``, ``surface``, ``distance``); ``mi.render`` returns the
``output`` layer (RGB; one channel in ``*_mono`` variants) and, as Mitsuba's
integrators do, develops every layer into the sensor's film (``film.bitmap()``,
``film.write()``; the layers other than the output are the film's AOVs,
:meth:`EpiscatterIntegrator.aov_names`).

Boolean properties accept Mitsuba's ``<boolean>`` and the strings
``true/false``, ``yes/no``, ``on/off``, ``1/0`` (any case); anything else is
refused (:func:`~integrators.core.properties.read_bool`).  ``mi.traverse(integrator)`` lists the
properties (read-only: build a new integrator to change one).  The methods
render whole images, so there is no per-ray ``sample()`` (Mitsuba's ``aov``
integrator cannot wrap them: use the film's AOVs) and no derivatives
(``render_forward``/``render_backward`` refuse).
"""
from __future__ import annotations

import contextvars
import time
import warnings
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from rectify._dr import drain_jit_kernels

from ..core import quality_auto
from ..core.capture import CameraCapture, capture_camera
from ..core.film import LAYERS, OUTPUTS, compose_layers, develop_into_film, layer_channels
from ..core.properties import check_unknown_properties, read_bool, read_choice, read_number
from ..core.scene_params import SceneParams
from ..partial.samples import empty_capture, masked_scattering, merge_capture, sample_mask


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
    """What one render accumulates while it runs (seed, stage times, stats),
    the frame state it was handed (``given``: an earlier render's
    ``frame_state``, for a partial render) and the one it hands on
    (``frame_state``)."""
    seed: int = 0
    timings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    given: object = None
    frame_state: object = None
    #: camera-sample index lists (mi.UInt32) whose values the method could
    #: not resolve and asks the epipolar template to ray-march with the
    #: samples it marches anyway (one march: ``remarch_disagreeing``)
    march: list = field(default_factory=list)
    #: (stats name, mask maker) pairs: camera-sample masks asked for like
    #: ``march`` whose maker the template calls where its next kernel over
    #: the queries makes them (``remarch_disagreeing``)
    march_later: list = field(default_factory=list)
    #: with ``report_launches``: JIT kernels launched per stage (else None)
    launches: dict | None = None
    #: with ``report_launches``: their execution time per stage [ms]
    kernel_ms: dict = field(default_factory=dict)
    #: the stage running (what launches outside every stage count under)
    stage: str = "other"


@dataclass(frozen=True)
class LightState:
    """What a several-light render keeps of one light for the next frame's
    partial render: the method's own frame state (None: none), the light's
    L_scat on every sample of the full capture (None: a subset was
    captured) and its frame choices (``stats["frame_choices"]``)."""
    frame_state: object
    L_scat: object
    choices: object


class LightStates(tuple):
    """The :class:`LightState` of every light of a several-light render, in
    the scene's order (its ``RenderResult.frame_state``)."""


#: why a camera outside the medium rules out a method's own sampling, and
#: the fix (:func:`warn_every_pixel_marched`)
CAMERA_OUTSIDE = ("the camera is outside the medium (each ray is marched from where it "
                  "enters the fog)", "put the camera inside the fog volume")


def warn_every_pixel_marched(method: str, why: str, fix: str) -> None:
    """The one warning of a method that marches every pixel because the
    scene rules its own sampling out (``why``): correct, at a ray marcher's
    cost, and ``fix`` gives the method's speed back."""
    warnings.warn(f"{method}: {why}, so every pixel is ray-marched (correct, at a ray "
                  f"marcher's cost); {fix} for the epipolar speed-up.", UserWarning,
                  stacklevel=4)


def count_launches(record: RenderRecord, stage: str) -> None:
    """Charge the JIT kernels launched since the last count, and their
    execution time, to ``stage``."""
    kernels = drain_jit_kernels()
    if kernels:
        record.launches[stage] = record.launches.get(stage, 0) + len(kernels)
        record.kernel_ms[stage] = record.kernel_ms.get(stage, 0.0) + sum(
            float(k.get("execution_time", 0.0)) for k in kernels)


#: Dr.Jit's expand threshold during a render: 0, reductions with local
#: atomics (an expanded reduction writes its target's size into the kernel)
SCATTER_EXPAND_THRESHOLD = 0

#: the record of the render running in this thread/context
_RECORD: contextvars.ContextVar = contextvars.ContextVar("episcatter_render_record")


@dataclass(frozen=True)
class RenderResult(Mapping):
    """One render: ``layers`` (name -> TensorXf; the result is also a mapping
    of them), ``timings`` (stage -> seconds), ``stats`` (what the method
    recorded), ``samples`` (mi.Bool over the camera samples that were
    computed; None: all of them), ``capture`` (the camera capture that was
    computed: all samples, or a subset capture of the computed ones,
    ``capture.sample`` their indices) and ``L_scat`` (per sample of
    ``capture``; 0 on samples of a full capture that were not computed),
    ``frame_state`` (what the method can reuse in a partial render of a
    later frame with the same camera, light and medium; opaque, None for
    most methods)."""
    layers: dict
    timings: dict
    stats: dict
    samples: object = None
    capture: object = None
    L_scat: object = None
    frame_state: object = None

    def __getitem__(self, name):
        return self.layers[name]

    def __iter__(self):
        return iter(self.layers)

    def __len__(self):
        return len(self.layers)
NO_DERIVATIVES = ("{} is not differentiable: derivatives are not supported (the epipolar "
                  "and filtered methods have no adjoint). For gradients render with one of "
                  "Mitsuba's differentiable integrators, e.g. 'prbvolpath'.")


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


class EpiscatterIntegrator(mi.SamplingIntegrator):
    """Base class; subclasses implement :meth:`scattering` (and may read
    their own properties in :meth:`read_properties`)."""

    #: properties a plugin has renamed: old name -> new name (the error for
    #: the old name says the new one)
    RENAMED_PROPERTIES: dict = {}

    #: stages the template times; methods may add their own via self.stage()
    def __init__(self, props):
        check_variant()
        super().__init__(props)
        self.output = read_choice(props, "output", "full", OUTPUTS)
        self.samples_per_pixel = (read_number(props, "samples_per_pixel", 1, minimum=1,
                                              integer=True)
                                  if "samples_per_pixel" in props else None)
        self.jitter_pixels = (read_bool(props, "jitter_pixels", False)
                              if "jitter_pixels" in props else None)
        #: count the JIT kernels of each stage into ``stats["launches"]``
        #: (owns Dr.Jit's kernel history during the render)
        self.report_launches = read_bool(props, "report_launches", False)
        self.quality, self.error_budget = quality_auto.read_quality(props)
        self.method_name = props.plugin_name()
        self.read_properties(props)
        check_unknown_properties(props, self.method_name,
                                 [k for k in vars(self) if not k.startswith("_")],
                                 self.RENAMED_PROPERTIES)
        #: the properties as given, but the quality mode (quality="auto"
        #: renders with these plus the settings it chooses)
        self._explicit = {k: props[k] for k in props.keys()
                          if k not in ("quality", "error_budget")}
        #: what mi.traverse lists: the properties as read (plain values)
        self.property_names = tuple(k for k, v in vars(self).items()
                                    if not k.startswith("_") and
                                    isinstance(v, (bool, int, float, str, type(None))))

    # -- hooks ------------------------------------------------------------------
    def read_properties(self, props) -> None:
        """Read and validate method properties (hook)."""

    def scattering(self, params: SceneParams, cap: CameraCapture) -> mi.Color3f:
        """L_scat per camera sample of ``cap`` (hook)."""
        raise NotImplementedError

    def widen_samples(self, params: SceneParams, cap: CameraCapture, mask: mi.Bool,
                      moved=None) -> mi.Bool:
        """The camera samples to compute for a partial render of ``mask``
        (hook): the smallest superset the method computes exactly as in a
        full render, plus -- given the boxes ``moved`` of what moved -- the
        samples whose shared inputs those boxes can change.  Default: every
        sample as soon as one is masked (a method that chooses anything from
        the whole frame); an empty mask computes nothing.  Per-sample
        methods return ``mask`` itself."""
        return dr.full(mi.Bool, dr.any(mask)[0] if dr.width(mask) else False, dr.width(mask))

    def partial_scattering(self, params: SceneParams, cap: CameraCapture, mask: mi.Bool,
                           moved=None):
        """``(L_scat, computed)`` of a partial render of ``mask`` on the full
        capture ``cap`` (hook): ``computed`` = :meth:`widen_samples`, L_scat
        of those samples (0 elsewhere).  Default: the method's
        :meth:`scattering` on the subset capture of ``computed``."""
        with self.stage("widen") as keep:
            computed = self.widen_samples(params, cap, mask, moved)
            keep.append(computed)
        with self.stage("scattering") as keep:
            L_scat = masked_scattering(self.scattering, params, cap, computed)
            keep.append(L_scat)
        return L_scat, computed

    def samples_alone(self, params: SceneParams) -> bool:
        """Whether each camera sample's L_scat depends on its own ray alone,
        with nothing chosen from the whole frame (hook): a partial render
        then captures the masked samples alone.  Default: False."""
        return False

    def reuse_refusal(self) -> str | None:
        """Why an animation cannot keep this method's samples between frames
        (a sentence naming the fix), or None (hook; default None: a partial
        render equals the full render on its computed samples)."""
        return None

    # -- several lights: the sum over them ------------------------------------------
    def scattering_of_lights(self, params: SceneParams, cap: CameraCapture) -> mi.Color3f:
        """L_scat of every camera sample: the sum over the lights of the
        method's :meth:`scattering` (single scattering is linear in the
        light; each light has its own epipolar geometry and visibility
        capture, the camera capture is shared).  With several lights the
        render hands on a :class:`LightStates`: each light's frame state,
        its L_scat on the full capture and its frame choices, so that a
        partial render of the next frame completes each light from its own
        last values."""
        lights = params.per_light()
        if len(lights) == 1:
            return self.scattering(params, cap)
        record, total, states = self.render_record, None, []
        for one in lights:
            record.frame_state = None
            record.stats.pop("frame_choices", None)
            L = self.scattering(one, cap)
            states.append(LightState(record.frame_state, L if cap.parent is None else None,
                                     record.stats.pop("frame_choices", None)))
            total = L if total is None else total + L
        # each light's L_scat is written by the kernel that sums them (kept
        # for the next frame's partial render, not computed again then)
        dr.schedule(*(x.L_scat for x in states if x.L_scat is not None))
        self._hand_on(record, states)
        return total

    def partial_scattering_of_lights(self, params: SceneParams, cap: CameraCapture,
                                     mask: mi.Bool, moved=None):
        """:meth:`partial_scattering` summed over the lights.  Each light
        computes its own widening of ``mask``; where it computes nothing, its
        value is the last frame's (``RenderRecord.given``, a
        :class:`LightStates`): those samples are outside the mask, so no
        moved object's shadow volume from any light meets them, and outside
        every row the light recomputes.  Without such a state (or with a
        different count of lights) every sample is computed."""
        lights = params.per_light()
        if len(lights) == 1:
            return self.partial_scattering(params, cap, mask, moved)
        record = self.render_record
        given = record.given
        if not (isinstance(given, LightStates) and len(given) == len(lights)
                and all(g.L_scat is not None and dr.width(g.L_scat) == cap.count
                        for g in given)):
            with self.stage("scattering") as keep:
                L_scat = self.scattering_of_lights(params, cap)
                keep.append(L_scat)
            return L_scat, dr.full(mi.Bool, True, cap.count)
        total, union, states = None, None, []
        try:
            for one, last in zip(lights, given):
                record.given, record.frame_state = last.frame_state, None
                record.stats.pop("frame_choices", None)
                L, computed = self.partial_scattering(one, cap, mask, moved)
                L = dr.select(computed, L, last.L_scat)
                states.append(LightState(record.frame_state, L,
                                         record.stats.pop("frame_choices", last.choices)))
                total = L if total is None else total + L
                union = computed if union is None else union | computed
        finally:
            record.given = given
        dr.schedule(*(x.L_scat for x in states))
        self._hand_on(record, states)
        return dr.select(union, total, 0.0), union

    def _hand_on(self, record: RenderRecord, states: list) -> None:
        """A several-light render's frame state and frame choices (per light)."""
        record.frame_state = LightStates(states)
        record.stats["frame_choices"] = tuple(x.choices for x in states)
        record.stats["lights"] = len(states)

    # -- per-render record and timing --------------------------------------------
    @property
    def render_record(self) -> RenderRecord:
        """The record of the render in progress (seed, timings, stats); a
        method's stages called on their own, outside any render (tests,
        experiments), write into a detached record with seed 0 that nobody
        reads (open :meth:`recording` to keep it)."""
        try:
            return _RECORD.get()
        except LookupError:
            return RenderRecord()

    def record(self, **stats) -> None:
        """Add named values to the running render's ``RenderResult.stats``."""
        self.render_record.stats.update(stats)

    @contextmanager
    def stage(self, name):
        """Time a block; results appended to the yielded list are evaluated
        (and waited for) before the clock stops.  With ``report_launches``
        the render's ``stats["launches"]`` counts the JIT kernels each stage
        launched (a nested stage's own are its own)."""
        record = self.render_record
        counting = record.launches is not None
        if counting:
            count_launches(record, record.stage)
        outer, record.stage = record.stage, name
        t0 = time.perf_counter()
        out = []
        try:
            yield out
            dr.eval(*out) if out else None
            dr.sync_thread()
        finally:
            if counting:
                count_launches(record, name)
            record.stage = outer
        timings = record.timings
        timings[name] = timings.get(name, 0.0) + time.perf_counter() - t0

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
        count = int(sensor_of(scene, sensor).sampler().sample_count())
        if count < 1:
            raise ValueError(
                f"The sensor's sampler has sample_count = {count}: give it at least 1 "
                "(<integer name=\"sample_count\" .../>, -D spp=1 for the suite's scenes), "
                "or pass spp to mi.render / the integrator's samples_per_pixel.")
        return count

    def jitters(self, spp: int) -> bool:
        """Whether camera samples are jittered inside the pixel at ``spp``
        samples per pixel (else: at the pixel centre, for spp = 1)."""
        return bool(self.jitter_pixels if self.jitter_pixels is not None else spp > 1)

    def aov_names(self):
        """The layers besides the output, developed into the film as AOVs."""
        return [f"{layer}.{c}" for layer in LAYERS if layer != self.output
                for c in layer_channels(layer)]

    @property
    def explicit_properties(self) -> dict:
        """The properties as given, without ``quality``/``error_budget``."""
        return dict(self._explicit)

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
    def render_layers(self, scene, sensor=0, seed=0, spp=0, samples=None,
                      moved=None, known=None, frame_state=None) -> RenderResult:
        """Every layer of one render (see the module doc; ``samples``: an
        optional boolean mask over the camera samples, mi.Bool or NumPy;
        ``moved``: boxes of what moved, for a partial render; ``known``: a
        full capture whose samples outside ``samples`` are this frame's --
        an animation's last frame where nothing moved -- so that only the
        masked samples are captured); ``frame_state``: the
        ``RenderResult.frame_state`` of the render ``known`` continues (the
        method checks it still fits before it uses it)."""
        variant = check_variant()
        if self.quality == "auto":
            return quality_auto.render_auto(self, scene, sensor, scalar_seed(seed), spp,
                                            samples=samples, moved=moved, known=known,
                                            frame_state=frame_state)
        if known is not None and samples is None:
            raise ValueError("known: a capture to complete needs the samples= mask of the "
                             "samples to capture anew.")
        with self.recording(seed) as record:
            record.given = frame_state if samples is not None else None
            return self._render_layers(scene, sensor, record.seed, spp, samples, moved, known,
                                       record, variant)

    @contextmanager
    def recording(self, seed=0):
        """The record (seed, stage timings, stats) of one render, current
        while the block runs: :meth:`stage` and :meth:`record` write into it.
        ``render_layers`` opens one; callers that drive the stages
        themselves (a sequence's partial frames) open their own."""
        record = RenderRecord(seed=scalar_seed(seed))
        token = _RECORD.set(record)
        history = dr.flag(dr.JitFlag.KernelHistory)
        if self.report_launches:
            if history:
                warnings.warn("report_launches takes over Dr.Jit's kernel history for the "
                              "render: the kernels before it and in it leave the caller's "
                              "history; read stats['launches'] instead, or turn "
                              "report_launches off.", stacklevel=4)
            record.launches = {}
            dr.set_flag(dr.JitFlag.KernelHistory, True)
            dr.kernel_history()                 # what came before is not this render's
        expand = dr.expand_threshold()
        # LLVM's expanded scatter-reductions write the target's size into
        # the kernel, so a new frame's row or light-ray count would be a new
        # kernel: reduce with local atomics instead (design: new frames)
        dr.set_expand_threshold(SCATTER_EXPAND_THRESHOLD)
        try:
            yield record
        except BaseException:
            # what the failed render left scheduled (or scattered) is
            # evaluated now: joined to the next render's first kernel it
            # would make that kernel one the next frame compiles again
            try:
                dr.eval()
            except Exception:
                pass
            raise
        finally:
            dr.set_expand_threshold(expand)
            dr.set_flag(dr.JitFlag.KernelHistory, history)
            _RECORD.reset(token)

    def _render_layers(self, scene, sensor, seed, spp, samples, moved, known, record, variant):
        t_start = time.perf_counter()
        with self.stage("validate"):
            params = SceneParams.from_scene(scene, sensor)
        spp = self.sample_count(scene, sensor, spp)
        jitter = self.jitters(spp)
        mask = None
        if samples is not None:
            cam = params.camera
            mask = sample_mask(samples, cam.width * cam.height * spp)
        alone = mask is not None and all(self.samples_alone(one) for one in params.per_light())
        with self.stage("capture") as keep:
            index = dr.compress(mask) if alone or known is not None else None
            cap = (empty_capture(params, spp) if index is not None and not dr.width(index) else
                   capture_camera(params, spp=spp, jitter=bool(jitter), seed=int(seed),
                                  surface=self.output == "full", samples=index))
            if known is not None and not alone:
                cap = merge_capture(known, cap)
            keep.append(cap.d)
        computed = None
        if mask is None or alone:
            with self.stage("scattering") as keep:
                L_scat = (self.scattering_of_lights(params, cap) if cap.count
                          else dr.zeros(mi.Color3f, 0))
                keep.append(L_scat)
            computed = mask
        else:
            L_scat, computed = self.partial_scattering_of_lights(params, cap, mask, moved)
        with self.stage("compose") as keep:
            layers = compose_layers(cap, L_scat, spp, "mono" in variant,
                                    None if alone else computed)
            keep.extend(layers.values())
        record.timings["total"] = time.perf_counter() - t_start
        if record.launches is not None:
            count_launches(record, "other")
            record.stats["launches"] = dict(record.launches)
            record.stats["kernel_ms"] = dict(record.kernel_ms)
        return RenderResult(layers=layers, timings=dict(record.timings),
                            stats=dict(record.stats), samples=computed, capture=cap,
                            L_scat=L_scat, frame_state=record.frame_state)

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if not develop:
            raise ValueError(f"{type(self).__name__} only supports develop=True.")
        layers = self.render_layers(scene, sensor, seed, spp)
        develop_into_film(sensor_of(scene, sensor).film(), layers, self.output,
                          self.aov_names())
        # the film's storage written now, in this frame (left pending, the
        # write would wait for, and join, the next frame's first kernel)
        dr.eval()
        return layers[self.output]

    def to_string(self):
        return f"{type(self).__name__}[output={self.output}]"
