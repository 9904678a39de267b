"""quality="auto" with an error_budget (issue 16, item 4): property
validation, the rules' monotonicity in the budget, an auto render equal to
the explicit render of its choice, and the fit of the committed constants."""
from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import pytest

from integrators.core import quality_auto as qa
from integrators.core import march_quality as rq
from integrators.tree import quality as tq
from integrators.fourier import quality as fq
from integrators.minmax import quality as mq

METHODS = ("raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar")


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("props, match", [
    ({"quality": "auto", "error_budget": 0.0}, "positive relMSE"),
    ({"quality": "auto", "error_budget": -1e-4}, "positive relMSE"),
    ({"error_budget": 1e-4}, "add quality='auto'"),
    ({"quality": "explicit", "error_budget": 1e-4}, "add quality='auto'"),
    ({"quality": "auto"}, "needs an error_budget"),
    ({"quality": "best", "error_budget": 1e-4}, "is not one of"),
])
def test_quality_properties_are_validated(method, props, match):
    with pytest.raises(Exception, match=match):
        mi.load_dict({"type": method, **props})


@pytest.mark.parametrize("method, knob", [("raymarch", {"steps": 64}),
                                          ("minmax_epipolar", {"initial_step": 4}),
                                          ("epipolar_tree", {"slice_spacing": 2.0}),
                                          ("fourier_filter", {"coefficients": 16})])
def test_auto_refuses_the_knobs_it_chooses(method, knob):
    with pytest.raises(Exception, match="chooses"):
        mi.load_dict({"type": method, "quality": "auto", "error_budget": 1e-4, **knob})


def test_auto_needs_a_rule(monkeypatch):
    monkeypatch.delitem(qa.RULES, "minmax_epipolar")
    with pytest.raises(Exception, match="no rule for 'minmax_epipolar'"):
        mi.load_dict({"type": "minmax_epipolar", "quality": "auto", "error_budget": 1e-4})


@pytest.mark.parametrize("e1, e2", [(7.8e-4, 2.3e-4), (5.7e-5, 4.6e-6), (1e-4, 1e-4), (0.0, 0.0)])
def test_minmax_step_shrinks_with_the_budget(e1, e2):
    steps = [mq.minmax_step(e1, e2, b) for b in BUDGETS]
    assert steps == sorted(steps, reverse=True)


def test_minmax_step_meets_a_power_law():
    """Errors C s^1.5 at the probe's steps: the chosen s is the largest
    candidate with C s^1.5 <= SAFETY * budget."""
    C = 1e-6
    s1, s2 = mq.MINMAX_PROBE
    s = mq.minmax_step(C * s1 ** 1.5, C * s2 ** 1.5, 2e-5)
    assert C * s ** 1.5 <= qa.SAFETY * 2e-5 < C * (2 * s) ** 1.5


BUDGETS = (1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 1e-6)


@pytest.mark.parametrize("e1, e2", [(1e-3, 2.5e-4), (1e-4, 9e-5), (1e-2, 1e-4), (0.0, 0.0)])
def test_march_steps_grow_as_the_budget_shrinks(e1, e2):
    steps = [rq.march_steps(e1, e2, b) for b in BUDGETS]
    assert steps == sorted(steps)


def test_march_steps_meet_a_power_law():
    """Errors C n^-2 at the probe's steps: the chosen n has C n^-2 = SAFETY * budget."""
    C = 3.0
    n1, n2 = rq.MARCH_PROBE
    n = rq.march_steps(C * n1 ** -2.0, C * n2 ** -2.0, 1e-5)
    assert C * n ** -2.0 == pytest.approx(qa.SAFETY * 1e-5, rel=0.02)


@pytest.mark.parametrize("e1, e2", [(1e-3, 9e-4), (1e-4, 2e-5), (3e-5, 3e-5), (1e-6, 1e-7)])
def test_tree_choice_is_monotone_in_the_budget(e1, e2):
    fit = qa.FIT["epipolar_tree"]
    A, B = tq.tree_model(e1, e2)
    s0, r0, _ = tq.TREE_PROBE
    pred = [A * (s / s0) ** fit["a"] + B * (r / r0) ** -fit["b"]
            for s, r in (tq.tree_choice(e1, e2, b) for b in BUDGETS)]
    assert all(p2 <= p1 * (1 + 1e-12) for p1, p2 in zip(pred, pred[1:]))


def filter_prediction(e1, e2, settings):
    """The rule's modelled relMSE of ``settings`` (exact weights: the series term)."""
    F, C = fq.filter_model(e1, e2)
    series = C * settings["coefficients"] ** qa.FIT["fourier_filter"]["k"]
    return series if settings.get("weights") == "exact" else F + series


@pytest.mark.parametrize("e1, e2", [(1e-3, 3e-4), (1e-4, 1e-4), (2e-3, 1e-5)])
def test_filter_prediction_shrinks_with_the_budget(e1, e2):
    pred = [filter_prediction(e1, e2, fq.filter_settings(e1, e2, b)) for b in BUDGETS]
    assert all(p2 <= p1 * (1 + 1e-12) for p1, p2 in zip(pred, pred[1:]))


def test_a_far_marcher_extrapolation_is_refitted_on_finer_steps():
    """The marcher's probe sees n^-1 between 64 and 128 steps (shadow edges
    not yet resolved) where the error then falls as n^-3: extrapolating the
    first slope to 1e-4 asked for 5,120 steps (the user's room: 11,916 steps,
    26x more accurate than asked).  The rule refits through 128 and 512
    steps against the finer reference and stays within the budget's steps."""
    coarse = [4e-3, 2e-3]                                  # k = -1
    fine = [2e-3, 2e-3 * 4.0 ** -3]                        # 128, 512 steps: k = -3
    unrefitted = rq.march_steps(*coarse, 1e-4)
    probe = FixedProbe(coarse + fine)
    choice = rq.choose_raymarch(probe, 1e-4)
    assert unrefitted >= 5000
    assert [a.get("fine", False) for a in probe.asked] == [False, False, True, True]
    needed = 512 * (qa.SAFETY * 1e-4 / fine[1]) ** (1 / -3.0)   # the true law's steps
    assert choice["steps"] == pytest.approx(needed, rel=0.02)
    assert choice["steps"] * 10 < unrefitted
    assert probe.predicted <= qa.SAFETY * 1e-4 * 1.001


