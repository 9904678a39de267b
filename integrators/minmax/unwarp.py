"""Stage "to camera": bilateral unwarp and the fix-up pass (Yusov 2013,
"Transformation from epipolar to rectangular coordinates", "Fix-up pass").

Every pixel centre lies between two slices; on each it reads the two
samples around its own ``β``; the four bilinear weights are multiplied by a
depth weight ``exp(−½ ((d_i − d)/(σ d))²)`` of the sample's depth ``d_i``
against the pixel's ``d`` and renormalised (:func:`unwarp`, one lane per
pixel reading colours; :func:`rectify.unrectify_bilateral_reference` is the
direct formula it is tested against).  ``σ`` defaults to the default
relative depth-break threshold of the refinement (:data:`DEPTH_SIGMA`): a
break the refinement sees as two surfaces is one the weights tell apart (a
tap across a break of four thresholds weighs e^{−8}); a wider ``σ`` blends
the far side of small relative breaks (a pillar's edge before a wall 12 %
deeper) into the near pixels Pixels whose weight sum falls below ``fixup_threshold`` have no
sample at their depth (a foreground edge between slices, a thin object):
the fix-up pass ray-marches them on their own (talk: "using fewer steps and
no min/max optimization"), with exact visibility for traced blockers and
the shadow map for resampled ones.  Beyond the talk, the pixels within
``ring_degrees`` of the epipole (Baran 2010 §6's ring, :func:`rectify.ring_mask`)
join the fix-up: there the in-scattering of a point light peaks within a
pixel and all slices meet, so no interpolation reproduces the pixel-centre
value.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from rectify import MIN_WEIGHT, alpha_to_slice, pixel_to_alpha_beta

from ..core.capture import CameraCapture
from ..core.marching import auto_spacing, march
from ..core.opaque import floats, two_or_more
from ..epipolar.ring import apart, peak_marched
from .slices_and_samples import EpipolarSamples


#: default relative depth scale of the bilateral weights (module docstring)
DEPTH_SIGMA = 0.03


@dataclass(frozen=True, eq=False)
class Unwarped:
    """Per pixel: the unwarped L_scat, the bilateral weight sum and the
    pixels the fix-up pass re-marched."""
    L: mi.Color3f = field(repr=False)
    weight: mi.Float = field(repr=False)
    fixup: mi.UInt32 = field(repr=False)

    @property
    def fixup_count(self) -> int:
        return dr.width(self.fixup)


def pixel_slices(samples: EpipolarSamples, pixels: mi.UInt32 | None = None):
    """``(β, k0, k1, f)`` of the pixel centres ``pixels`` (flat row-major;
    None: every pixel): the pixel's β and the two slices it lies between,
    ``f`` the weight of ``k1``.  A pixel's unwarped value reads these two
    slices alone."""
    frame = samples.frame
    W, H = frame.width, frame.height
    pix = dr.arange(mi.UInt32, W * H) if pixels is None else pixels
    y = pix // W
    alpha, beta = pixel_to_alpha_beta(frame, mi.Float(pix - y * W) + 0.5, mi.Float(y) + 0.5)
    k0, k1, f = alpha_to_slice(samples.slices, alpha)
    return beta, k0, k1, f


def unwarp(samples: EpipolarSamples, values: mi.Color3f, pixel_depth: mi.Float,
           depth_sigma: float = DEPTH_SIGMA, pixels: mi.UInt32 | None = None):
    """(L per pixel, weight sum per pixel) of the pixels ``pixels`` (flat
    row-major indices; None: every pixel, flat row-major): the bilateral
    weights of the module docstring, plain bilinear where the weight sum is
    below ``rectify.MIN_WEIGHT``.  ``pixel_depth``: per pixel of the image."""
    taps = unwarp_taps(samples, values, pixel_depth, depth_sigma, pixels)
    return taps.L, taps.weight


@dataclass(frozen=True, eq=False)
class UnwarpTaps:
    """Per pixel: the unwarped ``L`` and bilateral ``weight`` sum of
    :func:`unwarp`, and the darkest and brightest (channel sum) of the
    taps the blend counts (bilateral weight above ``TAP_SHARE`` of the
    sum; all four where the plain bilinear blend is used)."""
    L: mi.Color3f = field(repr=False)
    weight: mi.Float = field(repr=False)
    darkest: mi.Color3f = field(repr=False)
    brightest: mi.Color3f = field(repr=False)


#: a tap whose bilateral weight is at most this share of the pixel's sum
#: does not count as blended in (:class:`UnwarpTaps`)
TAP_SHARE = 1e-3


def unwarp_taps(samples: EpipolarSamples, values: mi.Color3f, pixel_depth: mi.Float,
                depth_sigma: float = DEPTH_SIGMA,
                pixels: mi.UInt32 | None = None) -> UnwarpTaps:
    """:func:`unwarp` with the extremes of the taps it blends."""
    grid, M = samples.grid, samples.count
    beta, k0, k1, f = pixel_slices(samples, pixels)
    if pixels is not None:
        pixel_depth = dr.gather(mi.Float, pixel_depth, pixels)
    start, step = floats(grid.start), floats(grid.step)
    inv = 1.0 / (depth_sigma * dr.maximum(dr.abs(pixel_depth), 1e-20))
    taps = []                                   # (flat sample index, bilinear weight)
    for k, w_k in ((k0, 1.0 - f), (k1, f)):
        # position of the pixel's β on slice k's row, clamped to the row
        u_row = (beta - dr.gather(mi.Float, start, k)) / dr.gather(mi.Float, step, k)
        u = dr.clip(u_row, 0.0, M - 1.0)
        j = dr.minimum(mi.UInt32(dr.floor(u)), M - 2)
        frac = u - mi.Float(j)
        # a tap counts where its sample was traced and lies within a sample
        # step of the pixel's β: a row clamped farther, or a sample past the
        # slice's on-screen samples, is no estimate of the pixel
        near = dr.abs(u_row - u) <= 1.0
        for i, w in ((k * M + j, w_k * (1.0 - frac)), (k * M + j + 1, w_k * frac)):
            taps.append((i, dr.select(near & dr.gather(mi.Bool, samples.used, i), w, 0.0)))
    colours = [dr.gather(mi.Color3f, values, i) for i, _ in taps]
    bilateral = [w * dr.exp(-0.5 * dr.square((dr.gather(mi.Float, samples.d, i) - pixel_depth)
                                             * inv)) for i, w in taps]
    den = sum(bilateral)
    num = sum(b * v for b, v in zip(bilateral, colours))
    plain_w = sum(w for _, w in taps)
    plain = sum(w * v for (_, w), v in zip(taps, colours)) / dr.maximum(plain_w, MIN_WEIGHT)
    ok = den >= MIN_WEIGHT
    L = dr.select(ok, num / dr.select(ok, den, 1.0), plain)
    # the extremes of the taps blended in
    lo_y, hi_y = mi.Float(dr.inf), mi.Float(-dr.inf)
    lo, hi = mi.Color3f(0.0), mi.Color3f(0.0)
    for (_, w), b, v in zip(taps, bilateral, colours):
        counts = dr.select(ok, b > TAP_SHARE * den, w > TAP_SHARE)
        y = v.x + v.y + v.z
        darker, brighter = counts & (y < lo_y), counts & (y > hi_y)
        lo, lo_y = dr.select(darker, v, lo), dr.select(darker, y, lo_y)
        hi, hi_y = dr.select(brighter, v, hi), dr.select(brighter, y, hi_y)
    none = lo_y > hi_y
    return UnwarpTaps(L=L, weight=den, darkest=dr.select(none, L, lo),
                      brightest=dr.select(none, L, hi))


def disagreeing_pixels(taps: UnwarpTaps, tolerance: float, peak: mi.Float) -> mi.Bool | None:
    """Per pixel of ``taps``: whether its blended taps disagree -- the
    darkest and the brightest differ by more than ``tolerance`` of the
    brighter and by more than ``tolerance``·1e-2 of ``peak`` (the frame's
    largest channel sum, :func:`frame_peak`), by
    :func:`~integrators.epipolar.ring.apart`, the test the epipolar
    template applies to a camera sample's two slices (None: ``tolerance
    ≥ 1``, none).  A shadow edge or a narrow beam runs between such taps,
    so their blend estimates neither side: :func:`fixup` ray-marches these
    pixels.

    The frame's ``peak`` bounds the test's floor, so that a partial render,
    which unwarps a subset of the pixels, flags what the full render does."""
    if tolerance >= 1.0 or not dr.width(taps.weight):
        return None
    dark, bright = taps.darkest, taps.brightest
    y_d, y_b = dark[0] + dark[1] + dark[2], bright[0] + bright[1] + bright[2]
    third = peak * (1.0 / 3.0)           # the peak as a channel sum, rounded as one
    return apart(dr.maximum(y_d, y_b), dr.minimum(y_d, y_b), dr.maximum(y_d, y_b), tolerance,
                 peak=third + third + third)


def frame_peak(samples: EpipolarSamples, values: mi.Color3f) -> mi.Float:
    """The largest channel sum of the used samples' ``values``."""
    return dr.max(dr.select(samples.used, values.x + values.y + values.z, 0.0))


