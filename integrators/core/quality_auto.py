"""``quality="auto"``: an integrator chooses its own settings for a relMSE
budget.

Common properties (every method, read by the template):

==================  ========================================================
``quality``         ``explicit`` (default): the settings as given;
                    ``auto``: the method picks its quality knobs for
                    ``error_budget`` from the scene before it renders.
``error_budget``    the relMSE to meet (pixel-centre convention of
                    DESIGN §2: scale-free relMSE against ``raymarch
                    visibility=exact``); needs ``quality="auto"``.
==================  ========================================================

How a method chooses (:data:`RULES`): a *probe* renders the scene at one
or two cheap settings of the method and measures their relMSE directly
on a strided subset of about :data:`PROBE_PIXELS` pixel centres -- and,
where its first render is a full image, :data:`EDGE_PIXELS` of them on
that image's edges instead, each stratum weighted by its share of the image
(:class:`Strata`: a few thin shafts can hold most of an error that a
strided subset steps over) -- against an exact marcher (``raymarch
visibility=exact`` with boundary bisections, :func:`reference_settings`)
run on those pixels alone (a partial render, which marches only the
masked samples).  An error model per method, with exponents fitted on
the suite's frontier runs (``python -m experiments.error_budget --fit``,
constants in :data:`FIT`), turns the probe's errors into a prediction for
every candidate setting; the rule takes the cheapest candidate predicted
to meet ``SAFETY * error_budget`` (the most accurate one when none is).

Each method's rule -- its error model, candidates and probe settings --
lives with the method and is registered by its plugin module
(:func:`register_rule`, a :class:`QualityRule`):
:mod:`integrators.core.march_quality` (``raymarch``, exact visibility),
:mod:`integrators.tree.quality` (``epipolar_tree``: slice spacing and
light rays), :mod:`integrators.fourier.quality` (``fourier_filter``:
coefficients and weights), :mod:`integrators.minmax.quality`
(``minmax_epipolar``: initial step).

Where a probe renders the whole image (tree, filter, minmax), it renders
its cheaper setting first and stops there when that setting's error
already meets the target: the rule returns it.  The tree's and the
filter's second probe setting is their predicted answer, returned when it
meets the target.  Either way the render reuses the probe's own render of
the setting returned (:func:`kept_render`) when that is the render asked
for (the whole frame, one sample per pixel centre, output ``full``, the
same seed).  When it is, a setting the rule's model chose (the probe did
not render it) is rendered by the probe and measured before it is
returned (:func:`settle`): the warning of a missed budget then rests on
the error of the image the user gets, not on the model's guess.

The chosen settings, the probe's errors and its time go into the render's
``RenderResult.stats`` (``auto_settings``, ``auto_probe``,
``auto_probe_s``, ``auto_reused``) and ``timings["probe"]``; the render
itself is that of an integrator built with the chosen settings (or the
probe's render of them), so it equals an explicit render with them.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np


QUALITIES = ("explicit", "auto")
#: pixel centres the probe measures its errors on (a strided subset).
#: ``experiments.error_budget``'s probe table on 60 held-out scenes: with
#: 1,200 and a 512-step reference no estimate is under a third of the
#: full image's relMSE (under half in 1 % of them); with 300, 1-4 % are,
#: down to a tenth -- the marcher's error on a spot-lit shaft lies in its
#: edges, which a sparser subset steps over
PROBE_PIXELS = 1200
#: the share of the image's pixels that are its edges (:func:`edge_pixels`),
#: and how many of the probe's pixels are taken on them once it has an
#: image of the scene (its first full-image render; the rest strided): a
#: stratified sample (:class:`Strata`).  On 20 held-out scenes at 320x240
#: (five probe settings each, against the 2,048-step reference): 900
#: strided + 300 edge pixels misjudge the full image's relMSE by a median
#: 1.09x (90th percentile 1.47x) and underestimate it by over 2x in 2 of 100
#: cases, 1,200 strided ones by 1.22x (3.8x) and in 21 -- down to 1/100 on
#: a spot's thin shafts (``python -m experiments.probe_strata``)
EDGE_SHARE = 0.05
EDGE_PIXELS = 300
#: the edge stratum's size at most: the :data:`EDGE_SHARE` of a 320x240
#: image, so that its :data:`EDGE_PIXELS` samples keep their density on
#: larger images.  At 640x480 a 5 % stratum (15,360 pixels) is hit 2.4
#: times on average by 123 pixels that hold 90 % of a spot's thin-shaft
#: error (held-out seed 2000, minmax: estimate 1/30 of the truth); capped,
#: and marched against :data:`EDGE_BISECTED_REFERENCE`, 0.95x.  On 20
#: held-out scenes at 640x480 (100 probe settings of the tree, the filter
#: and minmax, ``python -m experiments.probe_strata --size 640x480``):
#: estimates under half the truth 9 with a 5 % stratum, 4 capped, 2 as
#: the probe measures them (against its references; at true relMSE
#: 1.5e-6 and 2.6e-7)
EDGE_STRATUM = 3840
#: the exact marcher the probe's errors are measured against
#: (:func:`reference_settings`): with boundary bisections (each shadow
#: edge located, :func:`~integrators.core.marching.march_bisected`), and
#: the finer one a rule may ask for (:meth:`Probe.fine_reference`).  On 10
#: held-out scenes at 320x240 without a textured light (relMSE on the
#: probe's pixels against 8,192 steps with 12 bisections,
#: :mod:`experiments.probe_reference`, ``results/probe_reference``): 64
#: steps with 8 bisections at most 1.8e-6 on the strided pixels, in
#: 0.8-1.4x the time of 512 plain steps, which had up to 6e-4 (a spot's
#: thin shafts); 256 with 8 at most 1.0e-8, in 0.3-0.45x the time of 4,096
#: plain steps (up to 3.6e-6).  On the edge pixels of a stratified probe
#: (:class:`Strata`) 64 steps step over a spot's shafts thinner than a
#: step (8e-5 on held-out seed 2000, where 128 with 8 have 2e-8; 128 with
#: 8 at most 7e-7 on 17 such scenes): 64 only for a loose budget
#: (:data:`LOOSE_BUDGET`), 128 below it, 256 below :data:`TIGHT_BUDGET`
LOOSE_BISECTED_REFERENCE = {"steps": 64, "boundary_bisections": 8}
BISECTED_REFERENCE = {"steps": 128, "boundary_bisections": 8}
FINE_BISECTED_REFERENCE = {"steps": 256, "boundary_bisections": 8}
#: the reference on the edge stratum's pixels where it is capped
#: (:data:`EDGE_STRATUM`, :meth:`Probe.stratify`), whatever the budget:
#: its sharpest edges are where the coarser ones err, and an estimate
#: weighting them by their share of the image carries that error in full
#: (held-out seed 2000 at 640x480, a stratum of 3,840 pixels: against
#: 128x8 on its edges, minmax's estimate is 3.6x the truth, against 256x8
#: 1.6x, against this one or 1,024 steps 0.95x -- 512 and 1,024 alike on
#: the first 8 of those scenes; marched apart from the rest, 300 pixels at
#: 512x8 cost about what the other 900 at 128x8 cost, 25-45 ms).  Where a
#: textured spot lights the scene, the finer plain reference
#: (:data:`FINE_REFERENCE_STEPS`)
EDGE_BISECTED_REFERENCE = {"steps": 512, "boundary_bisections": 8}
#: steps of the plain exact marcher the probe measures against where a
#: textured spot light lights the scene: its texture varies inside the lit
#: intervals the bisections find, which their two samples per segment do
#: not resolve (three textured spots there: 256 steps with 8 bisections
#: 1.3e-5 ... 2.4e-5, 4,096 plain steps 2.6e-7 ... 6.4e-7; 64 with 8 up to
#: 3.8e-4, 512 plain steps up to 3.6e-5)
REFERENCE_STEPS = 512
#: steps of the finer plain reference (:meth:`Probe.fine_reference`)
FINE_REFERENCE_STEPS = 4096
#: budgets below this are probed against the finer reference: the
#: 512-step marcher's own error on thin occluders is of this order (a
#: textured spot through thin bars: against it, a 1e-5 budget chose
#: 1,600 light rays at 3.8e-5; against the finer one, 6.5e-6)
TIGHT_BUDGET = 3e-5
#: budgets from this one up are loose: the probe measures against
#: :data:`LOOSE_BISECTED_REFERENCE` (without a textured light), and the
#: marcher's probe marches few steps
#: (:data:`~integrators.core.march_quality.LOOSE_MARCH_PROBE`)
LOOSE_BUDGET = 3e-4
#: the budget's share the rule aims at (the probe's estimate is noisy)
SAFETY = 0.5
#: the budget's share a setting's error measured on a stratified sample
#: (:class:`Strata`) must meet for the rule to take it (:func:`meets`):
#: such an estimate is within 1.5x of the image's relMSE in 9 of 10 cases
#: and under half of it in 2 of 100 (held-out scenes, :data:`EDGE_PIXELS`),
#: so that a measured setting is not re-rendered finer for a margin the
#: estimate no longer needs; a model's prediction still aims at
#: :data:`SAFETY`
MEASURED_SAFETY = 0.8

#: method -> its rule (:class:`QualityRule`), registered by each plugin
#: module with :func:`register_rule`
RULES: dict = {}
#: method -> the constants of its error model (its rule's ``fit``)
FIT: dict = {}


@dataclass(frozen=True)
class QualityRule:
    """What ``quality="auto"`` needs of a method: the ``knobs`` its rule
    chooses (refused when given with ``quality="auto"``), the two settings
    its ``probe`` renders for an image diagonal, the rule ``choose(probe,
    budget, fit)`` -> settings, and the ``fit`` constants of its error
    model."""
    knobs: tuple
    probe: Callable[[float], list]
    choose: Callable
    fit: dict


def register_rule(method: str, rule: QualityRule) -> None:
    """Make ``rule`` the ``quality="auto"`` rule of plugin ``method``."""
    RULES[method] = rule
    FIT[method] = rule.fit


def read_quality(props) -> tuple[str, float | None]:
    """``quality`` and ``error_budget`` of ``props`` (module doc), with
    ValueErrors naming the fix (the knobs an auto rule chooses may not be
    given with it)."""
    quality = props.get("quality", "explicit")
    if quality not in QUALITIES:
        raise ValueError(f"Property 'quality' = {quality!r} is not one of {list(QUALITIES)}.")
    has_budget = "error_budget" in props
    if quality == "explicit":
        if has_budget:
            raise ValueError("Property 'error_budget' needs quality='auto' (the integrator then "
                             "chooses its settings to meet it); add quality='auto' or drop "
                             "error_budget.")
        return quality, None
    method = props.plugin_name()
    if method not in RULES:
        raise ValueError(f"quality='auto' has no rule for '{method}' yet: use one of "
                         f"{sorted(RULES)} or give the settings explicitly.")
    if not has_budget:
        raise ValueError("quality='auto' needs an error_budget (relMSE, pixel-centre "
                         "convention), e.g. error_budget=1e-4.")
    budget = props["error_budget"]
    if isinstance(budget, bool) or not isinstance(budget, (int, float)) or \
            not math.isfinite(budget) or budget <= 0:
        raise ValueError(f"Property 'error_budget' = {budget!r} must be a positive relMSE, "
                         "e.g. 1e-4.")
    given = sorted(k for k in RULES[method].knobs if k in props)
    if given:
        raise ValueError(f"quality='auto' chooses {given} itself: drop them, or drop "
                         "quality='auto' to set them explicitly.")
    return quality, float(budget)


# --------------------------------------------------------------------------
# The probe: errors on a pixel subset against an exact marcher
# --------------------------------------------------------------------------

def probe_pixels(width: int, height: int, target: int = PROBE_PIXELS) -> np.ndarray:
    """Indices (row-major) of a strided subset of about ``target`` pixels,
    every pixel when the image has fewer."""
    stride = max(1, int(round(math.sqrt(width * height / target))))
    ys, xs = np.meshgrid(np.arange(stride // 2, height, stride),
                         np.arange(stride // 2, width, stride), indexing="ij")
    return (ys * width + xs).ravel()


def edge_pixels(image: np.ndarray, share: float = EDGE_SHARE,
                most: int | None = EDGE_STRATUM) -> np.ndarray:
    """Indices (row-major, sorted) of the ``share`` of the pixels of
    ``image`` (H, W, C), at most ``most`` of them, with the largest
    relative contrast to a 4-neighbour, |Y_p - Y_n| / (Y_p + Y_n + 1e-2
    mean Y) on the channel mean Y: the shaft and shadow edges, where a
    method's error concentrates."""
    image = np.asarray(image, np.float64)
    Y = image[..., 0].copy()                # the channel mean, summed as numpy's mean sums
    for c in range(1, image.shape[-1]):
        Y += image[..., c]
    Y /= image.shape[-1]
    floor = 1e-2 * max(float(Y.mean()), 1e-30)
    down = np.abs(Y[1:] - Y[:-1]) / (Y[1:] + Y[:-1] + floor)            # each pixel and the next row's
    right = np.abs(Y[:, 1:] - Y[:, :-1]) / (Y[:, 1:] + Y[:, :-1] + floor)
    score = np.zeros_like(Y)
    for dst, c in ((score[1:], down), (score[:-1], down), (score[:, 1:], right),
                   (score[:, :-1], right)):
        np.maximum(dst, c, out=dst)
    n = max(min(int(round(share * Y.size)), most or Y.size), 1)
    flat = score.ravel()
    top = np.argpartition(-flat, n - 1)[:n]
    return np.sort(top[flat[top] > 0])