def test_a_still_far_marcher_choice_is_refitted_through_2048_steps():
    """The refit through 128 and 512 steps can still see n^-1 (the probe's
    pixels overestimate the error of a spot's thin shafts more at 512 steps
    than at 128: held-out seed 2066 chose 5,060 steps for 1e-4, which 512
    met, 10x the time).  Beyond 2,048 steps the rule measures 2,048 and
    refits through 512 and 2,048."""
    coarse, fine = [4e-3, 2e-3], [2e-3, 4.9e-4]            # k = -1 to 512 steps
    far = [4.9e-4, 1e-5]                                   # 512, 2048 steps: k = -2.8
    probe = FixedProbe(coarse + fine + far)
    choice = rq.choose_raymarch(probe, 1e-4)
    assert [a["steps"] for a in probe.asked] == [64, 128, 128, 512, 512, 2048]
    k = math.log(far[1] / far[0]) / math.log(4.0)
    needed = 2048 * (qa.SAFETY * 1e-4 / far[1]) ** (1 / k)
    assert choice["steps"] == math.ceil(needed) < 2048
    # without the second refit: 512 (4.9e-4 / 5e-5) ~ 5,000 steps
    assert rq.refit(FixedProbe(fine), 128, 512, 1e-4, qa.FIT["raymarch"])[0] > 4000


def test_a_loose_marcher_budget_is_probed_at_few_steps():
    """A 1e-3 budget needs tens of steps: the probe marches 16 and 32
    (64 and 128 cost more than the render they choose, held-out user
    scenes at 320x240), extrapolates through them, and refits through 32
    and 128 steps against its own reference where that asks for more."""
    probe = FixedProbe([2e-3, 5e-4])                       # k = -2: ~30 steps
    choice = rq.choose_raymarch(probe, 1e-3)
    assert [a["steps"] for a in probe.asked] == list(rq.LOOSE_MARCH_PROBE)
    assert choice["steps"] == math.ceil(32 * (qa.SAFETY * 1e-3 / 5e-4) ** (1 / -2.0))
    far = FixedProbe([4e-2, 2e-2, 2e-2, 2e-2 * 4.0 ** -3])  # k = -1, then -3 to 128
    choice = rq.choose_raymarch(far, 1e-3)
    assert [(a["steps"], a.get("fine", False)) for a in far.asked] == \
        [(16, False), (32, False), (32, False), (128, False)]
    needed = 128 * (qa.SAFETY * 1e-3 / (2e-2 * 4.0 ** -3)) ** (1 / -3.0)
    assert choice["steps"] == math.ceil(needed)
    # a tighter budget keeps the finer pair
    probe = FixedProbe([1e-3, 2.5e-4])
    rq.choose_raymarch(probe, 1e-4)
    assert [a["steps"] for a in probe.asked] == list(rq.MARCH_PROBE)


def test_a_near_marcher_choice_is_not_refitted():
    probe = FixedProbe([1e-3, 2.5e-4])                     # k = -2: 1e-4 needs ~160 steps
    choice = rq.choose_raymarch(probe, 1e-4)
    assert choice["steps"] <= rq.REFIT_STEPS and len(probe.asked) == 2


class FixedProbe:
    """A probe whose errors are given (the rules' input without a render)."""

    def __init__(self, errors, diagonal=200.0):
        self.errors, self.diagonal, self.asked = list(errors), diagonal, []

    def error(self, settings, partial=False, fine=False):
        self.asked.append({**settings, **({"fine": True} if fine else {})})
        return self.errors.pop(0)

    def predict(self, relmse, how):
        self.predicted, self.predicted_from = relmse, how

    def unreachable(self, budget, relmse, measured=None):
        self.over_budget = (budget, relmse)


def test_minmax_keeps_a_measured_step_where_a_finer_one_does_not_help():
    """Held-out window rooms and canopies at 1e-5: steps 16 and 4 measure
    8.2e-6 and 7.8e-6 (the error lies in the slices, not the initial
    samples); the rule chose step 1 from the clamped exponent and rendered
    it for 7.9e-6 at 1.5x the time.  Now the better measured step is kept,
    flagged only where it misses the budget."""
    probe = FixedProbe([8.2e-6, 7.8e-6])
    assert mq.choose_minmax(probe, 1e-5) == {"initial_step": mq.MINMAX_PROBE[1]}
    assert len(probe.asked) == 2 and probe.predicted == 7.8e-6
    assert probe.predicted_from == "measured" and not hasattr(probe, "over_budget")
    probe = FixedProbe([2.5e-5, 2.6e-5])
    assert mq.choose_minmax(probe, 1e-5) == {"initial_step": mq.MINMAX_PROBE[0]}
    assert probe.over_budget == (1e-5, 2.5e-5) and len(probe.asked) == 2
    # a finer step that helps is still extrapolated
    probe = FixedProbe([8e-6, 2e-6])
    assert mq.choose_minmax(probe, 1e-5) == {"initial_step": mq.minmax_step(8e-6, 2e-6, 1e-5)}


