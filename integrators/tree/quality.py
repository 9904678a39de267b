"""The ``quality="auto"`` rule of ``epipolar_tree`` (Baran 2010 §8 slices, §7
light rays): relMSE = A·(s/s₀)^a + B·(ρ/ρ₀)^-b in the slice spacing s [px]
and the light-ray density ρ (light rays per slice over the image diagonal in
pixels; the light-ray term is the tree's error floor at fixed light rays);
the probe renders (s₀, ρ₀), then -- unless its measured error meets the
budget (:func:`~integrators.core.quality_auto.meets`) -- a second
setting: the one the model predicts from that error alone, whichever term
holds it (the worst split of A + B), where that is cheap, else (s₀, 4ρ₀),
which separates A and B (:func:`second_probe`); the second is the answer
when it meets the budget, otherwise the model through both chooses; time
~ α + β/s + γ·ρ/s (fitted).

The probe and the machinery are :mod:`integrators.core.quality_auto`'s;
the plugin registers :data:`TREE_RULE`.
"""
from __future__ import annotations

import math

from ..core.quality_auto import Probe, QualityRule, meets, settle, target_of
from ..epipolar.light_rays.directional import MIN_AUTO_LIGHT_RAYS


#: constants fitted on results/frontier/quick640 and quick160 (pixel
#: centres) by ``python -m experiments.error_budget --fit-only``
FITTED = {"a": 1.9, "b": 1.1, "time": (0.543, 0.354, 0.102)}
#: candidate slice spacings [px] and light-ray densities of the tree
TREE_SPACINGS = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)
TREE_DENSITIES = (0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0)
#: the defaults' slice spacing [px] and light-ray density: a setting the
#: rule's model predicts (the probe did not measure it) is never coarser
DEFAULT_SPACING, DEFAULT_DENSITY = 1.0, 1.0
#: the tree's probe: slice spacing s0 and densities rho0, 4 rho0
TREE_PROBE = (2.0, 0.5, 2.0)
#: the most a predicted second probe may cost, in fixed second probes
#: (:func:`second_probe`): the fixed one and the render after it
PREDICTION_COST = 2.0


def tree_model(e1: float, e2: float, fit=None, second=None):
    """(A, B) of relMSE = A (s/s0)^a + B (rho/rho0)^-b from the probe's
    errors ``e1`` at (s0, rho0) and ``e2`` at ``second`` = (s, rho)
    (default (s0, 4 rho0), :data:`TREE_PROBE`).  A and B are clamped to
    >= 0; where the two settings cannot separate them (both terms scale
    alike), each is given the whole error the probe saw."""
    fit = fit or FITTED
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


def tree_choice_of(A: float, B: float, budget: float, fit=None, safe: bool = False,
                   finest=None):
    """:func:`tree_choice` for the model's terms ``A`` and ``B``; ``safe``:
    among the settings at least as fine as the defaults only; ``finest``:
    (s, rho) of a measured setting the candidates must be at least as fine
    as in each term the model could not resolve (A or B 0)."""
    fit = fit or FITTED
    s0, r0, _ = TREE_PROBE
    max_s = finest[0] if finest is not None and A == 0 else math.inf
    min_r = finest[1] if finest is not None and B == 0 else 0.0
    best, most = None, None
    for s in TREE_SPACINGS:
        for r in TREE_DENSITIES:
            if safe and (s > DEFAULT_SPACING or r < DEFAULT_DENSITY):
                continue
            if s > max_s or r < min_r:
                continue
            err = tree_error(A, B, s, r, fit)
            t = tree_time(s, r, fit)
            if err <= target_of(budget) and (best is None or t < best[0]):
                best = (t, s, r)
            if most is None or (err, t) < most[0]:
                most = ((err, t), s, r)
    return (best[1], best[2]) if best else (most[1], most[2])


def tree_error(A: float, B: float, s: float, r: float, fit=None) -> float:
    """The model's relMSE A (s/s0)^a + B (rho/rho0)^-b at spacing ``s`` and
    light-ray density ``r``."""
    fit = fit or FITTED
    s0, r0, _ = TREE_PROBE
    return A * (s / s0) ** fit["a"] + B * (r / r0) ** -fit["b"]