def edge_stratum_capped(n_pixels: int) -> bool:
    """Whether the edge stratum of an image of ``n_pixels`` is capped at
    :data:`EDGE_STRATUM` (fewer pixels than its :data:`EDGE_SHARE`): it
    then holds only the sharpest edges (:meth:`Probe.stratify`)."""
    return round(EDGE_SHARE * n_pixels) > EDGE_STRATUM


class Strata:
    """A stratified pixel sample: the probe's strided pixels plus extra
    pixels on the edges of an image of the scene (:func:`edge_pixels`), each
    stratum weighted by its share of the image so that the estimate of a
    mean over all pixels stays unbiased while the edges, where a few thin
    shafts can hold most of a method's error, are sampled several times as
    densely.  ``pixels``: the sample's indices (the strided ones first);
    ``weights``: per sample, its stratum's share of the image over the
    stratum's samples (they sum to 1); ``edge``: per sample, whether it
    lies in the edge stratum."""

    def __init__(self, strided: np.ndarray, edges: np.ndarray, n_pixels: int, extra: int):
        in_edges = np.isin(strided, edges)
        pick = edges[np.linspace(0, len(edges) - 1, min(extra, len(edges))).round().astype(int)] \
            if len(edges) and extra else np.zeros(0, strided.dtype)
        pick = np.setdiff1d(pick, strided)
        self.pixels = np.concatenate([strided, pick]).astype(np.int64)
        self.edge = edge = np.concatenate([in_edges, np.ones(len(pick), bool)])
        w = np.zeros(len(self.pixels))
        share_e = len(edges) / n_pixels
        if edge.any():
            w[edge] = share_e / edge.sum()
        if (~edge).any():
            w[~edge] = (1.0 - share_e) / (~edge).sum()
        else:                                  # every pixel an edge: one stratum
            w[:] = 1.0 / len(w)
        self.weights = w / w.sum()