def test_minmax_returns_its_measured_finer_step_where_the_render_reuses_it():
    """Held-out seed 2020 at 640x480, 1e-5: steps 16 and 4 measured 1e-5 and
    2.4e-6 (4 meets the budget), the model picked 8 and the probe rendered
    it too -- three renders where the measured 4, whose render the probe
    keeps, costs none.  Where the render does not reuse the probe's, the
    model's coarser step is the cheaper render and stays."""
    assert mq.minmax_step(4e-5, 5e-7, 1e-5) == 8
    probe = FixedProbe([4e-5, 5e-7])
    probe.reusable = True
    assert mq.choose_minmax(probe, 1e-5) == {"initial_step": mq.MINMAX_PROBE[1]}
    assert len(probe.asked) == 2 and (probe.predicted, probe.predicted_from) == (5e-7,
                                                                                 "measured")
    probe = FixedProbe([4e-5, 5e-7])
    assert mq.choose_minmax(probe, 1e-5) == {"initial_step": 8}
    assert len(probe.asked) == 2 and probe.predicted_from == "model"


def test_a_stratified_probe_takes_a_measured_setting_within_its_margin():
    """A setting measured at 0.7x the budget on a stratified sample (an
    estimate within 1.5x of the image's in 9 of 10 cases) is taken; on a
    strided one (down to 1/100 of it on thin shafts) the rule renders a
    finer setting; a model's prediction still aims at SAFETY."""
    first = qa.probe_settings("epipolar_tree", 200.0)[0]
    stratified = FixedProbe([7e-6])
    stratified.weights = np.ones(1)
    assert tq.choose_tree(stratified, 1e-5) == first and len(stratified.asked) == 1
    strided = FixedProbe([7e-6, 1e-6])
    assert tq.choose_tree(strided, 1e-5) != first and len(strided.asked) == 2
    assert qa.meets(stratified, qa.MEASURED_SAFETY * 1e-5, 1e-5)
    assert not qa.meets(strided, qa.MEASURED_SAFETY * 1e-5, 1e-5)
    assert qa.MEASURED_SAFETY < 1 and qa.target_of(1e-5) == qa.SAFETY * 1e-5


def test_tree_model_recovers_both_terms_from_any_second_setting():
    fit = qa.FIT["epipolar_tree"]
    s0, r0, _ = tq.TREE_PROBE
    A, B = 2e-4, 5e-5
    for s2, r2 in ((1.0, 2.0), (s0, 4 * r0), (0.5, 0.5), (4.0, 8.0)):
        e2 = A * (s2 / s0) ** fit["a"] + B * (r2 / r0) ** -fit["b"]
        assert tq.tree_model(A + B, e2, second=(s2, r2)) == pytest.approx((A, B), rel=1e-9)
    # both terms scaled alike: not separable, each gets the whole error
    assert tq.tree_model(1e-4, 1e-4, second=(s0, r0)) == (1e-4, 1e-4)


def test_tree_renders_its_prediction_second_and_keeps_it_when_it_meets_the_target():
    """The first probe just misses a 1e-5 budget (relMSE 8e-6 for a target
    of 5e-6); the second probe is the setting predicted from that error
    alone -- meeting the target whichever term holds it, cheaper than
    giving each term all of it (held-out scenes: 3-10x more accurate than
    the target at up to twice the time) -- no dearer than the fixed
    second probe, and its error (1e-6) meets the budget, so it is the
    answer (its probe render reused)."""
    s0, _, r1 = tq.TREE_PROBE
    s, r = tq.worst_split_choice(8e-6, 1e-5)
    assert tq.second_probe(8e-6, 1e-5) == (s, r)
    assert tq.tree_time(s0, r1) < tq.tree_time(s, r) <= tq.PREDICTION_COST * tq.tree_time(s0, r1)
    for A, B in ((8e-6, 0.0), (0.0, 8e-6), (4e-6, 4e-6)):
        assert tq.tree_error(A, B, s, r) <= qa.target_of(1e-5)
    assert tq.tree_time(s, r) < tq.tree_time(*tq.tree_choice_of(8e-6, 8e-6, 1e-5))
    probe = FixedProbe([8e-6, 1e-6])
    got = tq.choose_tree(probe, 1e-5)
    first = qa.probe_settings("epipolar_tree", probe.diagonal)[0]
    assert probe.asked[0] == first and probe.asked[1] == got != first
    assert got == tq.tree_settings(s, r, probe.diagonal)
    # when the prediction misses too, the model through both errors decides
    probe = FixedProbe([8e-6, 4e-6 / 0.5 * 0.9])
    got = tq.choose_tree(probe, 1e-5)
    assert probe.asked[1] == tq.tree_settings(s, r, probe.diagonal)
    A, B = tq.tree_model(8e-6, 7.2e-6, second=(s, r))
    want = tq.tree_settings(*tq.tree_choice_of(A, B, 1e-5, safe=True), probe.diagonal)
    want["light_rays"] = max(want["light_rays"], 256)
    assert got == want


def test_tree_separates_its_two_terms_when_the_prediction_is_dear():
    """The first probe misses a 1e-5 budget by 200x: the setting predicted
    from that error alone is the finest of both knobs (relMSE 3e-7 to 1e-6
    at 5-10x the time of the setting that meets the budget, on held-out
    scenes), so the second probe is the fixed (s0, 4 rho0), which separates
    the slice-spacing and light-ray terms; kept when it meets the target,
    else the model through both decides."""
    s0, _, r1 = tq.TREE_PROBE
    assert tq.tree_choice_of(1e-3, 1e-3, 1e-5) == (min(tq.TREE_SPACINGS), max(tq.TREE_DENSITIES))
    assert tq.second_probe(1e-3, 1e-5) == (s0, r1)
    fixed = qa.probe_settings("epipolar_tree", 200.0)
    probe = FixedProbe([1e-3, 1e-6])
    assert tq.choose_tree(probe, 1e-5) == fixed[1] == probe.asked[1]
    assert probe.predicted_from == "measured"
    # the light rays' term dominates (e2 = e1 / 4^b): the model keeps the
    # spacing no finer than the defaults need and buys light rays
    fit = qa.FIT["epipolar_tree"]
    probe = FixedProbe([1e-3, 1e-3 * 4 ** -fit["b"]])
    got = tq.choose_tree(probe, 1e-5)
    assert probe.predicted_from == "model"
    assert got["slice_spacing"] == tq.DEFAULT_SPACING
    assert got["light_rays"] > fixed[1]["light_rays"]