def fixup(params, cap: CameraCapture, frame, L_pixel: mi.Color3f, weight: mi.Float,
          threshold: float, steps: int, shadow_map=None, also=None,
          pixels: mi.UInt32 | None = None, bisections: int = 0) -> Unwarped:
    """Re-march the pixels whose bilateral weight is below ``threshold``,
    and those of the mask ``also`` (camera samples of ``cap``: one per
    pixel, in pixel order) or of the index list ``also``.  ``pixels``: the
    pixels ``L_pixel``, ``weight`` and ``also`` hold (None: every pixel);
    ``fixup`` lists the re-marched ones by their position there.  Traced
    blockers (no ``shadow_map``): the epipolar methods' exact marcher
    (:func:`~integrators.epipolar.ring.peak_marched`: its shadow and cone
    edges located by ``bisections`` bisections, the pixels at a point
    light's peak with more steps; ``frame``: the light's epipolar frame);
    resampled: the shadow map's."""
    todo = weight < threshold
    if also is not None:
        if isinstance(also, mi.UInt32):
            if dr.width(also):
                dr.scatter(todo, True, also)
        else:
            todo |= also
    idx = dr.compress(todo)
    L = mi.Color3f(L_pixel)
    if dr.width(idx):
        lanes = two_or_more(idx)
        samples = lanes if pixels is None else dr.gather(mi.UInt32, pixels, lanes)
        dr.scatter(L, march_samples(params, cap, samples, frame, steps, shadow_map, bisections),
                   lanes)
    return Unwarped(L=L, weight=weight, fixup=idx)


def march_every_pixel(params, cap: CameraCapture, frame, steps: int, shadow_map=None,
                      bisections: int = 0) -> Unwarped:
    """:func:`fixup`'s march of every camera sample of ``cap`` (a frame
    the plugin marches pixel by pixel)."""
    n = cap.count
    lanes = two_or_more(dr.arange(mi.UInt32, n))
    L = dr.zeros(mi.Color3f, n)
    dr.scatter(L, march_samples(params, cap, lanes, frame, steps, shadow_map, bisections), lanes)
    return Unwarped(L=L, weight=dr.zeros(mi.Float, n), fixup=dr.arange(mi.UInt32, n))


def march_samples(params, cap: CameraCapture, samples: mi.UInt32, frame, steps: int,
                  shadow_map=None, bisections: int = 0) -> mi.Color3f:
    """L_scat of the camera samples ``samples`` of ``cap`` by the fix-up's
    marcher (:func:`fixup`: traced blockers or the shadow map's)."""
    sub = cap.subset(samples)
    if shadow_map is None:
        return peak_marched(params, sub, frame, steps, bisections)
    return march(params, sub, steps, shadow_map=shadow_map, spacing=auto_spacing(params))