def settings_key(settings: dict) -> tuple:
    """A hashable key of a settings dict (its items, sorted)."""
    return tuple(sorted(settings.items()))


def subset_relmse(test: np.ndarray, ref: np.ndarray, eps: float = 1e-2,
                  weights: np.ndarray | None = None) -> float:
    """DESIGN §2's scale-free relMSE of two (pixels, 3) arrays (``weights``:
    per pixel, summing to 1, for a stratified sample, :class:`Strata`)."""
    ref = np.asarray(ref, np.float64)
    w = (np.full(len(ref), 1.0 / max(len(ref), 1)) if weights is None
         else np.asarray(weights, np.float64))
    floor = eps * float(np.sum(w * ref.mean(axis=-1))) ** 2
    d2 = (np.asarray(test, np.float64) - ref) ** 2
    if floor <= 0:
        return 0.0 if not d2.any() else math.inf
    return float(np.sum(w * np.mean(d2 / (ref ** 2 + floor), axis=-1)))


def reference_settings(scene, sensor=0, fine: bool = False, loose: bool = False,
                       edges: bool = False) -> dict:
    """The ``raymarch visibility=exact`` settings the probe of ``scene``
    measures against (``fine``: the finer reference; ``loose``: a loose
    budget's; ``edges``: the edge stratum's): the bisected marcher
    (:data:`BISECTED_REFERENCE`, :data:`FINE_BISECTED_REFERENCE`,
    :data:`LOOSE_BISECTED_REFERENCE`, :data:`EDGE_BISECTED_REFERENCE`), or
    :data:`REFERENCE_STEPS` / :data:`FINE_REFERENCE_STEPS` plain steps
    where a textured spot light lights the scene."""
    from .scene_params import SceneParams

    s = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
    if any(light.textured for light in SceneParams.from_scene(scene, s).lights):
        return {"steps": FINE_REFERENCE_STEPS if fine or edges else REFERENCE_STEPS}
    return dict(EDGE_BISECTED_REFERENCE if edges else FINE_BISECTED_REFERENCE if fine else
                LOOSE_BISECTED_REFERENCE if loose else BISECTED_REFERENCE)