def test_filter_renders_its_prediction_second():
    m1 = fq.FILTER_PROBE[0]
    k = qa.FIT["fourier_filter"]["k"]
    m2 = fq.predicted_coefficients(1.2e-5, 1e-5)
    assert m1 < m2 <= fq.FLOOR_TEST_M and 1.2e-5 * (m2 / m1) ** k <= qa.SAFETY * 1e-5
    assert fq.predicted_coefficients(1.0, 1e-5) == fq.FILTER_COEFFICIENTS[-1]
    probe = FixedProbe([1.2e-5, 1e-6])
    assert fq.choose_filter(probe, 1e-5) == {"coefficients": m2} == probe.asked[1]
    F, C = 2e-5, 0.4
    e = [F + C * m ** k for m in (m1, 64)]
    assert fq.filter_model(*e, m2=64) == pytest.approx((F, C), rel=1e-9)


def test_filter_probes_its_defaults_first():
    """The filter's first probe is its defaults' 32 coefficients, not 16:
    on the suite's frontier runs 32 render in the time of 16 at a third to
    a tenth of the error, and a probe that started at 16 rendered a second
    and often a third image for budgets the defaults meet (held-out seed
    2011 at 640x480, 1e-5: 16 coefficients 1.1e-5, then 32 at 4.4e-6 --
    2.2x the time of rendering 32 alone)."""
    from integrators.fourier.basis import DEFAULT_M

    probe = FixedProbe([4.4e-6])
    assert fq.choose_filter(probe, 1e-5) == {"coefficients": DEFAULT_M}
    assert probe.asked == [{"coefficients": DEFAULT_M}] and probe.predicted_from == "measured"


def test_filter_floor_above_the_budget_switches_to_exact_weights():
    """A held-out point light (seed 2 of experiments.random_scenes 'shafts'):
    reference-ray weights level off at relMSE 4.6e-5 whatever the
    coefficients, so a 1e-5 budget needs weights='exact' (the rule used to
    return 16 coefficients, 5x over the budget)."""
    got = qa.RULES["fourier_filter"].choose(FixedProbe([4.61e-5, 4.17e-5]), 1e-5)
    assert got.get("weights") == "exact"
    assert "weights" not in qa.RULES["fourier_filter"].choose(
        FixedProbe([4.61e-5, 4.17e-5]), 1e-4)


def test_filter_tests_its_floor_before_a_dear_prediction():
    """Held-out spot lights at 640x480 (seeds 2004, 2020): 16 coefficients
    measure 5e-4 whatever M (the reference-ray weights' floor); the
    series-only prediction for 1e-4 asked for 96 coefficients (1.4 s, the
    same 5e-4) before the model switched to exact weights.  Now a
    prediction above FLOOR_TEST_M tests the floor at the same M with exact
    weights, kept when it meets the budget; where it does not, the floor
    and series terms it separates choose."""
    m1 = fq.FILTER_PROBE[0]
    assert fq.predicted_coefficients(5e-4, 1e-4) > fq.FLOOR_TEST_M
    probe = FixedProbe([5e-4, 3e-6])
    got = fq.choose_filter(probe, 1e-4)
    assert got == {"coefficients": m1, "weights": "exact"} == probe.asked[1]
    assert len(probe.asked) == 2 and probe.predicted_from == "measured"
    # the series term, not the floor: exact weights hardly help, so the
    # model buys coefficients with exact weights (the floor is gone there)
    probe = FixedProbe([1e-4, 9e-5])
    got = fq.choose_filter(probe, 1e-5)
    k = qa.FIT["fourier_filter"]["k"]
    assert got["weights"] == "exact" and 9e-5 * (got["coefficients"] / m1) ** k <= 0.5e-5
    assert all(a.get("coefficients", 0) <= fq.FLOOR_TEST_M for a in probe.asked)


def test_probe_pixels_stride_the_image():
    idx = qa.probe_pixels(160, 120, 1200)
    assert len(idx) == 1200 and len(set(idx.tolist())) == 1200
    assert len(qa.probe_pixels(128, 96)) == pytest.approx(qa.PROBE_PIXELS, rel=0.15)
    assert len(qa.probe_pixels(3, 2, 1200)) == 6


def slow_relmse(test, ref, eps=1e-2):
    """DESIGN §2's scale-free relMSE over every pixel, written out."""
    floor = eps * np.mean(ref) ** 2
    return float(np.mean((test - ref) ** 2 / (ref ** 2 + floor)))


def test_a_stratified_sample_of_every_pixel_is_the_plain_relmse():
    rng = np.random.default_rng(3)
    ref = rng.random((12, 10, 3)) + 0.05
    test = ref * (1 + 0.1 * rng.standard_normal(ref.shape))
    every = np.arange(120)
    strata = qa.Strata(every, qa.edge_pixels(test), 120, 30)
    assert sorted(strata.pixels.tolist()) == every.tolist()
    assert strata.weights.sum() == pytest.approx(1.0)
    flat, flat_ref = test.reshape(-1, 3), ref.reshape(-1, 3)
    got = qa.subset_relmse(flat[strata.pixels], flat_ref[strata.pixels], weights=strata.weights)
    assert got == pytest.approx(slow_relmse(test, ref), rel=1e-12)
    assert qa.subset_relmse(flat, flat_ref) == pytest.approx(slow_relmse(test, ref), rel=1e-12)


