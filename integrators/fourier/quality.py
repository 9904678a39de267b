"""The ``quality="auto"`` rule of ``fourier_filter`` (Klehm 2014 §3 truncated
Fourier series): relMSE = F + C·M^k in the coefficients M (F: what the
series cannot fix, mostly the ``reference_ray`` weights' approximation); the
probe renders the defaults' M (:data:`FILTER_PROBE`) with the default
weights, then -- unless that meets the target -- the M predicted as if its
error were all series (F = 0), which is the answer when it meets the target
and otherwise gives F and C. Where F alone misses the target the rule
switches to ``weights="exact"`` (which removes most of F) and picks M from
the series term C·M^k alone.  Where that prediction needs more than
:data:`FLOOR_TEST_M` coefficients, the second probe is the first M with
``weights="exact"`` instead: at the same M the two errors separate F and
C·M^k directly, and a floor-bound error (a spot or point light's
reference-ray weights: relMSE 1e-4 to 6e-4 at every M on held-out scenes)
does not cost a render of 96-256 coefficients first.

The first probe is the defaults' M, not fewer: the series' cost hardly
depends on M up to there (on the suite's frontier runs at 640x480,
results/frontier/quick640, 32 coefficients render in 0.94-1.07x the time
of 16, at a third to a tenth of their relMSE), so a cheaper first probe
only saves a render that meets fewer budgets.

Where the method's defaults take the exact visibility sum instead of the
series (a directional light, ``visibility="exact_directional"``), the
series only approximates that sum: the rule measures the defaults and
returns them, flagged over budget where they miss it (no setting of the
series does better; on the held-out thick-fog shafts the series gave
relMSE 0.03-0.8 at any M where the defaults gave 3e-6).

The probe and the machinery are :mod:`integrators.core.quality_auto`'s;
the plugin registers :data:`FILTER_RULE`.
"""
from __future__ import annotations

from ..core.quality_auto import Probe, QualityRule, meets, settle, target_of
from .basis import DEFAULT_M


#: constants fitted on results/frontier/quick640 and quick160 (pixel
#: centres) by ``python -m experiments.error_budget --fit-only``
FITTED = {"k": -1.62}
#: candidate coefficients of the filter, and its probe (the defaults' M,
#: then twice that: module doc)
FILTER_COEFFICIENTS = (8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)
FILTER_PROBE = (DEFAULT_M, 2 * DEFAULT_M)
#: the most coefficients the second probe renders with the default weights
#: (module doc); a larger prediction tests the floor at the first probe's M
FLOOR_TEST_M = 64


def filter_model(e1: float, e2: float, fit=None, m2: int | None = None) -> tuple[float, float]:
    r"""(F, C) of relMSE = F + C M^k through the probe's errors ``e1`` at
    M = :data:`FILTER_PROBE`\ [0] and ``e2`` at ``m2`` (default
    :data:`FILTER_PROBE`\ [1]) (module doc)."""
    fit = fit or FITTED
    m1 = FILTER_PROBE[0]
    m2 = m2 or FILTER_PROBE[1]
    k = fit["k"]
    C = max((e1 - e2) / (m1 ** k - m2 ** k), 0.0)
    return max(e2 - C * m2 ** k, 0.0), C


def filter_settings(e1: float, e2: float, budget: float, fit=None, m2: int | None = None,
                    safe: bool = False) -> dict:
    """Coefficients M (and weights) of the filter: the smallest candidate
    with F + C M^k within the target; where the floor F alone misses it,
    ``weights="exact"`` and the smallest M with C M^k within it (the most
    coefficients when none is); ``safe``: never fewer than the defaults'
    :data:`~integrators.fourier.basis.DEFAULT_M`."""
    return filter_choice(*filter_model(e1, e2, fit, m2), budget, fit, safe)


def filter_choice(F: float, C: float, budget: float, fit=None, safe: bool = False) -> dict:
    """:func:`filter_settings` from the model's floor ``F`` and series
    constant ``C``."""
    floor = DEFAULT_M if safe else 0
    for M in FILTER_COEFFICIENTS:
        if M < floor:
            continue
        if filter_error(F, C, M, False, fit) <= target_of(budget):
            return {"coefficients": M}
    for M in FILTER_COEFFICIENTS:
        if M < floor:
            continue
        if filter_error(F, C, M, True, fit) <= target_of(budget):
            return {"coefficients": M, "weights": "exact"}
    return {"coefficients": FILTER_COEFFICIENTS[-1], "weights": "exact"}