class Probe:
    """The probe of one scene (module doc): renders settings of a method at
    one sample per pixel centre and measures them on :func:`probe_pixels`
    against the exact marcher on those pixels (``pixels``:
    :data:`PROBE_PIXELS` unless given; the marcher
    :func:`reference_settings`, its finer one with ``fine``, or ``steps``
    plain steps where given).  The reference is marched when the first
    error is measured: where that first render is a full image,
    :data:`EDGE_PIXELS` of the pixels (at most a quarter) are taken on its
    edges and the rest strided, a stratified sample (:class:`Strata`, its
    weights in every error after; ``loose``: a loose budget's reference),
    whose edge pixels, where the stratum is capped, are marched against
    the edge reference (:func:`reference_settings` with ``edges``)
    whatever the budget (:meth:`stratify`); a
    probe whose first render is partial keeps the strided pixels.  Its
    full-image renders are kept (:attr:`kept`, by settings) so that a
    render asking for one of them again reuses it (:func:`render_auto`)."""

    def __init__(self, scene, sensor, method: str, base: dict, pixels: int | None = None,
                 steps: int | None = None, seed=0, fine: bool = False, loose: bool = False):
        self.scene, self.sensor, self.method, self.seed = scene, sensor, method, seed
        #: one sample per pixel centre, the full image, whatever the render asks
        self.base = {k: v for k, v in base.items()
                     if k not in ("samples_per_pixel", "jitter_pixels", "output")}
        s = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
        self.width, self.height = (int(v) for v in s.film().crop_size())
        self.pixels = probe_pixels(self.width, self.height, pixels or PROBE_PIXELS)
        #: per probe pixel, its weight in an error (None: all alike)
        self.weights = None
        #: how many of :attr:`pixels` were added on the edges (:class:`Strata`)
        self.edge_pixels = 0
        #: per probe pixel, whether it lies in the edge stratum (None: not stratified)
        self.edge = None
        self._set_mask()
        #: the marcher's settings of the reference and of the finer one
        self.reference_props = ({"steps": steps} if steps else
                                reference_settings(scene, s, fine, loose and not fine))
        self.fine_props = (self.reference_props if steps or fine else
                           reference_settings(scene, s, True))
        #: the marcher's settings on the edge stratum's pixels, where the
        #: stratum is capped (:meth:`stratify`); None: the reference's
        self.edge_props = None
        self._edge_reference = None if steps else reference_settings(scene, s, edges=True)
        self._reference = self._fine = None
        #: (settings key, which pixels) -> the marcher's values there
        self._marched = {}
        #: (settings key, partial) -> the probe pixels' values of a render
        self._rendered = {}
        self.errors = []
        #: settings key -> RenderResult of each full-image probe render
        self.kept = {}
        #: the relMSE the rule expects of its choice, and whether the probe
        #: measured it (``"measured"``) or its error model predicts it
        #: (``"model"``); None where the model has nothing to go on
        self.predicted, self.predicted_from = None, None
        #: whether the rule expects to miss the budget at every setting
        self.over_budget = False
        #: whether the render after the probe reuses its full-image renders
        #: (:func:`reuses_probe`): a rule's model-chosen setting is then
        #: rendered and measured at no extra cost (:func:`settle`)
        self.reusable = False

    def _set_mask(self) -> None:
        self.mask = np.zeros(self.width * self.height, bool)
        self.mask[self.pixels] = True

    @property
    def reference(self) -> np.ndarray:
        """The exact marcher's values on the probe pixels (marched once, at
        first use: the probe's pixels are fixed from then on)."""
        if self._reference is None:
            self._reference = self._stratum_reference(self.reference_props)
        return self._reference

    def _march(self, props: dict, which: str) -> np.ndarray:
        """The exact marcher's values at ``props`` on the probe pixels of
        the edge stratum (``which="edges"``), of the rest (``"rest"``) or
        on all of them (``"all"``), marched once."""
        import mitsuba as mi

        key = (settings_key(props), which)
        if key not in self._marched:
            pixels = (self.pixels if which == "all" else
                      self.pixels[self.edge if which == "edges" else ~self.edge])
            integ = mi.load_dict({"type": "raymarch", "visibility": "exact", **props})
            res = self.render(integ, partial=True, pixels=pixels)
            self._marched[key] = self.image(integ, res)[pixels]
        return self._marched[key]

    def _stratum_reference(self, props: dict) -> np.ndarray:
        """The reference on the probe pixels: the marcher at ``props``, on
        the edge stratum's pixels at :attr:`edge_props` where that is set
        and another setting."""
        if self.edge_props is None or not self.edge.any() or props == self.edge_props:
            return self._march(props, "all")
        edges = self._march(self.edge_props, "edges")
        out = np.empty((len(self.pixels), edges.shape[-1]))
        out[self.edge] = edges
        if (~self.edge).any():
            out[~self.edge] = self._march(props, "rest")
        return out

    def stratify(self, image: np.ndarray) -> None:
        """Add the edges of ``image`` (H, W, C), a full render of the scene,
        to the probe pixels (:class:`Strata`); only before the reference is
        marched.  Where the stratum is capped (:data:`EDGE_STRATUM` pixels,
        fewer than :data:`EDGE_SHARE` of the image) it holds only the
        sharpest edges, where the budget's reference errs: its pixels are
        then marched against the edge reference (:attr:`edge_props`); on
        smaller images they keep the budget's (validated on 60 held-out
        scenes at 320x240, where the stratum is exactly 5 %)."""
        if self._reference is not None or self.edge_pixels:
            return
        extra = min(EDGE_PIXELS, len(self.pixels) // 4)
        strided = probe_pixels(self.width, self.height, len(self.pixels) - extra)
        n = self.width * self.height
        strata = Strata(strided, edge_pixels(image, EDGE_SHARE, EDGE_STRATUM), n, extra)
        self.edge_pixels = len(strata.pixels) - len(strided)
        self.pixels, self.weights, self.edge = strata.pixels, strata.weights, strata.edge
        if edge_stratum_capped(n):
            self.edge_props = self._edge_reference
        self._set_mask()

    def predict(self, relmse, how: str) -> None:
        """Record the error the rule expects of the setting it returns."""
        ok = relmse is not None and math.isfinite(relmse)
        self.predicted, self.predicted_from = (float(relmse), how) if ok else (None, None)

    def unreachable(self, budget: float, relmse, measured: dict | None = None) -> None:
        """The rule's finest setting is predicted to miss ``budget`` (or its
        choice, ``measured``, was measured over it): say so (a
        ``UserWarning`` naming what converges) instead of returning an
        image over budget silently; the render's stats record it."""
        self.over_budget = True
        what = (f"measured relMSE {relmse:.2e} on the probe's pixels at the setting its rule "
                f"chose, {measured}" if measured is not None else
                f"predicted relMSE {relmse:.2e} at the finest setting its rule considers")
        warnings.warn(
            f"quality='auto': {self.method} is not expected to reach error_budget {budget:g} "
            f"({what}): the render will be over budget.  raymarch with visibility='exact' "
            "converges to the reference with enough steps; or raise the budget.",
            UserWarning, stacklevel=3)

    def render(self, integrator, partial=False, pixels=None):
        """RenderResult of ``integrator`` at one sample per pixel centre (a
        partial render of the probe pixels -- or of ``pixels`` where given
        -- where the method marches samples alone)."""
        if pixels is not None:
            mask = np.zeros(self.width * self.height, bool)
            mask[pixels] = True
        else:
            mask = self.mask
        kw = {"samples": mask} if partial else {}
        return integrator.render_layers(self.scene, self.sensor, seed=self.seed, spp=1, **kw)

    def image(self, integrator, result) -> np.ndarray:
        """The output layer of ``integrator``'s ``result``, (pixels, C)."""
        img = np.asarray(result[integrator.output], np.float64)
        return img.reshape(-1, img.shape[-1])

    def values(self, integrator, partial=False, result=None) -> np.ndarray:
        """The output layer of ``integrator`` (or of its ``result``) on the
        probe pixels."""
        res = result if result is not None else self.render(integrator, partial)
        return self.image(integrator, res)[self.pixels]

    def error(self, settings: dict, partial=False, fine=False) -> float:
        """relMSE of the method at ``settings`` on the probe pixels (against
        :meth:`fine_reference` with ``fine``); the first full-image render
        stratifies the pixels (:meth:`stratify`)."""
        import mitsuba as mi

        key = (settings_key(settings), partial)
        if key not in self._rendered:        # measured against the other reference before
            integ = mi.load_dict({"type": self.method, **self.base, **settings})
            res = self.render(integ, partial)
            if not partial:
                self.kept[settings_key(settings)] = res
                img = self.image(integ, res)
                self.stratify(img.reshape(self.height, self.width, -1))
                self._rendered[key] = img[self.pixels]
            else:
                self._rendered[key] = self.values(integ, result=res)
        ref = self.fine_reference() if fine else self.reference
        e = subset_relmse(self._rendered[key], ref, weights=self.weights)
        self.errors.append({**settings, "relmse": e, **({"fine": True} if fine else {})})
        return e

    def fine_reference(self) -> np.ndarray:
        """The finer reference (:func:`reference_settings` with ``fine``) on
        the probe pixels (made once): errors of settings near the probe's
        own reference need a finer one."""
        if self.fine_props == self.reference_props:
            return self.reference
        if self._fine is None:
            self._fine = self._stratum_reference(self.fine_props)
        return self._fine

    @property
    def diagonal(self) -> float:
        return math.hypot(self.width, self.height)


# --------------------------------------------------------------------------
# Rules: probe -> settings
# --------------------------------------------------------------------------

def settle(probe: Probe, settings: dict, budget: float, predicted) -> None:
    """A rule returns ``settings`` its model chose (the probe did not render
    them) with the model's ``predicted`` relMSE: where the render after the
    probe reuses the probe's full-image renders (``probe.reusable``) the
    probe renders them and measures their error -- the render the user
    gets, at no extra cost -- and the budget is flagged only where that
    measurement misses it; otherwise the prediction stands, flagged where
    it misses the target."""
    if getattr(probe, "reusable", False):
        e = probe.error(settings)
        probe.predict(e, "measured")
        if e > budget:
            probe.unreachable(budget, e, measured=settings)
        return
    probe.predict(predicted, "model")
    if predicted is not None and predicted > target_of(budget):
        probe.unreachable(budget, predicted)


def clamped_exponent(e_a: float, e_b: float, x_a: float, x_b: float, fit: dict) -> float:
    """k of relMSE = C x^k through the probe's errors ``e_a`` at ``x_a`` and
    ``e_b`` at ``x_b``, clamped to ``fit["k_range"]``; ``fit["k"]`` where
    either shows nothing (0 or not finite)."""
    if not all(e > 0 and math.isfinite(e) for e in (e_a, e_b)):
        return fit["k"]
    k = math.log(e_a / e_b) / math.log(x_a / x_b)
    return min(max(k, fit["k_range"][0]), fit["k_range"][1])


def target_of(budget: float) -> float:
    """The relMSE a rule's model aims at for ``budget``."""
    return SAFETY * budget


def meets(probe, relmse: float, budget: float) -> bool:
    """Whether a setting whose error the probe measured, ``relmse``, is
    taken for ``budget``: within :data:`MEASURED_SAFETY` of it on a
    stratified probe, within :func:`target_of` on a strided one."""
    share = MEASURED_SAFETY if getattr(probe, "weights", None) is not None else SAFETY
    return relmse <= share * budget


def probe_settings(method: str, diagonal: float) -> list[dict]:
    """The two settings the probe of ``method`` renders (its rule's
    ``probe``), for an image of ``diagonal`` pixels.  The tree's and the
    filter's rules render the first and, in place of the second, their
    predicted answer (the fixed second setting only where there is no
    prediction); ``experiments.error_budget`` measures the probe's
    estimates on this fixed pair."""
    if method not in RULES:
        raise ValueError(f"no quality='auto' rule for {method!r}: use one of {sorted(RULES)}.")
    return RULES[method].probe(diagonal)


def probe_errors(probe: Probe, settings, budget: float):
    """``(first, e1, e2)``: the probe's errors at its two settings of
    ``settings(diagonal)`` (a rule's probe), the cheaper ``first`` rendered
    first; ``e2`` is None when ``e1`` already meets the budget (:func:`meets`; the second
    setting is then not rendered, and the rule returns ``first``, whose
    render the probe keeps)."""
    first, second = settings(probe.diagonal)
    e1 = probe.error(first)
    if meets(probe, e1, budget):
        return first, e1, None
    return first, e1, probe.error(second)


def budget_probe(scene, sensor, method: str, base: dict, budget: float, seed=0) -> Probe:
    """The :class:`Probe` of ``method`` for ``budget``: its reference the
    budget's tier (the finer one below :data:`TIGHT_BUDGET`, the loose one
    from :data:`LOOSE_BUDGET` up)."""
    return Probe(scene, sensor, method, base, seed=seed, fine=budget < TIGHT_BUDGET,
                 loose=budget >= LOOSE_BUDGET)


def choose(scene, method: str, budget: float, base: dict | None = None, sensor=0, seed=0):
    """(settings, stats) of ``method`` for ``budget`` on ``scene``: the
    rule's choice and what the probe measured (its errors, its time)."""
    settings, stats, _ = probe_and_choose(scene, method, budget, base, sensor, seed)
    return settings, stats


def probe_and_choose(scene, method: str, budget: float, base: dict | None = None, sensor=0,
                     seed=0, reusable: bool = False):
    """:func:`choose`, and the :class:`Probe` (with its kept renders);
    ``reusable``: the render after it reuses the probe's full-image renders
    (:func:`reuses_probe`), so a model-chosen setting is measured
    (:func:`settle`)."""
    if method not in RULES:
        raise ValueError(f"no quality='auto' rule for {method!r}: use one of {sorted(RULES)}.")
    if not (isinstance(budget, (int, float)) and budget > 0):
        raise ValueError(f"error budget {budget!r} must be a positive relMSE, e.g. 1e-4.")
    t0 = time.perf_counter()
    probe = budget_probe(scene, sensor, method, base or {}, budget, seed)
    probe.reusable = reusable
    settings = RULES[method].choose(probe, float(budget), FIT[method])
    return settings, {"auto_probe": probe.errors, "auto_probe_s": time.perf_counter() - t0,
                      "auto_probe_pixels": int(len(probe.pixels)),
                      "auto_probe_edge_pixels": int(probe.edge_pixels),
                      "auto_predicted_relmse": probe.predicted,
                      "auto_predicted_from": probe.predicted_from,
                      "auto_over_budget": probe.over_budget}, probe


def reuses_probe(inner, scene, sensor, spp, partial_args: dict) -> bool:
    """Whether the render ``inner`` is asked for (the whole frame, one
    sample per pixel centre, output ``full``) is one the probe renders."""
    if any(v is not None for v in partial_args.values()):
        return False
    n = inner.sample_count(scene, sensor, spp)
    return n == 1 and not inner.jitters(n) and inner.output == "full"


def kept_render(probe: Probe, inner, scene, sensor, spp, settings: dict, partial_args: dict):
    """The probe's render of ``settings`` if it is the render ``inner``
    is asked for (:func:`reuses_probe`, the probe's seed), else None."""
    if not reuses_probe(inner, scene, sensor, spp, partial_args):
        return None
    return probe.kept.get(settings_key(settings))


def render_auto(integrator, scene, sensor=0, seed=0, spp=0, **kw):
    """``render_layers`` of an auto integrator: choose (:func:`choose`),
    then render with an integrator built with the chosen settings -- or,
    where the choice is a setting the probe rendered in full as asked
    (:func:`kept_render`), that render, which is the same image; its
    result with the choice in ``stats`` (``auto_reused``) and the probe in
    ``timings``.  ``seed``: a Python int (the template's
    :func:`~integrators.template.base.scalar_seed`)."""
    import mitsuba as mi

    base = dict(integrator.explicit_properties)
    reusable = reuses_probe(integrator, scene, sensor, spp, kw)
    settings, stats, probe = probe_and_choose(scene, integrator.method_name,
                                              integrator.error_budget, base, sensor, int(seed),
                                              reusable)
    inner = mi.load_dict({"type": integrator.method_name, **base, **settings})
    result = kept_render(probe, inner, scene, sensor, spp, settings, kw)
    reused = result is not None
    if not reused:
        result = inner.render_layers(scene, sensor, seed, spp, **kw)
    return replace(result, timings={**result.timings, "probe": stats["auto_probe_s"]},
                   stats={**result.stats, **stats, "auto_settings": settings,
                          "auto_reused": reused, "error_budget": integrator.error_budget})