def test_a_stratified_probe_sees_the_error_of_a_thin_shaft():
    """A lit shaft one pixel wide across a dark image, wrong by 30 % in the
    test image, and nothing else wrong: the strided pixels step over it
    (the estimate is 0 -- held-out seed 2000's spot shafts: 1/100 of the
    true relMSE), the edge pixels hold it and the stratified estimate is
    within 1.5x of the whole image's relMSE, unbiased over the choice of
    the edge sample (its mean over shifted picks within 5 %)."""
    h, w = 240, 320
    ref = np.full((h, w, 3), 0.05)
    ref[:, 101] = 1.0                                  # the shaft
    test = ref.copy()
    test[:, 101] *= 1.3
    true = slow_relmse(test, ref)
    flat, flat_ref = test.reshape(-1, 3), ref.reshape(-1, 3)
    strided = qa.probe_pixels(w, h, qa.PROBE_PIXELS - qa.EDGE_PIXELS)
    assert qa.subset_relmse(flat[strided], flat_ref[strided]) == 0.0
    edges = qa.edge_pixels(test)
    assert np.isin(np.arange(h) * w + 101, edges).all()
    strata = qa.Strata(strided, edges, h * w, qa.EDGE_PIXELS)
    est = qa.subset_relmse(flat[strata.pixels], flat_ref[strata.pixels], weights=strata.weights)
    assert true / 1.5 <= est <= true * 1.5
    # the same estimate from every shift of the edge picks: unbiased on average
    ests = []
    for shift in range(8):
        picks = np.roll(edges, shift)
        st = qa.Strata(strided, picks, h * w, qa.EDGE_PIXELS)
        ests.append(qa.subset_relmse(flat[st.pixels], flat_ref[st.pixels], weights=st.weights))
    assert np.mean(ests) == pytest.approx(true, rel=0.05)


def test_a_probe_stratifies_on_its_first_full_render(make_scene):
    """The tree's probe: its first render is a full image, so its pixels
    become strided ones and edge ones before the reference is marched; the
    marcher's (partial renders) keeps the strided pixels; an image of fewer
    pixels than the probe's is measured on every pixel."""
    scene = make_scene(res=(80, 60))
    probe = qa.Probe(scene, 0, "epipolar_tree", {})
    e = probe.error({"slice_spacing": 2.0, "light_rays": 64})
    assert math.isfinite(e) and 0 < probe.edge_pixels <= qa.EDGE_PIXELS
    assert probe.weights is not None and probe.weights.sum() == pytest.approx(1.0)
    assert len(probe.reference) == len(probe.pixels) == probe.mask.sum()
    march = qa.Probe(scene, 0, "raymarch", {})
    march.error({"visibility": "exact", "steps": 16}, partial=True)
    assert march.edge_pixels == 0 and march.weights is None
    small = qa.Probe(make_scene(), 0, "epipolar_tree", {})
    small.error({"slice_spacing": 2.0, "light_rays": 64})
    assert sorted(small.pixels.tolist()) == list(range(32 * 24))


def test_the_edge_stratum_keeps_its_density_on_a_large_image():
    """A 640x480 image with a thin shaft (error 30 %) among many weaker
    edges (a faint stripe every fourth column): the edge stratum is the
    most contrasted :data:`~qa.EDGE_STRATUM` pixels, not 5 % of the image,
    so its samples land on the shaft as densely as at 320x240 and the
    stratified estimate is within 2x of the true relMSE for every shift
    of the edge picks (0.58-1.16x; a 5 % stratum, 15,360 pixels, misses
    the shaft for a third of them: 0)."""
    h, w = 480, 640
    ref = np.full((h, w, 3), 0.05)
    ref[:, ::4] = 0.08                                 # the weaker edges
    ref[:40, 201] = 1.0                                # the shaft
    test = ref.copy()
    test[:40, 201] *= 1.3
    true = slow_relmse(test, ref)
    flat, flat_ref = test.reshape(-1, 3), ref.reshape(-1, 3)
    strided = qa.probe_pixels(w, h, qa.PROBE_PIXELS - qa.EDGE_PIXELS)
    edges = qa.edge_pixels(test)
    assert len(edges) == qa.EDGE_STRATUM and np.isin(np.arange(40) * w + 201, edges).all()
    assert len(qa.edge_pixels(test[:240, :320])) == round(qa.EDGE_SHARE * 240 * 320)
    for shift in range(16):
        st = qa.Strata(strided, np.roll(edges, shift), h * w, qa.EDGE_PIXELS)
        est = qa.subset_relmse(flat[st.pixels], flat_ref[st.pixels], weights=st.weights)
        assert true / 2 <= est <= true * 2


def test_the_probe_marches_its_edge_stratum_against_the_edge_reference(make_scene,
                                                                       monkeypatch):
    """Where the edge stratum is capped (here at 120 of the 240 pixels 5 %
    would take), its pixels are measured against the edge reference
    whatever the budget's reference (the coarser ones err on exactly those
    sharpest edges), the rest against the budget's; both are the
    marcher's values on those pixels.  Uncapped, one reference: the
    budget's."""
    scene = make_scene(res=(80, 60))
    plain = qa.Probe(scene, 0, "epipolar_tree", {}, loose=True)
    plain.error({"slice_spacing": 2.0, "light_rays": 64})
    assert plain.edge.any() and plain.edge_props is None
    assert list(plain._marched) == [(qa.settings_key(qa.LOOSE_BISECTED_REFERENCE), "all")]
    monkeypatch.setattr(qa, "EDGE_STRATUM", 120)
    probe = qa.Probe(scene, 0, "epipolar_tree", {}, loose=True)
    probe.error({"slice_spacing": 2.0, "light_rays": 64})
    assert probe.edge is not None and probe.edge.any() and (~probe.edge).any()
    assert probe.edge_props == qa.EDGE_BISECTED_REFERENCE
    assert probe.reference_props == qa.LOOSE_BISECTED_REFERENCE

    def full(props):
        integ = mi.load_dict({"type": "raymarch", "visibility": "exact", **props})
        img = np.asarray(integ.render_layers(scene, spp=1)[integ.output], np.float64)
        return img.reshape(-1, img.shape[-1])[probe.pixels]

    edge_ref, rest_ref = full(qa.EDGE_BISECTED_REFERENCE), full(qa.LOOSE_BISECTED_REFERENCE)
    assert np.allclose(probe.reference[probe.edge], edge_ref[probe.edge], rtol=1e-5, atol=1e-9)
    assert np.allclose(probe.reference[~probe.edge], rest_ref[~probe.edge], rtol=1e-5, atol=1e-9)
    fine = probe.fine_reference()
    assert np.array_equal(fine[probe.edge], probe.reference[probe.edge])