def filter_error(F: float, C: float, M: int, exact_weights: bool, fit=None) -> float:
    """The model's relMSE at M coefficients: F + C M^k, or C M^k with
    ``weights="exact"`` (which removes the floor F)."""
    fit = fit or FITTED
    return (0.0 if exact_weights else F) + C * M ** fit["k"]


def predicted_coefficients(e1: float, budget: float, fit=None) -> int:
    """The second probe's M: the smallest candidate above the first probe's
    M whose series term C M^k meets the target if all of the first probe's
    error ``e1`` is series (F = 0)."""
    fit = fit or FITTED
    m1 = FILTER_PROBE[0]
    above = [M for M in FILTER_COEFFICIENTS if M > m1]
    for M in above:
        if e1 * (M / m1) ** fit["k"] <= target_of(budget):
            return M
    return above[-1]


def choose_filter(probe: Probe, budget: float, fit=None) -> dict:
    """Coefficients and weights of the filter (module doc): the defaults
    where they take the exact sum (:func:`exact_by_default`); else the
    first probe setting if it meets the target; else the M predicted from
    its error alone (:func:`predicted_coefficients`) -- or, where that is
    more than :data:`FLOOR_TEST_M`, the first M with exact weights
    (:func:`floor_model`) -- rendered as the second probe and returned if
    it meets the target; else the model through both."""
    if exact_by_default(probe):
        e0 = probe.error({})
        probe.predict(e0, "measured")
        if e0 > budget:
            probe.unreachable(budget, e0)
        return {}
    first = filter_probe(probe.diagonal)[0]
    e1 = probe.error(first)
    if meets(probe, e1, budget):
        probe.predict(e1, "measured")
        return first
    m1, m2 = first["coefficients"], predicted_coefficients(e1, budget, fit)
    if m2 > FLOOR_TEST_M:                # test the floor at the same M (module doc)
        second = {"coefficients": m1, "weights": "exact"}
        model = lambda e2: floor_model(e1, e2, m1, fit)
    else:
        second = {"coefficients": m2}
        model = lambda e2: filter_model(e1, e2, fit, m2)
    e2 = probe.error(second)
    if meets(probe, e2, budget):
        probe.predict(e2, "measured")
        return second
    F, C = model(e2)
    settings = filter_choice(F, C, budget, fit, safe=True)   # a guess: not below 32
    settle(probe, settings, budget,
           filter_error(F, C, settings["coefficients"], "weights" in settings, fit))
    return settings


def floor_model(e1: float, e_exact: float, m: int, fit=None) -> tuple[float, float]:
    """(F, C) of relMSE = F + C M^k from the errors at the same ``m`` with
    the default weights (``e1``) and with ``weights="exact"``
    (``e_exact``, the series term alone)."""
    fit = fit or FITTED
    return max(e1 - e_exact, 0.0), e_exact / m ** fit["k"]


def exact_by_default(probe: Probe) -> bool:
    """Whether the method with the user's other properties (``probe.base``)
    takes the exact visibility sum on this scene (the integrator's own
    ``exact_visibility``: a directional light, no property of the series);
    False for a probe without a scene (errors given, as in tests)."""
    import mitsuba as mi

    from ..core.scene_params import SceneParams

    if getattr(probe, "scene", None) is None:
        return False
    integ = mi.load_dict({"type": probe.method, **probe.base})
    return bool(integ.exact_visibility(SceneParams.from_scene(probe.scene, probe.sensor)))


def filter_probe(diagonal: float) -> list[dict]:
    """The two settings the probe renders for an image of ``diagonal`` pixels."""
    return [{"coefficients": m} for m in FILTER_PROBE]


#: the rule the plugin registers (:func:`~integrators.core.quality_auto.register_rule`)
FILTER_RULE = QualityRule(knobs=("coefficients", "weights"), probe=filter_probe,
                          choose=choose_filter, fit=FITTED)
