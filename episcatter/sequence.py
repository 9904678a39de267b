"""Rendering animations with temporal reuse (Lin et al.; DESIGN §3
"Animations").

A :class:`Sequence` owns the frame state (the integrator stays stateless):
the previous frame's moving-object boxes, camera capture, L_scat per sample
and camera/light/medium parameters.  For each frame it

1. poses the moving shapes (:class:`episcatter.motion.ShapeAnimator`);
2. reads the scene (camera, light, medium);
3. computes the change mask before any capture or scattering work
   (:func:`integrators.change_mask.change_mask`, on the last frame's
   capture): the samples whose segment meets a moving object's bounded
   shadow volume in the previous or the current frame; every sample when
   the camera, light or medium changed
   (:func:`integrators.change_mask.whole_frame_changes`) or on the first
   frame;
4. captures and computes the dirty samples alone
   (:func:`integrators.sample_reuse.render_samples`) and keeps the rest
   (G-buffer and L_scat); there is no periodic refresh;
5. composes the layers as the render template does.

A reused frame equals a full render of that frame to float rounding (the
tests check it for every motion and light kind).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr
import numpy as np

from integrators.capture import capture_camera
from integrators.change_mask import (ShadowVolumes, TriangleGroups, change_mask,
                                     frame_invariants, mesh_arrays, shape_boxes,
                                     whole_frame_changes)
from integrators.sample_reuse import render_samples, reuse_blocker
from integrators.scene_params import SceneParams
from integrators.template import compose_layers

from .motion import ShapeAnimator


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


class Sequence:
    """An animation of ``scene`` rendered with ``integrator`` (one of ours).

    ``motions``: :class:`episcatter.motion.Motion` / ``Deform`` objects or
    parsed ``--move`` specs; ``frames``: the frame count (sets the motion
    phase); ``reuse``: recompute dirty samples only (False: every frame in
    full, the baseline); ``volume_boxes``: boxes per moving mesh bounding its
    shadow volume (more: a tighter mask); ``keep_mask``: store each frame's
    mask (NumPy) in its result."""

    def __init__(self, scene, integrator, motions, frames: int, reuse: bool = True,
                 spp: int = 0, seed: int = 0, volume_boxes: int = 8, keep_mask: bool = False):
        if frames < 1:
            raise ValueError(f"frames = {frames}: render at least one frame.")
        if reuse:
            why = reuse_blocker(integrator)
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
        self._state = None   # (boxes, d, L_scat, invariants) of the last frame

    def moving_boxes(self) -> list:
        """Boxes per moving shape (:class:`integrators.change_mask.Boxes`)."""
        return [shape_boxes(s, self.volume_boxes, self.groups.get(s.id()))
                for s in self.animator.moving_shapes]

    def render_frame(self, k: int) -> FrameResult:
        """Pose, mask, compute and compose frame ``k`` (frames are expected
        in order; any order is still exact, only the reuse shrinks)."""
        with self.integrator.recording(self.seed) as record:
            return self._render_frame(k, record)

    def _render_frame(self, k: int, record) -> FrameResult:
        integ = self.integrator
        timings: dict[str, float] = {}

        def timed(name, fn):
            t0 = time.perf_counter()
            out = fn()
            dr.sync_thread()
            timings[name] = time.perf_counter() - t0
            return out

        t_start = time.perf_counter()
        timed("motion", lambda: self.animator.apply(k, self.frames))
        params = timed("validate", lambda: SceneParams.from_scene(self.scene))
        jitter = integ.jitters(self.spp)

        def capture(samples):
            return timed("capture", lambda: capture_camera(
                params, spp=self.spp, jitter=jitter, seed=self.seed,
                surface=integ.output == "full", samples=samples))

        invariants = frame_invariants(params)
        boxes = self.moving_boxes()
        previous = self._state
        whole = whole_frame_changes(previous[3] if previous else None, invariants)
        if not self.reuse:
            whole = whole or ["no reuse"]
        mask = None
        if previous is not None and not whole:
            def make_mask():
                m = change_mask(previous[1], ShadowVolumes.from_sets(previous[0] + boxes, params))
                dr.eval(m)
                return m
            mask = timed("mask", make_mask)

        def compute():
            out = render_samples(integ, params, capture, mask,
                                 previous[1:3] if previous else None)
            dr.eval(out[1], out[0].d, out[0].T_cam, out[0].L_surface)
            return out
        cap, L_scat = timed("scattering", compute)
        timings["scattering"] -= timings.get("capture", 0.0)
        n = dr.width(cap.d)
        mask_np = None if mask is None else np.array(mask)
        recomputed = n if mask is None else int(np.count_nonzero(mask_np))

        def compose():
            layers = compose_layers(cap, L_scat, self.spp)
            dr.eval(*layers.values())
            return layers
        layers = timed("compose", compose)
        timings.update({f"scattering.{k2}": v for k2, v in record.timings.items()
                        if k2 != "scattering"})
        timings["total"] = time.perf_counter() - t_start
        self._state = (boxes, cap, L_scat, invariants)
        return FrameResult(index=k, layers={key: np.array(v) for key, v in layers.items()},
                           recomputed=recomputed, samples=n, whole_frame=whole, timings=timings,
                           mask=(np.ones(n, bool) if mask is None else mask_np)
                           if self.keep_mask else None)

    def __iter__(self):
        for k in range(self.frames):
            yield self.render_frame(k)
