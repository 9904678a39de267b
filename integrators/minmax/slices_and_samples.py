"""Epipolar slices and the samples along them (Yusov 2013, "Epipolar
Sampling: Sample generation" and "improved sample placement").

* Slices: exit points on the image border joined to the epipole (or, when it
  is off screen, to the border crossing nearest to it; behind the camera the
  lines converge on the anti-epipole, "in exactly the same way").  ``slices``
  a number: about that many exit points equally spaced along the exit edges
  (the talk); ``auto``: Baran's sinh placement, every pixel centre within
  half a pixel of a slice (:func:`integrators.epipolar.frame.choose_slices`).
* Samples: ``samples`` per slice between the entry and the exit point of the
  slice's on-screen segment, the border shrunk by half a pixel (so the end
  samples sit on pixel centres), placed uniformly in the angle ``β`` from the
  camera–light axis (:mod:`rectify.grid`).  Rescaled exit points: a slice
  shorter than ``samples − 1`` pixels gets samples one pixel apart and the
  rest of its row runs past the exit, off screen, and is never integrated
  (the talk's "1:1 correspondence between samples on the line and screen
  pixels").
* Each sample is a camera ray traced with Mitsuba (``sensor.sample_ray`` at
  its film position, first non-null surface or the medium exit): its depth
  is exact, not read from a depth buffer.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify import (BetaGrid, EpipolarFrame, Slices, grid_directions, per_slice_beta_grid,
                     project_direction, slice_segments)

from ..core.capture import first_surface
from ..core.light_transport import medium_exit_distance
from ..core.opaque import floats, point, scalar, uints
from ..epipolar.frame import choose_slices, epipolar_frame_of


#: half a pixel: the border the end samples sit on (pixel centres)
BORDER_SHRINK_PX = 0.5
#: samples past the last on-screen one that the unwarp may still read
EXTRA_SAMPLES = 2


@dataclass(frozen=True, eq=False)
class EpipolarSamples:
    """``S`` slices × ``M`` samples, flat row-major (index ``k·M + j``)."""
    frame: EpipolarFrame
    slices: Slices
    grid: BetaGrid
    used: mi.Bool = field(repr=False)      # on screen (or just past the exit)
    slice: mi.UInt32 = field(repr=False)   # k of every sample
    beta: mi.Float = field(repr=False)     # angle from the camera–light axis
    o: mi.Point3f = field(repr=False)      # Mitsuba's ray origin (near plane)
    omega: mi.Vector3f = field(repr=False)
    t_near: mi.Float = field(repr=False)   # pinhole -> ray origin distance
    d: mi.Float = field(repr=False)        # in-medium distance along the ray
    rho: mi.Float = field(repr=False, default=None)   # pixel distance to the epipole
    on_screen_count: np.ndarray = field(repr=False, default=None)  # (S,) used samples per slice

    @property
    def count(self) -> int:
        return self.grid.count

    @property
    def size(self) -> int:
        return self.slices.count * self.grid.count


def make_epipolar_slices(frame: EpipolarFrame, slices) -> Slices:
    """``slices`` = ``'auto'`` (sinh, half-pixel bound) or a count."""
    return choose_slices(frame, 0 if slices == "auto" else int(slices))


def rescaled_grid(frame: EpipolarFrame, slices: Slices, samples: int, density: float = 1.0):
    """Per-slice β grid of ``samples`` samples, spaced at least about
    ``1/density`` pixel apart (short slices run past their exit; the talk:
    density 1).  Returns the grid and how many samples of each row are on
    screen (plus EXTRA_SAMPLES)."""
    grid = per_slice_beta_grid(frame, slices, count=samples, margin_px=-BORDER_SHRINK_PX)
    entry, exit_ = slice_segments(frame, slices)
    length = np.maximum(np.linalg.norm(exit_ - entry, axis=1) - 2 * BORDER_SHRINK_PX, 1.0)
    stretch = np.maximum((samples - 1) / (density * length), 1.0)
    step = grid.step * stretch
    used = np.minimum(np.ceil((samples - 1) / stretch - 1e-9).astype(np.int64) + 1 + EXTRA_SAMPLES,
                      samples)
    return BetaGrid(start=grid.start, step=step, count=grid.count), used


def trace_samples(params, frame: EpipolarFrame, slices: Slices, grid: BetaGrid,
                  on_screen: np.ndarray) -> EpipolarSamples:
    """Camera ray and depth of every used sample (unused ones: zeros)."""
    S, M = slices.count, grid.count
    idx = dr.arange(mi.UInt32, S * M)
    k = idx // M
    j = idx - k * M
    used = j < dr.gather(mi.UInt32, uints(on_screen), k)
    beta = dr.fma(mi.Float(j), dr.gather(mi.Float, floats(grid.step), k),
                  dr.gather(mi.Float, floats(grid.start), k))
    w = grid_directions(frame, slices, grid)
    x, y, z = project_direction(frame, w)
    used &= z > 0
    cam = params.camera
    # trace the used samples alone (short slices leave much of their row unused)
    dr.eval(x, y, used)
    live = dr.compress(used)
    o, omega = dr.zeros(mi.Point3f, S * M), dr.zeros(mi.Vector3f, S * M)
    d, t_near = dr.zeros(mi.Float, S * M), dr.zeros(mi.Float, S * M)
    if dr.width(live):
        pos = mi.Point2f(dr.gather(mi.Float, x, live) / cam.width,
                         dr.gather(mi.Float, y, live) / cam.height)
        ray, _ = params.sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        ray.d = dr.normalize(ray.d)
        _, t_surf = first_surface(params.scene, ray)
        t_exit = medium_exit_distance(params, ray.o, ray.d)
        dr.scatter(o, ray.o, live)
        dr.scatter(omega, ray.d, live)
        dr.scatter(d, dr.minimum(t_surf, t_exit), live)
        dr.scatter(t_near, dr.norm(ray.o - point(cam.origin)), live)
    ex, ey = (scalar(v) for v in frame.epipole)
    rho = dr.select(used, dr.sqrt(dr.square(x - ex) + dr.square(y - ey)), dr.inf)
    out = EpipolarSamples(frame=frame, slices=slices, grid=grid, used=used, slice=k, beta=beta,
                          o=o, omega=omega, t_near=t_near, d=d, rho=rho,
                          on_screen_count=on_screen)
    dr.eval(out.used, out.beta, out.o, out.omega, out.t_near, out.d, out.rho)
    return out


@dataclass(frozen=True, eq=False)
class SampleLayout:
    """Where the samples of a frame lie before any is traced: the frame, the
    slices, the β grid and the used samples per slice (camera and light
    alone)."""
    frame: EpipolarFrame
    slices: Slices
    grid: BetaGrid
    on_screen: np.ndarray

    def rows(self, rows: np.ndarray) -> "SampleLayout":
        """The layout of the slices ``rows`` (sorted indices) alone, each
        with its own α, β grid and used samples: traced, they are those
        slices' samples of the whole frame."""
        sl = self.slices
        return SampleLayout(self.frame, Slices(sl.alpha[rows], sl.points[rows], False, "custom"),
                            BetaGrid(self.grid.start[rows], self.grid.step[rows],
                                     self.grid.count), self.on_screen[rows])


def sample_layout(params, slices="auto", samples: int = 256,
                  density: float = 1.0) -> SampleLayout:
    """Frame, slices and rescaled β grid of a frame (stage 1 before tracing)."""
    if samples < 2:
        raise ValueError(f"Property 'samples' = {samples} must be >= 2.")
    frame = epipolar_frame_of(params)
    sl = make_epipolar_slices(frame, slices)
    grid, on_screen = rescaled_grid(frame, sl, samples, density)
    return SampleLayout(frame, sl, grid, on_screen)


def trace_layout(params, layout: SampleLayout) -> EpipolarSamples:
    """The traced samples of ``layout`` (:func:`trace_samples`)."""
    return trace_samples(params, layout.frame, layout.slices, layout.grid, layout.on_screen)


def epipolar_samples(params, slices="auto", samples: int = 256,
                     density: float = 1.0) -> EpipolarSamples:
    """Stage 1 of the pipeline: frame, slices, rescaled samples, traced depths."""
    return trace_layout(params, sample_layout(params, slices, samples, density))