@pytest.mark.parametrize("method", METHODS)
def test_auto_render_equals_the_explicit_render_of_its_choice(make_scene, method):
    scene = make_scene()
    auto = mi.load_dict({"type": method, "quality": "auto", "error_budget": 1e-4})
    res = auto.render_layers(scene, spp=1)
    settings = res.stats["auto_settings"]
    assert set(settings) <= set(qa.RULES[method].knobs)
    assert res.stats["auto_probe_s"] > 0 and res.timings["probe"] > 0
    assert len(res.stats["auto_probe"]) >= 1
    same = mi.load_dict({"type": method, **settings}).render_layers(scene, spp=1)
    assert np.array_equal(np.asarray(res["full"]), np.asarray(same["full"]))


@pytest.mark.parametrize("method", ["epipolar_tree", "fourier_filter"])
def test_a_loose_budget_keeps_the_probe_render(make_scene, method):
    """A budget the cheaper probe setting already meets: the rule stops after
    one probe render and returns that render (``auto_reused``), which is the
    explicit render of the choice, bit for bit, at the same seed; a request
    the probe did not render (4 jittered samples per pixel) renders anew.
    (A point light: with a directional light the filter's defaults are
    the exact sum, which its rule keeps.)"""
    scene = make_scene(light="point")
    auto = mi.load_dict({"type": method, "quality": "auto", "error_budget": 1e3})
    res = auto.render_layers(scene, seed=3, spp=1)
    first = qa.probe_settings(method, 200.0)[0]
    assert len(res.stats["auto_probe"]) == 1 and res.stats["auto_reused"]
    assert set(res.stats["auto_settings"]) == set(first)
    same = mi.load_dict({"type": method, **res.stats["auto_settings"]}).render_layers(
        scene, seed=3, spp=1)
    assert np.array_equal(np.asarray(res["full"]), np.asarray(same["full"]))
    jittered = auto.render_layers(scene, spp=4)
    assert not jittered.stats["auto_reused"]


def test_auto_via_mi_render(make_scene):
    scene = make_scene()
    img = mi.render(scene, integrator=mi.load_dict({"type": "raymarch", "quality": "auto",
                                                    "error_budget": 1e-3}), spp=1)
    assert np.all(np.isfinite(np.asarray(img)))


def fixture_rows():
    """Frontier-like rows whose errors and times follow the committed model
    exactly (two scenes per method, 640x480)."""
    fit = qa.FIT
    rows = []
    base = {"convention": "pixel_centre", "width": 640, "height": 480}
    diag = math.hypot(640, 480)
    for scene, C in (("a.xml", 1e-2), ("b.xml", 3.0)):
        for n in (64, 256, 1024):
            rows.append({**base, "scene": scene, "method": "raymarch", "time_s": 1.0,
                         "params": {"visibility": "exact", "steps": n},
                         "relmse": C * n ** fit["raymarch"]["k"]})
        for M in (16, 32, 64, 128):
            rows.append({**base, "scene": scene, "method": "fourier_filter", "time_s": 1.0,
                         "params": {"coefficients": M, "weights": "reference_ray"},
                         "relmse": C * M ** fit["fourier_filter"]["k"]})
        tree = fit["epipolar_tree"]
        al, be, ga = tree["time"]
        for s in (0.5, 1.0, 2.0, 4.0):
            for L in (0, 512, 1024):
                rho = (L or diag) / diag
                rows.append({**base, "scene": scene, "method": "epipolar_tree",
                             "params": {"slice_spacing": s, "light_rays": L},
                             "relmse": C * 1e-3 * (s ** tree["a"] + 0.5 * rho ** -tree["b"]),
                             "time_s": C * (al + be / s + ga * rho / s)})
    return rows


def test_fit_reproduces_the_committed_constants():
    from experiments.error_budget import fit_constants

    got = fit_constants(fixture_rows())
    fit = qa.FIT
    assert got["raymarch"]["k"] == pytest.approx(fit["raymarch"]["k"], abs=0.01)
    assert got["fourier_filter"]["k"] == pytest.approx(fit["fourier_filter"]["k"], abs=0.01)
    assert got["epipolar_tree"]["a"] == pytest.approx(fit["epipolar_tree"]["a"], abs=0.01)
    assert got["epipolar_tree"]["b"] == pytest.approx(fit["epipolar_tree"]["b"], abs=0.01)
    assert got["epipolar_tree"]["time"] == pytest.approx(fit["epipolar_tree"]["time"], abs=2e-3)


def test_fit_refuses_rows_without_sweeps():
    from experiments.error_budget import fit_constants

    with pytest.raises(ValueError, match="frontier sweep"):
        fit_constants([])


