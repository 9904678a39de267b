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
on a strided subset of about :data:`PROBE_PIXELS` pixel centres, against
an exact marcher (``raymarch visibility=exact``, :data:`REFERENCE_STEPS`
steps) run on that subset alone (a partial render, which marches only
the masked samples).  An error model per method, with exponents fitted on
the suite's frontier runs (``python -m experiments.error_budget --fit``,
constants in :data:`FIT`), turns the probe's errors into a prediction for
every candidate setting; the rule takes the cheapest candidate predicted
to meet ``SAFETY * error_budget`` (the most accurate one when none is).

* ``raymarch`` (exact visibility, Baran 2010 §2's reference marcher):
  relMSE = C·n^k in the steps n; the probe marches the subset at
  :data:`MARCH_PROBE` steps, which gives the scene's own C and k (k
  clamped to ``FIT["raymarch"]["k_range"]``).
* ``epipolar_tree`` (Baran 2010 §8 slices, §7 light rays): relMSE =
  A·(s/s₀)^a + B·(ρ/ρ₀)^-b in the slice spacing s [px] and the light-ray
  density ρ (light rays per slice over the image diagonal in pixels; the
  light-ray term is the tree's error floor at fixed light rays); the probe
  renders (s₀, ρ₀), then -- unless that meets the target -- the setting
  the model predicts from that error alone (A = B = its error, a
  conservative split), which is the answer when it meets the target and
  otherwise separates A and B; time ~ α + β/s + γ·ρ/s (fitted).
* ``fourier_filter`` (Klehm 2014 §3 truncated Fourier series): relMSE =
  F + C·M^k in the coefficients M (F: what the series cannot fix, mostly
  the ``reference_ray`` weights' approximation); the probe renders M = 16
  with the default weights, then -- unless that meets the target -- the M
  predicted as if its error were all series (F = 0), which is the answer
  when it meets the target and otherwise gives F and C.  Where F alone misses the target the
  rule switches to ``weights="exact"`` (which removes most of F) and picks
  M from the series term C·M^k alone.

* ``minmax_epipolar`` (Yusov 2013 §3 initial integration samples): relMSE
  = C·s^k in the initial step s (samples between integration samples);
  the probe renders s = 16 and 4, which give the scene's C and k (k
  clamped to ``FIT["minmax_epipolar"]["k_range"]``, set a priori: the
  suite's frontier runs have no minmax sweep to fit it on); the largest
  candidate step predicted to meet the target.

Where a probe renders the whole image (tree, filter, minmax), it renders
its cheaper setting first and stops there when that setting's error
already meets the target: the rule returns it.  The tree's and the
filter's second probe setting is their predicted answer, returned when it
meets the target.  Either way the render reuses the probe's own render of
the setting returned (:func:`kept_render`) when that is the render asked
for (the whole frame, one sample per pixel centre, output ``full``, the
same seed).

The chosen settings, the probe's errors and its time go into the render's
``RenderResult.stats`` (``auto_settings``, ``auto_probe``,
``auto_probe_s``, ``auto_reused``) and ``timings["probe"]``; the render
itself is that of an integrator built with the chosen settings (or the
probe's render of them), so it equals an explicit render with them.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
import numpy as np


QUALITIES = ("explicit", "auto")
#: pixel centres the probe measures its errors on (a strided subset; 300
#: and a 512-step reference estimate the relMSE within 2x in 90 % of the
#: cases, ``experiments.error_budget``'s probe table)
PROBE_PIXELS = 300
#: steps of the exact marcher the probe's errors are measured against
REFERENCE_STEPS = 512
#: the budget's share the rule aims at (the probe's estimate is noisy)
SAFETY = 0.5
#: steps of the marcher's probe
MARCH_PROBE = (64, 128)
#: candidate slice spacings [px] and light-ray densities of the tree
TREE_SPACINGS = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)
TREE_DENSITIES = (0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0)
#: the tree's probe: slice spacing s0 and densities rho0, 4 rho0
TREE_PROBE = (2.0, 0.5, 2.0)
#: candidate coefficients of the filter, and its probe
FILTER_COEFFICIENTS = (8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)
FILTER_PROBE = (16, 32)
#: candidate initial steps of minmax_epipolar, and its probe
MINMAX_STEPS = (1, 2, 4, 8, 16, 32)
MINMAX_PROBE = (16, 4)

#: constants fitted on results/frontier/quick640 and quick160 (pixel
#: centres) by ``python -m experiments.error_budget --fit-only``
FIT = {
    "raymarch": {"k": -1.99, "k_range": (-4.0, -1.0)},
    "epipolar_tree": {"a": 1.9, "b": 1.1, "time": (0.543, 0.354, 0.102)},
    "fourier_filter": {"k": -1.62},
    "minmax_epipolar": {"k": 1.0, "k_range": (0.5, 3.0)},
}


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
    given = sorted(k for k in RULES[method]["knobs"] if k in props)
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


def settings_key(settings: dict) -> tuple:
    """A hashable key of a settings dict (its items, sorted)."""
    return tuple(sorted(settings.items()))


def subset_relmse(test: np.ndarray, ref: np.ndarray, eps: float = 1e-2) -> float:
    """DESIGN §2's scale-free relMSE of two (pixels, 3) arrays."""
    floor = eps * float(np.mean(ref)) ** 2
    d2 = (np.asarray(test, np.float64) - ref) ** 2
    if floor <= 0:
        return 0.0 if not d2.any() else math.inf
    return float(np.mean(d2 / (ref.astype(np.float64) ** 2 + floor)))


class Probe:
    """The probe of one scene (module doc): renders settings of a method at
    one sample per pixel centre and measures them on :func:`probe_pixels`
    against the exact marcher on those pixels (``pixels``, ``steps``:
    :data:`PROBE_PIXELS`, :data:`REFERENCE_STEPS` unless given).  Its
    full-image renders are kept (:attr:`kept`, by settings) so that a
    render asking for one of them again reuses it (:func:`render_auto`)."""

    def __init__(self, scene, sensor, method: str, base: dict, pixels: int | None = None,
                 steps: int | None = None, seed=0):
        import mitsuba as mi

        self.scene, self.sensor, self.method, self.seed = scene, sensor, method, seed
        #: one sample per pixel centre, the full image, whatever the render asks
        self.base = {k: v for k, v in base.items()
                     if k not in ("samples_per_pixel", "jitter_pixels", "output")}
        s = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
        self.width, self.height = (int(v) for v in s.film().crop_size())
        self.pixels = probe_pixels(self.width, self.height, pixels or PROBE_PIXELS)
        self.mask = np.zeros(self.width * self.height, bool)
        self.mask[self.pixels] = True
        ref = mi.load_dict({"type": "raymarch", "visibility": "exact",
                            "steps": steps or REFERENCE_STEPS})
        self.reference = self.values(ref, partial=True)
        self.errors = []
        #: settings key -> RenderResult of each full-image probe render
        self.kept = {}

    def render(self, integrator, partial=False):
        """RenderResult of ``integrator`` at one sample per pixel centre (a
        partial render of the probe pixels where the method marches
        samples alone)."""
        kw = {"samples": self.mask} if partial else {}
        return integrator.render_layers(self.scene, self.sensor, seed=self.seed, spp=1, **kw)

    def values(self, integrator, partial=False, result=None) -> np.ndarray:
        """The output layer of ``integrator`` (or of its ``result``) on the
        probe pixels."""
        res = result if result is not None else self.render(integrator, partial)
        img = np.asarray(res[integrator.output], np.float64)
        return img.reshape(-1, img.shape[-1])[self.pixels]

    def error(self, settings: dict, partial=False) -> float:
        """relMSE of the method at ``settings`` on the probe pixels."""
        import mitsuba as mi

        integ = mi.load_dict({"type": self.method, **self.base, **settings})
        res = self.render(integ, partial)
        if not partial:
            self.kept[settings_key(settings)] = res
        e = subset_relmse(self.values(integ, result=res), self.reference)
        self.errors.append({**settings, "relmse": e})
        return e

    @property
    def diagonal(self) -> float:
        return math.hypot(self.width, self.height)


# --------------------------------------------------------------------------
# Rules: probe -> settings
# --------------------------------------------------------------------------

def target_of(budget: float) -> float:
    return SAFETY * budget


def probe_settings(method: str, diagonal: float) -> list[dict]:
    """The two settings the probe of ``method`` renders (module doc), for an
    image of ``diagonal`` pixels.  The tree's and the filter's rules render
    the first and, in place of the second, their predicted answer
    (:func:`choose_tree`, :func:`choose_filter`; the fixed second setting
    only where there is no prediction); ``experiments.error_budget``
    measures the probe's estimates on this fixed pair."""
    if method == "raymarch":
        return [{"visibility": "exact", "steps": n} for n in MARCH_PROBE]
    if method == "epipolar_tree":
        s0, r0, r1 = TREE_PROBE
        return [{"slice_spacing": s0, "light_rays": light_rays_of(r, diagonal)}
                for r in (r0, r1)]
    if method == "fourier_filter":
        return [{"coefficients": m} for m in FILTER_PROBE]
    if method == "minmax_epipolar":
        return [{"initial_step": s} for s in MINMAX_PROBE]
    raise ValueError(f"no quality='auto' rule for {method!r}: use one of {sorted(RULES)}.")


def probe_errors(probe: Probe, method: str, budget: float):
    """``(first, e1, e2)``: the probe's errors at its two settings of
    ``method`` (:func:`probe_settings`), the cheaper ``first`` rendered
    first; ``e2`` is None when ``e1`` already meets the target (the second
    setting is then not rendered, and the rule returns ``first``, whose
    render the probe keeps)."""
    first, second = probe_settings(method, probe.diagonal)
    e1 = probe.error(first)
    if e1 <= target_of(budget):
        return first, e1, None
    return first, e1, probe.error(second)


def choose_raymarch(probe: Probe, budget: float, fit=None) -> dict:
    """Steps of the exact marcher: relMSE = C n^k through the probe's two
    step counts (k clamped; the fitted k where the probe sees no error)."""
    fit = fit or FIT["raymarch"]
    e1, e2 = (probe.error(p, partial=True) for p in probe_settings("raymarch", probe.diagonal))
    return {"visibility": "exact", "steps": march_steps(e1, e2, budget, fit)}


def march_steps(e1: float, e2: float, budget: float, fit=None) -> int:
    """Steps n with C n^k = SAFETY·budget, C and k from the errors ``e1``,
    ``e2`` at :data:`MARCH_PROBE` (module doc)."""
    fit = fit or FIT["raymarch"]
    n1, n2 = MARCH_PROBE
    if not (e2 > 0 and math.isfinite(e2)):
        return 16
    k = fit["k"]
    if e1 > 0 and math.isfinite(e1):
        k = min(max(math.log(e2 / e1) / math.log(n2 / n1), fit["k_range"][0]), fit["k_range"][1])
    n = n2 * (target_of(budget) / e2) ** (1.0 / k)
    return int(min(max(math.ceil(n), 16), 16384))


def tree_model(e1: float, e2: float, fit=None, second=None):
    """(A, B) of relMSE = A (s/s0)^a + B (rho/rho0)^-b from the probe's
    errors ``e1`` at (s0, rho0) and ``e2`` at ``second`` = (s, rho)
    (default (s0, 4 rho0), :data:`TREE_PROBE`).  A and B are clamped to
    >= 0; where the two settings cannot separate them (both terms scale
    alike), each is given the whole error the probe saw."""
    fit = fit or FIT["epipolar_tree"]
    s0, r0, r1 = TREE_PROBE
    s2, r2 = second if second is not None else (s0, r1)
    u = (s2 / s0) ** fit["a"]
    v = (r2 / r0) ** -fit["b"]
    if abs(v - u) <= 1e-9 * max(u, v):
        share = max(e1, e2 / u)
        return share, share
    B = (e2 - u * e1) / (v - u)
    if B < 0:
        return max(e1, e2 / u), 0.0
    A = e1 - B
    if A < 0:
        return 0.0, max(e1, e2 / v)
    return A, B


def tree_choice(e1: float, e2: float, budget: float, fit=None, second=None):
    """(slice_spacing, density) of least modelled time meeting the target
    (the most accurate candidate if none does), the model through the
    probe's errors (:func:`tree_model`)."""
    return tree_choice_of(*tree_model(e1, e2, fit, second), budget, fit)


def tree_choice_of(A: float, B: float, budget: float, fit=None):
    """:func:`tree_choice` for the model's terms ``A`` and ``B``."""
    fit = fit or FIT["epipolar_tree"]
    s0, r0, _ = TREE_PROBE
    al, be, ga = fit["time"]
    best, most = None, None
    for s in TREE_SPACINGS:
        for r in TREE_DENSITIES:
            err = A * (s / s0) ** fit["a"] + B * (r / r0) ** -fit["b"]
            t = al + be / s + ga * r / s
            if err <= target_of(budget) and (best is None or t < best[0]):
                best = (t, s, r)
            if most is None or (err, t) < most[0]:
                most = ((err, t), s, r)
    return (best[1], best[2]) if best else (most[1], most[2])


def light_rays_of(density: float, diagonal: float) -> int:
    return int(min(max(round(density * diagonal), 32), 32767))


def tree_settings(s: float, r: float, diagonal: float) -> dict:
    return {"slice_spacing": s, "light_rays": light_rays_of(r, diagonal)}


def choose_tree(probe: Probe, budget: float, fit=None) -> dict:
    """Slice spacing and light rays of the tree (module doc): the first probe
    setting if it meets the target; else the setting predicted from its
    error alone (both terms of the model given all of it), rendered as the
    second probe and returned if it meets the target; else the choice of
    the model through both."""
    first = probe_settings("epipolar_tree", probe.diagonal)[0]
    e1 = probe.error(first)
    if e1 <= target_of(budget):
        return first
    s2, r2 = tree_choice_of(e1, e1, budget, fit)
    second = tree_settings(s2, r2, probe.diagonal)
    if second == first:                  # no prediction beyond it: the fixed second probe
        second = probe_settings("epipolar_tree", probe.diagonal)[1]
        s2, r2 = TREE_PROBE[0], TREE_PROBE[2]
    e2 = probe.error(second)
    if e2 <= target_of(budget):
        return second
    return tree_settings(*tree_choice(e1, e2, budget, fit, (s2, r2)), probe.diagonal)


def filter_model(e1: float, e2: float, fit=None, m2: int | None = None) -> tuple[float, float]:
    r"""(F, C) of relMSE = F + C M^k through the probe's errors ``e1`` at
    M = :data:`FILTER_PROBE`\ [0] and ``e2`` at ``m2`` (default
    :data:`FILTER_PROBE`\ [1]) (module doc)."""
    fit = fit or FIT["fourier_filter"]
    m1 = FILTER_PROBE[0]
    m2 = m2 or FILTER_PROBE[1]
    k = fit["k"]
    C = max((e1 - e2) / (m1 ** k - m2 ** k), 0.0)
    return max(e2 - C * m2 ** k, 0.0), C


def filter_settings(e1: float, e2: float, budget: float, fit=None, m2: int | None = None) -> dict:
    """Coefficients M (and weights) of the filter: the smallest candidate
    with F + C M^k within the target; where the floor F alone misses it,
    ``weights="exact"`` and the smallest M with C M^k within it (the most
    coefficients when none is)."""
    fit = fit or FIT["fourier_filter"]
    k = fit["k"]
    F, C = filter_model(e1, e2, fit, m2)
    for M in FILTER_COEFFICIENTS:
        if F + C * M ** k <= target_of(budget):
            return {"coefficients": M}
    for M in FILTER_COEFFICIENTS:
        if C * M ** k <= target_of(budget):
            return {"coefficients": M, "weights": "exact"}
    return {"coefficients": FILTER_COEFFICIENTS[-1], "weights": "exact"}


def predicted_coefficients(e1: float, budget: float, fit=None) -> int:
    """The second probe's M: the smallest candidate above the first probe's
    M whose series term C M^k meets the target if all of the first probe's
    error ``e1`` is series (F = 0)."""
    fit = fit or FIT["fourier_filter"]
    m1 = FILTER_PROBE[0]
    above = [M for M in FILTER_COEFFICIENTS if M > m1]
    for M in above:
        if e1 * (M / m1) ** fit["k"] <= target_of(budget):
            return M
    return above[-1]


def choose_filter(probe: Probe, budget: float, fit=None) -> dict:
    """Coefficients and weights of the filter (module doc): the first probe
    setting if it meets the target; else the M predicted from its error
    alone (:func:`predicted_coefficients`), rendered as the second probe
    and returned if it meets the target; else the model through both."""
    first = probe_settings("fourier_filter", probe.diagonal)[0]
    e1 = probe.error(first)
    if e1 <= target_of(budget):
        return first
    m2 = predicted_coefficients(e1, budget, fit)
    e2 = probe.error({"coefficients": m2})
    if e2 <= target_of(budget):
        return {"coefficients": m2}
    return filter_settings(e1, e2, budget, fit, m2)


def minmax_step(e1: float, e2: float, budget: float, fit=None) -> int:
    """Initial step s with C s^k within the target, C and k through the
    errors ``e1``, ``e2`` at :data:`MINMAX_PROBE` (k clamped; the largest
    candidate predicted to meet it, else 1)."""
    fit = fit or FIT["minmax_epipolar"]
    s1, s2 = MINMAX_PROBE
    if not (e2 > 0 and math.isfinite(e2)):
        return s2 if e2 == 0 else 1
    k = fit["k"]
    if e1 > 0 and math.isfinite(e1):
        k = min(max(math.log(e1 / e2) / math.log(s1 / s2), fit["k_range"][0]), fit["k_range"][1])
    ok = [s for s in MINMAX_STEPS if e2 * (s / s2) ** k <= target_of(budget)]
    return max(ok) if ok else MINMAX_STEPS[0]


def choose_minmax(probe: Probe, budget: float, fit=None) -> dict:
    """Initial step of the min/max method (module doc)."""
    first, e1, e2 = probe_errors(probe, "minmax_epipolar", budget)
    return first if e2 is None else {"initial_step": minmax_step(e1, e2, budget, fit)}


#: method -> the knobs its rule chooses and the rule (probe, budget) -> settings
RULES = {
    "raymarch": {"knobs": ("steps", "visibility"), "choose": choose_raymarch},
    "epipolar_tree": {"knobs": ("slice_spacing", "light_rays", "slices"),
                      "choose": choose_tree},
    "fourier_filter": {"knobs": ("coefficients", "weights"), "choose": choose_filter},
    "minmax_epipolar": {"knobs": ("initial_step",), "choose": choose_minmax},
}


def choose(scene, method: str, budget: float, base: dict | None = None, sensor=0, seed=0):
    """(settings, stats) of ``method`` for ``budget`` on ``scene``: the
    rule's choice and what the probe measured (its errors, its time)."""
    settings, stats, _ = probe_and_choose(scene, method, budget, base, sensor, seed)
    return settings, stats


def probe_and_choose(scene, method: str, budget: float, base: dict | None = None, sensor=0,
                     seed=0):
    """:func:`choose`, and the :class:`Probe` (with its kept renders)."""
    if method not in RULES:
        raise ValueError(f"no quality='auto' rule for {method!r}: use one of {sorted(RULES)}.")
    if not (isinstance(budget, (int, float)) and budget > 0):
        raise ValueError(f"error budget {budget!r} must be a positive relMSE, e.g. 1e-4.")
    t0 = time.perf_counter()
    probe = Probe(scene, sensor, method, base or {}, seed=seed)
    settings = RULES[method]["choose"](probe, float(budget))
    return settings, {"auto_probe": probe.errors, "auto_probe_s": time.perf_counter() - t0,
                      "auto_probe_pixels": int(len(probe.pixels))}, probe


def kept_render(probe: Probe, inner, scene, sensor, spp, settings: dict, partial_args: dict):
    """The probe's render of ``settings`` if it is the render ``inner``
    is asked for (the whole frame, one sample per pixel centre, output
    ``full``, the probe's seed), else None."""
    if any(v is not None for v in partial_args.values()):
        return None
    n = inner.sample_count(scene, sensor, spp)
    if n != 1 or inner.jitters(n) or inner.output != "full":
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
    settings, stats, probe = probe_and_choose(scene, integrator.method_name,
                                              integrator.error_budget, base, sensor, int(seed))
    inner = mi.load_dict({"type": integrator.method_name, **base, **settings})
    result = kept_render(probe, inner, scene, sensor, spp, settings, kw)
    reused = result is not None
    if not reused:
        result = inner.render_layers(scene, sensor, seed, spp, **kw)
    return replace(result, timings={**result.timings, "probe": stats["auto_probe_s"]},
                   stats={**result.stats, **stats, "auto_settings": settings,
                          "auto_reused": reused, "error_budget": integrator.error_budget})
