"""The ``quality="auto"`` rule of ``minmax_epipolar`` (Yusov 2013 §3 initial
integration samples): relMSE = C·s^k in the initial step s (samples between
integration samples); the probe renders s = 16 and 4, which give the scene's
C and k (k clamped to ``FITTED["k_range"]``, set a priori:
the suite's frontier runs have no minmax sweep to fit it on); the largest
candidate step predicted to meet the target -- but the finer probe step
itself where it meets the budget and the render reuses the probe's (a
coarser step would cost a render more) -- or, where the finer probe step
hardly lowers the error (:data:`FLAT_GAIN`), the better of the two
measured steps, flagged where it misses the budget.

The probe and the machinery are :mod:`integrators.core.quality_auto`'s;
the plugin registers :data:`MINMAX_RULE`.
"""
from __future__ import annotations

import math

from ..core.quality_auto import (Probe, QualityRule, clamped_exponent, meets, probe_errors,
                                 settle, target_of)


#: constants fitted on results/frontier/quick640 and quick160 (pixel
#: centres) by ``python -m experiments.error_budget --fit-only``
FITTED = {"k": 1.0, "k_range": (0.5, 3.0)}
#: candidate initial steps of minmax_epipolar, and its probe
MINMAX_STEPS = (1, 2, 4, 8, 16, 32)
MINMAX_PROBE = (16, 4)
#: the least factor by which the probe's finer step must lower the error
#: for the initial step to count as a lever: below it the error lies
#: elsewhere (the slices, the light rays, the epipole's ring) and a still
#: finer step would only cost time (:func:`choose_minmax`)
FLAT_GAIN = 1.25


def minmax_step(e1: float, e2: float, budget: float, fit=None) -> int:
    """Initial step s with C s^k within the target, C and k through the
    errors ``e1``, ``e2`` at :data:`MINMAX_PROBE` (k clamped; the largest
    candidate predicted to meet it, else 1)."""
    s2 = MINMAX_PROBE[1]
    if not (e2 > 0 and math.isfinite(e2)):
        return s2 if e2 == 0 else 1
    ok = [s for s in MINMAX_STEPS if minmax_error(e1, e2, s, fit) <= target_of(budget)]
    return max(ok) if ok else MINMAX_STEPS[0]


def minmax_error(e1: float, e2: float, s: int, fit=None) -> float | None:
    """The model's relMSE C s^k at initial step ``s`` (k through the errors
    at :data:`MINMAX_PROBE`, clamped; None where the probe saw no error)."""
    fit = fit or FITTED
    s1, s2 = MINMAX_PROBE
    if not (e2 > 0 and math.isfinite(e2)):
        return None
    return e2 * (s / s2) ** clamped_exponent(e1, e2, s1, s2, fit)


def choose_minmax(probe: Probe, budget: float, fit=None) -> dict:
    """Initial step of the min/max method (module doc)."""
    first, e1, e2 = probe_errors(probe, minmax_probe, budget)
    if e2 is None:
        probe.predict(e1, "measured")
        return first
    if e2 > 0 and math.isfinite(e1) and e1 < FLAT_GAIN * e2:
        # the finer step hardly helps: keep the better of the two measured
        # settings (both rendered), flagged where it misses the budget
        best, e = (first, e1) if e1 <= e2 else ({"initial_step": MINMAX_PROBE[1]}, e2)
        probe.predict(e, "measured")
        if e > budget:
            probe.unreachable(budget, e, measured=best)
        return best
    s = minmax_step(e1, e2, budget, fit)
    if s > MINMAX_PROBE[1] and getattr(probe, "reusable", False) and meets(probe, e2, budget):
        # the finer probe step meets the budget and the render after the
        # probe reuses its render: returning it costs nothing, where the
        # model's coarser step would cost one more render
        s = MINMAX_PROBE[1]
    if s == MINMAX_PROBE[1]:
        probe.predict(e2, "measured")
    else:
        settle(probe, {"initial_step": s}, budget,
               minmax_error(e1, e2, s, fit) if e2 > 0 else e2)
    return {"initial_step": s}


def minmax_probe(diagonal: float) -> list[dict]:
    """The two settings the probe renders for an image of ``diagonal`` pixels."""
    return [{"initial_step": s} for s in MINMAX_PROBE]


#: the rule the plugin registers (:func:`~integrators.core.quality_auto.register_rule`)
MINMAX_RULE = QualityRule(knobs=("initial_step",), probe=minmax_probe,
                          choose=choose_minmax, fit=FITTED)