def light_rays_of(density: float, diagonal: float) -> int:
    return int(min(max(round(density * diagonal), 32), 32767))


def tree_settings(s: float, r: float, diagonal: float) -> dict:
    return {"slice_spacing": s, "light_rays": light_rays_of(r, diagonal)}


def tree_time(s: float, r: float, fit=None) -> float:
    """The time model alpha + beta/s + gamma rho/s of spacing ``s`` and
    light-ray density ``r`` (relative units)."""
    al, be, ga = (fit or FITTED)["time"]
    return al + be / s + ga * r / s


def second_probe(e1: float, budget: float, fit=None) -> tuple[float, float]:
    """(s, rho) of the tree's second probe after the first missed the target
    with ``e1``: the setting predicted from ``e1`` alone (whichever term
    holds it, :func:`worst_split_choice`), kept when its measured error
    meets the budget (:func:`~integrators.core.quality_auto.meets`), where
    the time model says it costs at most :data:`PREDICTION_COST` fixed second probes (s0, 4 rho0)
    -- what the fixed one and the render after it would cost; otherwise
    that fixed one, which separates the two terms with a coarse render (a
    prediction from one error far over the target asks for the finest
    setting of both knobs: several times the cost of the setting the two
    terms, once separated, call for)."""
    s0, _, r1 = TREE_PROBE
    guess = worst_split_choice(e1, budget, fit)
    if guess is not None and \
            tree_time(*guess, fit) <= PREDICTION_COST * tree_time(s0, r1, fit):
        return guess
    return s0, r1


def worst_split_choice(e1: float, budget: float, fit=None):
    """(s, rho) of least modelled time that meets the target however the
    probe's error ``e1`` splits between the two terms (A + B = e1; the model
    is linear in the split, so its two ends: all of it in either term), or
    None where no candidate does."""
    best = None
    for s in TREE_SPACINGS:
        for r in TREE_DENSITIES:
            if max(tree_error(e1, 0.0, s, r, fit), tree_error(0.0, e1, s, r, fit)) \
                    <= target_of(budget):
                t = tree_time(s, r, fit)
                if best is None or t < best[0]:
                    best = (t, s, r)
    return None if best is None else best[1:]


def choose_tree(probe: Probe, budget: float, fit=None) -> dict:
    """Slice spacing and light rays of the tree (module doc): the first probe
    setting if it meets the target; else the second probe
    (:func:`second_probe`), returned if it meets the target; else the
    choice of the model through both."""
    first = tree_probe(probe.diagonal)[0]
    e1 = probe.error(first)
    if meets(probe, e1, budget):
        probe.predict(e1, "measured")
        return first
    s2, r2 = second_probe(e1, budget, fit)
    second = tree_settings(s2, r2, probe.diagonal)
    if second == first:                  # no prediction beyond it: the fixed second probe
        second = tree_probe(probe.diagonal)[1]
        s2, r2 = TREE_PROBE[0], TREE_PROBE[2]
    e2 = probe.error(second)
    if meets(probe, e2, budget):
        probe.predict(e2, "measured")
        return second
    A, B = tree_model(e1, e2, fit, (s2, r2))
    # a guess: never coarser than the defaults, nor than the second probe in
    # a term the two probes could not separate (the fit set it to 0)
    s, r = tree_choice_of(A, B, budget, fit, safe=True, finest=(s2, r2))
    settings = tree_settings(s, r, probe.diagonal)
    settings["light_rays"] = max(settings["light_rays"], MIN_AUTO_LIGHT_RAYS)
    settle(probe, settings, budget, tree_error(A, B, s, r, fit))
    return settings


def tree_probe(diagonal: float) -> list[dict]:
    """The two settings the probe renders for an image of ``diagonal`` pixels."""
    s0, r0, r1 = TREE_PROBE
    return [{"slice_spacing": s0, "light_rays": light_rays_of(r, diagonal)} for r in (r0, r1)]


#: the rule the plugin registers (:func:`~integrators.core.quality_auto.register_rule`)
TREE_RULE = QualityRule(knobs=("slice_spacing", "light_rays", "slices"), probe=tree_probe,
                        choose=choose_tree, fit=FITTED)
