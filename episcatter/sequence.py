"""Rendering animations with temporal reuse (Lin et al.; DESIGN §3
"Animations").

A :class:`Sequence` owns the frame state (the integrator stays stateless):
the previous frame's moving-object boxes, camera capture, L_scat per sample,
camera/light/medium parameters and the method's frame-wide choices.  For
each frame it

1. poses the moving shapes (:class:`episcatter.motion.ShapeAnimator`);
2. reads the scene (camera, light, medium);
3. computes the change mask before any capture or scattering work
   (:func:`integrators.partial.change_mask.change_mask`, on the last frame's
   capture): the samples whose segment meets a moving object's bounded
   shadow volume in the previous or the current frame; every sample when
   the camera, light or medium changed
   (:func:`integrators.partial.change_mask.whole_frame_changes`) or on the first
   frame;
4. asks the integrator for those samples through the render template's
   partial render (``render_layers(samples=mask, moved=boxes)``: the method
   widens the mask to what it computes together -- per sample for
   ``raymarch``, per slice for ``epipolar_tree`` and ``minmax_epipolar``,
   per row for ``fourier_filter`` -- and to the samples whose
   shared blockers meet the moved boxes; only the dirty samples are
   captured anew, ``known=`` the last capture) and keeps the previous
   frame's values (G-buffer and L_scat) for the others
   (:func:`merge_frame`); there is no periodic refresh;
5. checks that the frame-wide choices the method recorded (light-ray
   count, the kernel's SVD inputs, minmax's light top and constant light
   colour: ``stats["frame_choices"]``) are the
   previous frame's: else the kept samples were computed with other
   choices and the frame is rendered again in full;
6. composes the layers as the render template does.

A reused frame equals a full render of that frame to float rounding (the
tests check it for every integrator, motion and light kind).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from integrators.core.film import compose_layers
from integrators.core.scene_params import SceneParams
from integrators.core.shadow_volumes import Boxes, TriangleGroups, mesh_arrays, shape_boxes
from integrators.partial.change_mask import (change_mask_of_lights, frame_invariants,
                                             whole_frame_changes)
from integrators.partial.samples import merge_capture

from .motion import ShapeAnimator


#: the render template's own stages (the others are the method's, inside ``scattering``)
TEMPLATE_STAGES = ("validate", "capture", "widen", "scattering", "compose")


@dataclass
class FrameResult:
    """One frame: its layers (NumPy (H, W, C)), how many camera samples were
    recomputed of how many, why the whole frame was (``whole_frame``: e.g.
    ``["camera"]``; all three on the first frame) and the stage times (s)."""
    index: int
    layers: dict
    recomputed: int
    samples: int
    whole_frame: list
    timings: dict
    mask: np.ndarray | None = field(default=None, repr=False)

    @property
    def recomputed_fraction(self) -> float:
        return self.recomputed / self.samples


@dataclass(frozen=True)
class FrameState:
    """What the next frame reuses: the moving boxes, the full capture and
    L_scat per sample, the camera/light/medium parameters, the method's
    frame-wide choices and its ``RenderResult.frame_state`` (the epipolar
    methods' rectification)."""
    boxes: list
    cap: object
    L_scat: object
    invariants: dict
    choices: object
    method_state: object = None


def merge_frame(previous: FrameState, result):
    """``(cap, L_scat)`` of a partial render ``result`` (a
    :class:`~integrators.template.base.RenderResult`) completed with the previous
    frame's values on the samples it did not compute: a subset capture's
    samples (``capture.sample``) are scattered into the previous capture
    (:func:`~integrators.partial.samples.merge_capture`); a full capture is this
    frame's and takes the previous L_scat outside ``result.samples``."""
    part, values = result.capture, result.L_scat
    if result.samples is None:
        return part, values
    if part.sample is None:
        return part, dr.select(result.samples, values, previous.L_scat)
    L_scat = type(previous.L_scat)(previous.L_scat)
    if dr.width(part.sample):
        dr.scatter(L_scat, values, part.sample)
    return merge_capture(previous.cap, part), L_scat


class Sequence:
    """An animation of ``scene`` rendered with ``integrator`` (one of ours).

    ``motions``: :class:`episcatter.motion.Motion` / ``Deform`` objects or
    parsed ``--move`` specs; ``frames``: the frame count (sets the motion
    phase); ``reuse``: recompute dirty samples only (False: every frame in
    full, the baseline); ``volume_boxes``: boxes per moving mesh bounding its
    shadow volume (more: a tighter mask); ``keep_mask``: store each frame's
    recomputed samples (NumPy) in its result."""

    def __init__(self, scene, integrator, motions, frames: int, reuse: bool = True,
                 spp: int = 0, seed: int = 0, volume_boxes: int = 8, keep_mask: bool = False):
        if frames < 1:
            raise ValueError(f"frames = {frames}: render at least one frame.")
        if reuse:
            why = integrator.reuse_refusal()
            if why:
                raise ValueError(why)
        self.scene, self.integrator, self.frames = scene, integrator, int(frames)
        self.animator = ShapeAnimator(scene, motions)
        self.reuse, self.seed, self.volume_boxes = reuse, int(seed), int(volume_boxes)
        self.spp = integrator.sample_count(scene, 0, spp)
        self.keep_mask = keep_mask
        # triangle clusters of each moving mesh, grouped once at its rest pose
        self.groups = {}
        for shape in self.animator.moving_shapes:
            mesh = mesh_arrays(shape) if self.volume_boxes > 1 else None
            if mesh is not None:
                self.groups[shape.id()] = TriangleGroups.of(mesh[0], mesh[1], self.volume_boxes)
        self._state: FrameState | None = None

    def moving_boxes(self) -> list:
        """Boxes per moving shape (:class:`integrators.core.shadow_volumes.Boxes`)."""
        return [shape_boxes(s, self.volume_boxes, self.groups.get(s.id()))
                for s in self.animator.moving_shapes]

    def render_frame(self, k: int) -> FrameResult:
        """Pose, mask, compute and compose frame ``k`` (frames are expected
        in order; any order is still exact, only the reuse shrinks)."""
        integ = self.integrator
        timings: dict[str, float] = {}

        def timed(name, fn):
            t0 = time.perf_counter()
            out = fn()
            dr.sync_thread()
            timings[name] = timings.get(name, 0.0) + time.perf_counter() - t0
            return out

        t_start = time.perf_counter()
        timed("motion", lambda: self.animator.apply(k, self.frames))
        params = timed("invariants", lambda: SceneParams.from_scene(self.scene))
        invariants = frame_invariants(params)
        boxes = self.moving_boxes()
        previous = self._state
        whole = whole_frame_changes(previous.invariants if previous else None, invariants)
        if not self.reuse:
            whole = whole or ["no reuse"]
        mask = None
        if previous is not None and not whole:
            def make_mask():
                m = change_mask_of_lights(previous.cap, previous.boxes + boxes, params)
                dr.eval(m)
                return m
            mask = timed("mask", make_mask)

        def render(samples):
            partial = samples is not None
            result = integ.render_layers(self.scene, seed=self.seed, spp=self.spp,
                                         samples=samples,
                                         moved=Boxes.concat(previous.boxes + boxes)
                                         if partial else None,
                                         known=previous.cap if partial else None,
                                         frame_state=previous.method_state if partial else None)
            for name, value in result.timings.items():
                if name != "total":
                    key = name if name in TEMPLATE_STAGES else f"scattering.{name}"
                    timings[key] = timings.get(key, 0.0) + value
            return result

        result = render(mask)
        # a partial render that computed no row records no choices: nothing
        # it depends on changed, so the previous frame's stand
        choices = result.stats.get("frame_choices",
                                   previous.choices if mask is not None else None)
        if mask is not None and choices != previous.choices:
            whole, mask = ["frame choices"], None          # kept samples are stale
            result = render(None)
        cap, L_scat = timed("merge", lambda: self._merge(previous, result))
        n = dr.width(cap.d)
        computed = None if mask is None else result.samples
        computed_np = None if computed is None else np.array(computed, dtype=bool)
        recomputed = n if computed is None else int(np.count_nonzero(computed_np))

        def compose():
            layers = compose_layers(cap, L_scat, self.spp, "mono" in mi.variant())
            dr.eval(*layers.values())
            return layers
        layers = timed("compose_frame", compose)
        timings["total"] = time.perf_counter() - t_start
        self._state = FrameState(boxes, cap, L_scat, invariants, choices, result.frame_state)
        return FrameResult(index=k, layers={key: np.array(v) for key, v in layers.items()},
                           recomputed=recomputed, samples=n, whole_frame=whole, timings=timings,
                           mask=(np.ones(n, bool) if computed_np is None else computed_np)
                           if self.keep_mask else None)

    @staticmethod
    def _merge(previous, result):
        if previous is None or result.samples is None:
            return result.capture, result.L_scat
        cap, L_scat = merge_frame(previous, result)
        dr.eval(cap.d, cap.T_cam, cap.L_surface, cap.hit, L_scat)
        return cap, L_scat

    def __iter__(self):
        for k in range(self.frames):
            yield self.render_frame(k)
