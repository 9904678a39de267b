"""Per-slice partial renders of ``minmax_epipolar``: temporal reuse (Lin et
al.) at the granularity of Yusov's epipolar slices.

Every camera ray of a slice's samples and every light ray of its 1-D
height map lie in the slice's half-plane (the camera–light axis and the
direction α around it).  So a slice's samples, their traced depths, its
integration samples (the ``depth`` criterion compares neighbours of one
slice), its height map, min/max tree and interpolated values depend on
that slice alone -- given three frame-wide choices: the settings and the
sample layout (camera and light), the light top ``u_top`` of directional
depths (the scene's bounding box, :func:`~integrators.minmax.light_rays.light_top`)
and the light colour when it is constant over every texel of the frame
(:func:`~integrators.minmax.minmax_tree.constant_colour`).  A pixel's value
depends on the two slices around it (the unwarp) and on its own ray (its
depth; the fix-up march).

A partial render handed the last frame's :class:`SliceState` therefore

1. re-traces only the slices whose half-plane meets a moved box
   (:func:`~integrators.partial.row_subset.moved_slices`, the machinery
   ``epipolar_tree`` uses) and recomputes their values; the others keep
   the last frame's;
2. takes the frame's constant colour from every slice's texel colour
   bounds (the recomputed slices' and the kept ones', :func:`merged_bounds`);
3. unwarps (and fixes up) only the pixels of the mask and those whose two
   slices include a recomputed one (:func:`computed_pixels`).

The ``u_top`` and the constant colour are recorded as the render's
``stats["frame_choices"]``: the sequence renders a frame whose choices
differ from the last frame's in full.  Other refinement criteria
(``inscattering``, ``visibility``: thresholds floored at the frame's mean)
and resampled blockers (a shadow map fitted to the whole frame) compute
the whole frame.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import uints
from ..partial.row_subset import moved_slices, put_rows, same_slices
from .slices_and_samples import EpipolarSamples, SampleLayout
from .unwarp import pixel_slices


@dataclass(frozen=True, eq=False)
class SliceState:
    """What a later frame's partial render reuses: the settings, the traced
    samples of every slice, their interpolated values and every slice's
    texel colour bounds (:func:`~integrators.minmax.minmax_tree.colour_bounds`)."""
    settings: dict
    samples: EpipolarSamples
    values: mi.Color3f = field(repr=False)
    colour_lo: mi.Color3f = field(repr=False)
    colour_hi: mi.Color3f = field(repr=False)

    def fits(self, settings: dict, layout: SampleLayout) -> bool:
        """Whether the state's slices are those of ``layout`` (same settings,
        camera, light axis, slices and β grids)."""
        a, b = self.samples, layout
        return (self.settings == settings
                and np.array_equal(np.asarray(a.frame.axis), np.asarray(b.frame.axis))
                and np.array_equal(np.asarray(a.frame.camera.origin),
                                   np.asarray(b.frame.camera.origin))
                and same_slices(a.slices, b.slices)
                and np.array_equal(a.grid.start, b.grid.start)
                and np.array_equal(a.grid.step, b.grid.step)
                and np.array_equal(a.on_screen_count, b.on_screen))


def dirty_slices(layout: SampleLayout, moved) -> np.ndarray:
    """Sorted indices of the slices whose half-plane meets a box of
    ``moved`` (their samples or light rays can meet what moved)."""
    return np.flatnonzero(moved_slices(layout.frame, layout.slices.alpha, moved))


def computed_pixels(samples: EpipolarSamples, mask: mi.Bool, rows: np.ndarray) -> mi.Bool:
    """The pixels a partial render recomputes: ``mask`` and every pixel
    between two slices of which one is in ``rows``."""
    dirty = np.zeros(samples.slices.count, bool)
    dirty[rows] = True
    dirty = mi.Bool(dirty)
    _, k0, k1, _ = pixel_slices(samples)
    out = mask | dr.gather(mi.Bool, dirty, k0) | dr.gather(mi.Bool, dirty, k1)
    dr.eval(out)
    return out


def merged_samples(state: SliceState, part: EpipolarSamples, rows: np.ndarray,
                   frame) -> EpipolarSamples:
    """The whole frame's samples: the state's, with the depths of ``rows``
    from ``part`` (their samples traced anew; nothing else of a sample
    depends on the scene's geometry)."""
    full = state.samples
    d = put_rows(full.d, part.d, uints(rows), full.count)
    dr.eval(d)
    return replace(full, frame=frame, d=d)


def merged_rows(state_values, part_values, rows: np.ndarray, per: int):
    """``state_values`` (``per`` entries per slice) with ``rows`` replaced."""
    out = put_rows(state_values, part_values, uints(rows), per)
    dr.eval(out)
    return out


def merged_bounds(state: SliceState, lo, hi, rows: np.ndarray):
    """Every slice's texel colour bounds: the state's, ``rows``' from ``lo``, ``hi``."""
    return merged_rows(state.colour_lo, lo, rows, 1), merged_rows(state.colour_hi, hi, rows, 1)