def test_held_out_scenes_are_shafts_the_cycle_never_draws():
    """experiments.random_scenes 'shafts' (the held-out set): σt·B in
    [0.3, 30], 3-8 occluders, and no seed of the stress cycle draws it (the
    cycle's scenes are unchanged)."""
    from experiments import random_scenes as rs

    assert "shafts" not in rs.KIND_CYCLE and "shafts" in rs.FORCED_KINDS
    rs.random_scene(1000, "shafts").load()
    for seed in range(1000, 1012):
        spec = rs.random_scene(seed, "shafts")
        assert 0.3 <= spec.sigma_t * spec.box_half <= 30.0
        assert 3 <= len(spec.occluders) <= 8


def test_every_plugin_registers_its_own_rule():
    """The rules live with their methods (core/march_quality, tree/, fourier/,
    minmax/ quality modules); each plugin module registers its own, so the
    template and the probe know no method by name."""
    import inspect

    from integrators.template import base

    assert sorted(qa.RULES) == ["epipolar_tree", "fourier_filter", "minmax_epipolar", "raymarch"]
    for method, rule in qa.RULES.items():
        assert rule.fit is qa.FIT[method]
        assert len(rule.probe(500.0)) == 2 and all(k in rule.knobs for k in rule.probe(500.0)[0])
    for module in (qa, base):
        source = inspect.getsource(module)
        assert not any(f'"{m}"' in source for m in ("epipolar_tree", "fourier_filter",
                                                      "minmax_epipolar")), module.__name__


@pytest.mark.parametrize("case", [
    ("tree", [1e-3], 1e-2, "measured", 1e-3),        # the first setting meets it
    ("tree", [1e-3, 2e-5], 1e-4, "measured", 2e-5),  # the predicted second meets it
    ("filter", [4.61e-5, 4.17e-5], 1e-5, "model", None),
    ("minmax", [1e-3, 2.5e-4], 1e-5, "model", None),
    ("raymarch", [4e-4, 1e-4, 1e-4, 6e-6], 1e-5, "model", None),
])
def test_every_rule_states_the_error_it_expects(case):
    """The rule records the relMSE it expects of its choice: the probe's
    own measurement when it returns a probed setting, else its model's
    prediction, which meets the target when a candidate does."""
    method, errors, budget, how, value = case
    rule = {"tree": tq.choose_tree, "filter": fq.choose_filter, "minmax": mq.choose_minmax,
            "raymarch": rq.choose_raymarch}[method]
    probe = FixedProbe(errors)
    rule(probe, budget)
    assert probe.predicted_from == how
    if value is not None:
        assert probe.predicted == value
    else:
        assert probe.predicted > 0 and math.isfinite(probe.predicted)


def test_a_model_predicted_setting_is_never_coarser_than_the_defaults():
    """Where the probe did not measure the setting it returns, the rule's
    model is a guess: the tree's spacing and light rays and the filter's
    coefficients stay at least as fine as the defaults (a textured spot
    through thin bars: the model chose slice_spacing=4, 13x over a 1e-5
    budget, where the defaults met it)."""
    # errors that the unconstrained model reads as "the spacing costs nothing"
    e1, e2 = 1e-4, 2.2e-5
    second = tq.tree_choice_of(e1, e1, 1e-5)
    assert tq.tree_choice_of(*tq.tree_model(e1, e2, second=second), 1e-5)[0] == 4.0  # unguarded
    probe = FixedProbe([e1, e2], diagonal=400.0)
    got = tq.choose_tree(probe, 1e-5)
    assert probe.predicted_from == "model"
    assert got["slice_spacing"] <= tq.DEFAULT_SPACING
    assert got["light_rays"] >= max(400, 256)
    # the filter: never fewer coefficients than the defaults' 32 on a guess
    m2 = fq.predicted_coefficients(3e-4, 1.2e-4)
    assert fq.filter_settings(3e-4, 2.9e-4, 1.2e-4, m2=m2)["coefficients"] < 32  # unguarded
    probe = FixedProbe([3e-4, 2.9e-4])
    got = fq.choose_filter(probe, 1.2e-4)
    assert probe.predicted_from == "model" and got["coefficients"] >= 32


def test_a_model_choice_the_render_reuses_is_measured_before_it_is_returned():
    """Where the render after the probe reuses the probe's full renders, a
    setting the model chose is rendered by the probe and measured (no extra
    cost): its measured error is the prediction, and a miss of the budget
    is flagged even where the model expected the target met (held-out
    seeds 2000 and 2018: the filter's exact weights, chosen on a guess,
    ended 5.8x and 11x over a 1e-5 budget unflagged)."""
    cases = [(tq.choose_tree, [1e-3, 1e-3 * 4 ** -qa.FIT["epipolar_tree"]["b"]]),
             (fq.choose_filter, [4.61e-5, 4.17e-5]),
             (mq.choose_minmax, [1e-3, 2.5e-4])]
    for rule, errors in cases:
        for final, flagged in ((4e-6, False), (6e-5, True)):
            probe = FixedProbe(errors + [final])
            probe.reusable, probe.over_budget = True, False
            got = rule(probe, 1e-5)
            assert probe.asked[-1] == got and len(probe.asked) == len(errors) + 1
            assert (probe.predicted, probe.predicted_from) == (final, "measured")
            assert bool(probe.over_budget) == flagged, rule.__name__
        # not reusable: the model's prediction stands, nothing rendered
        probe = FixedProbe(list(errors))
        rule(probe, 1e-5)
        assert probe.predicted_from == "model" and len(probe.asked) == len(errors)


def test_a_budget_no_setting_reaches_is_said():
    """The finest setting is predicted to miss: a warning naming the way out,
    and the stats flag it (the error is not returned over budget silently)."""
    with pytest.warns(UserWarning, match="not expected to reach error_budget"):
        probe = qa.Probe.__new__(qa.Probe)
        probe.method, probe.over_budget = "epipolar_tree", False
        probe.unreachable(1e-7, 3e-5)
    assert probe.over_budget
    probe = FixedProbe([1e-3, 9e-4])
    tq.choose_tree(probe, 1e-9)
    assert probe.over_budget[0] == 1e-9


