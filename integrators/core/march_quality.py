"""The ``quality="auto"`` rule of ``raymarch`` (exact visibility, Baran 2010
§2's reference marcher): relMSE = C·n^k in the steps n; the probe marches
the subset at :data:`MARCH_PROBE` steps, which gives the scene's own C and k
(k clamped to ``FITTED["k_range"]``) -- at a loose budget
(:data:`~integrators.core.quality_auto.LOOSE_BUDGET`) the coarser
:data:`LOOSE_MARCH_PROBE`, nearer the few steps such a budget needs and
cheaper beside a render of them.

The probe and the machinery are :mod:`integrators.core.quality_auto`'s;
the plugin registers :data:`MARCH_RULE`.
"""
from __future__ import annotations

import math

from .quality_auto import LOOSE_BUDGET, Probe, QualityRule, clamped_exponent, target_of


#: constants fitted on results/frontier/quick640 and quick160 (pixel
#: centres) by ``python -m experiments.error_budget --fit-only``
FITTED = {"k": -1.99, "k_range": (-4.0, -1.0)}
#: steps of the marcher's probe
MARCH_PROBE = (64, 128)
#: steps of the marcher's probe at a loose budget: such a budget needs
#: tens of steps, where the probe's two partial renders and its reference
#: cost about a render of the answer; a choice beyond
#: :data:`LOOSE_REFIT_STEPS` is refitted through it and its finer count
LOOSE_MARCH_PROBE = (16, 32)
LOOSE_REFIT_STEPS = 128
#: a choice beyond this many steps is refitted through it (:func:`choose_raymarch`)
REFIT_STEPS = 512
#: a refitted choice beyond this many steps is refitted again through
#: :data:`REFIT_STEPS` and this count
FAR_REFIT_STEPS = 2048


def choose_raymarch(probe: Probe, budget: float, fit=None) -> dict:
    """Steps of the exact marcher: relMSE = C n^k through the probe's two
    step counts (k clamped; the fitted k where the probe sees no error).
    Where that asks for more than :data:`REFIT_STEPS`, the slope measured
    between the probe's coarse counts is no guide (shadow edges converge
    as n^-1 until the steps resolve them, then faster): the model is fitted
    again through the probe's finer count and :data:`REFIT_STEPS`, both
    against the finer reference, so a far extrapolation does not choose
    tens of times the steps the budget needs -- and where that still asks
    for more than :data:`FAR_REFIT_STEPS`, once more through those two
    counts (:func:`refit`)."""
    fit = fit or FITTED
    pair = LOOSE_MARCH_PROBE if budget >= LOOSE_BUDGET else MARCH_PROBE
    e1, e2 = (probe.error({"visibility": "exact", "steps": m}, partial=True) for m in pair)
    n = march_steps(e1, e2, budget, fit, pair)
    predicted = march_error(e1, e2, n, fit, pair)
    if pair == LOOSE_MARCH_PROBE and n > LOOSE_REFIT_STEPS and predicted is not None:
        # the coarse slope is no guide that far: through the finer count and
        # LOOSE_REFIT_STEPS, against the probe's own reference (a loose
        # budget's target is far above its error)
        n, predicted = refit(probe, pair[1], LOOSE_REFIT_STEPS, budget, fit, fine=False)
    if n > REFIT_STEPS and predicted is not None:
        n, predicted = refit(probe, MARCH_PROBE[1], REFIT_STEPS, budget, fit)
        if n > FAR_REFIT_STEPS and predicted is not None:
            # still far: the slope through REFIT_STEPS is no guide either (a
            # spot's thin shafts, held-out seed 2066: 5,060 steps for 1e-4
            # where 512 met it, 10x the time)
            n, predicted = refit(probe, REFIT_STEPS, FAR_REFIT_STEPS, budget, fit)
    probe.predict(predicted, "model")
    if predicted is not None and predicted > target_of(budget):
        probe.unreachable(budget, predicted)
    return {"visibility": "exact", "steps": n}


def refit(probe: Probe, lo: int, hi: int, budget: float, fit, fine: bool = True) -> tuple:
    """(steps, predicted relMSE) of relMSE = C n^k through the errors at
    ``lo`` and ``hi`` steps against the finer reference (``fine``; else the
    probe's own) (k clamped); (``hi``, None) where ``hi`` already matches
    that reference."""
    f_lo, f_hi = (probe.error({"visibility": "exact", "steps": m}, partial=True, fine=fine)
                  for m in (lo, hi))
    if not (f_hi > 0 and math.isfinite(f_hi)):
        return hi, None
    k = clamped_exponent(f_hi, f_lo, hi, lo, fit)
    n = int(min(max(math.ceil(hi * (target_of(budget) / f_hi) ** (1.0 / k)), lo), 16384))
    return n, f_hi * (n / hi) ** k


def march_exponent(e1: float, e2: float, fit=None, pair=MARCH_PROBE) -> float:
    """k of relMSE = C n^k through the errors at the probe's step counts
    ``pair`` (clamped to the fit's range; the fitted k where e1 shows
    nothing)."""
    n1, n2 = pair
    return clamped_exponent(e2, e1, n2, n1, fit or FITTED)


def march_steps(e1: float, e2: float, budget: float, fit=None, pair=MARCH_PROBE) -> int:
    """Steps n with C n^k = SAFETY·budget, C and k from the errors ``e1``,
    ``e2`` at the step counts ``pair`` (module doc)."""
    n2 = pair[1]
    if not (e2 > 0 and math.isfinite(e2)):
        return 16
    n = n2 * (target_of(budget) / e2) ** (1.0 / march_exponent(e1, e2, fit, pair))
    return int(min(max(math.ceil(n), 16), 16384))


def march_error(e1: float, e2: float, n: int, fit=None, pair=MARCH_PROBE) -> float | None:
    """The model's relMSE at ``n`` steps (None where the probe saw no error)."""
    if not (e2 > 0 and math.isfinite(e2)):
        return None
    return e2 * (n / pair[1]) ** march_exponent(e1, e2, fit, pair)


def march_probe(diagonal: float) -> list[dict]:
    """The two settings the probe renders for an image of ``diagonal`` pixels."""
    return [{"visibility": "exact", "steps": n} for n in MARCH_PROBE]


#: the rule the plugin registers (:func:`~integrators.core.quality_auto.register_rule`)
MARCH_RULE = QualityRule(knobs=("steps", "visibility"), probe=march_probe,
                         choose=choose_raymarch, fit=FITTED)