def test_a_textured_spot_through_thin_bars_meets_a_tight_budget():
    """The issue's first user scene, rebuilt: a textured spot light through a
    lattice of thin bars, ``epipolar_tree`` with error_budget 1e-5.  Probed
    against the 512-step marcher (whose own error on the bars is of that
    order) the rule chose the default spacing with 1,600 light rays and
    reached 3.8e-5; against the finer reference a tight budget now gets,
    it meets the budget within 2x and is never coarser than the defaults."""
    import warnings

    import mitsuba as mi

    from episcatter.metrics import scale_free_relmse
    from tests.conftest import scene_dict

    d = scene_dict(light="spot_textured", res=(160, 120), blocker=None)
    for i in range(9):
        x = -1.0 + 0.25 * i
        bar = {"radius": 0.015, "bsdf": {"type": "diffuse", "reflectance": 0.3}}
        d[f"bar_{i}"] = {"type": "cylinder", "p0": [x, 1.4, -1.5], "p1": [x, 1.4, 1.5], **bar}
        d[f"cross_{i}"] = {"type": "cylinder", "p0": [-1.5, 1.45, x], "p1": [1.5, 1.45, x], **bar}
    scene = mi.load_dict(d)
    ref = np.array(mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 2048,
                                 "boundary_bisections": 12}).render_layers(scene, spp=1)["full"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = mi.load_dict({"type": "epipolar_tree", "quality": "auto", "error_budget": 1e-5}
                              ).render_layers(scene, spp=1)
    settings = result.stats["auto_settings"]
    assert settings["slice_spacing"] <= 1.0
    assert scale_free_relmse(np.array(result["full"]), ref) <= 2e-5


def test_the_tree_keeps_the_light_rays_its_fit_cannot_resolve():
    """The two probe settings differ in a term the fit then sets to 0 (here
    the light rays: the second probe, with 4x the light rays, measured no
    better than the first); the rule used to choose the fewest light rays
    for such a term (the suite's hall at 1e-5: 256 light rays where the
    second probe measured 1,600 -- 147x over the budget).  A term the fit
    cannot resolve is kept at least as fine as the measured setting."""
    e1 = 1e-3
    probe = FixedProbe([e1, 1.1e-3])
    settings = tq.choose_tree(probe, 1e-7)
    second = probe.asked[1]
    assert tq.tree_model(e1, 1.1e-3, second=(second["slice_spacing"],
                                             second["light_rays"] / probe.diagonal))[1] == 0.0
    assert settings["light_rays"] >= second["light_rays"]


def test_the_filter_keeps_its_exact_default_for_a_directional_light():
    """Held-out thick-fog shafts (error_budget seeds 2012, 2016): the series
    at any M missed by 0.03-0.8 relMSE where the defaults -- the exact
    visibility sum for a directional light -- gave 3e-6; the rule chose
    series settings.  It now measures and returns the defaults."""
    import warnings

    import mitsuba as mi

    from experiments.error_budget import scene_spec

    scene = scene_spec(2016, "mixed").at_resolution(48, 36).load()
    default = np.asarray(mi.render(scene, integrator=mi.load_dict({"type": "fourier_filter"}),
                                   spp=1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = mi.load_dict({"type": "fourier_filter", "quality": "auto",
                               "error_budget": 1e-3}).render_layers(scene, spp=1)
    assert result.stats["auto_settings"] == {}
    assert np.array_equal(np.asarray(result["full"]), default)


def test_the_marchers_probe_sees_the_edges_of_a_spot_lit_shaft():
    """Held-out seed 2000 (a spot light's shafts through blockers): the
    marcher's error at 128 steps lies along the shafts' edges.  Measured on
    a 300-pixel subset the probe saw a tenth of the full image's relMSE
    (error_budget 1e-4 chose 180 steps and reached 9e-4); its subset now
    sees it within 2x."""
    from episcatter.metrics import scale_free_relmse
    from experiments.error_budget import scene_spec

    scene = scene_spec(2000, "mixed").at_resolution(128, 96).load()
    probe = qa.Probe(scene, 0, "raymarch", {})
    settings = {"visibility": "exact", "steps": 128}
    estimate = probe.error(settings, partial=True)
    ref = mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 2048})
    true = scale_free_relmse(np.array(mi.load_dict({"type": "raymarch", **settings})
                                      .render_layers(scene, spp=1)["full"]),
                             np.array(ref.render_layers(scene, spp=1)["full"]))
    assert 0.5 * true <= estimate <= 2.0 * true


@pytest.mark.parametrize("seed", [2005, 2045])
def test_minmax_meets_a_loose_budget_in_a_window_lit_room(seed):
    """The issue's second user scene, as the held-out generator writes it:
    a room lit by the sun through a barred window (experiments.user_scenes
    ``window_room``); ``minmax_epipolar`` with error_budget 1e-3 once
    ended 7x over it.  Its render meets the budget within 2x (against the
    exact marcher) or says it cannot."""
    import warnings

    from episcatter.metrics import scale_free_relmse
    from experiments.error_budget import scene_spec

    spec = scene_spec(seed, "mixed")
    assert "window_room" in spec.name
    scene = spec.at_resolution(64, 48).load()
    ref = np.asarray(mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 1024,
                                   "boundary_bisections": 8}).render(scene, spp=1))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = mi.load_dict({"type": "minmax_epipolar", "quality": "auto",
                               "error_budget": 1e-3}).render_layers(scene, spp=1)
    e = scale_free_relmse(np.asarray(result["full"]), ref)
    said = any("not expected to reach" in str(w.message) for w in caught)
    assert e <= 2e-3 or said, (e, result.stats["auto_settings"])
