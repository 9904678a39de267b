"""fourier_filter at its defaults on the stress scenes of issue 12
(:mod:`scenes.fourier_stress`) against ``raymarch visibility=exact``
(scattering only, pixel centres)."""
from functools import lru_cache

import mitsuba as mi
import numpy as np
import pytest

import scenes
from episcatter import metrics
from integrators.fourier.references import (auto_reference_rays, decay_coordinate,
                                            interpolated_kernel_reference)
from integrators.fourier.rows import row_spacing, small_image_scale


@lru_cache(maxsize=None)
def _scene(name, res, sigma_t=None):
    defines = {"res_x": res[0], "res_y": res[1]}
    if sigma_t is not None:
        defines["sigma_t"] = sigma_t
    return mi.load_file(scenes.path(name), **defines)


def _render(name, res, kind, sigma_t=None, **props):
    integ = mi.load_dict({"type": kind, "output": "scattering", **props})
    return np.array(integ.render(_scene(name, res, sigma_t)))


@lru_cache(maxsize=None)
def _reference(name, res, sigma_t=None):
    return _render(name, res, "raymarch", sigma_t, visibility="exact", steps=1024)


@pytest.mark.parametrize("visibility", ["exact_directional", "filter"])
@pytest.mark.parametrize("sigma_t", [0.002, 0.15, 1.0])
def test_energy_right_from_thin_to_thick_fog(sigma_t, visibility):
    """Sun room (~10 m across): σt·size 0.02 to 10, the default (exact sum)
    and the filter with its reference rays.  Klehm's single reference ray
    lost 22 % at σt = 1 (mean ratio 0.78) and 68 % at 3."""
    res = (48, 36)
    img = _render("sun_room", res, "fourier_filter", sigma_t, visibility=visibility)
    ratio = metrics.mean_ratio(img, _reference("sun_room", res, sigma_t))
    assert abs(ratio - 1.0) < 0.02, ratio


def test_single_reference_ray_is_the_paper_and_loses_energy_in_thick_fog():
    """``reference_rays=1`` keeps Klehm's §3.2 weights (and their failure)."""
    res = (48, 36)
    img = _render("sun_room", res, "fourier_filter", 1.0, reference_rays=1)
    assert metrics.mean_ratio(img, _reference("sun_room", res, 1.0)) < 0.9


@pytest.mark.parametrize("name", ["sun_room", "hall", "spot_room", "nave_onscreen",
                                  "sun_behind"])
def test_one_pixel_image(name):
    """1×1 (the scene's 64 antialiased samples in one pixel) was off by up
    to 15× (hall: 0 against 0.0158): its sample read the blockers of a
    slice half the field of view away from its own ray.  Then 8.6 % low
    (nave_onscreen, sun_behind: the (anti-)epipole within half a pixel of
    an edge, whose wedge got no slices at the small image's fine spacing;
    rectify.slices)."""
    img = _render(name, (1, 1), "fourier_filter")
    ref = _reference(name, (1, 1))
    assert float(img.mean()) == pytest.approx(float(ref.mean()), rel=0.02, abs=1e-3 * float(ref.max()))


def test_small_image_rows():
    assert small_image_scale(640, 480) == 1.0
    assert small_image_scale(1, 1) == pytest.approx(1 / 32)
    assert row_spacing(1.0, 16, 12) == pytest.approx(0.5)


def test_interpolated_reference_weights_follow_the_query_kernel():
    """The mix of the two nearest reference rays (NumPy oracle) weights the
    texels as the query's own kernel does, within a few per cent of the
    total weight, wherever the rays are spaced by SPACING in s; one
    reference ray (Klehm) is off by whole factors in thick fog."""
    sigma_t, length = 1.0, 10.0
    gamma = np.linspace(0.0, length, 2001)
    lo, hi = 0.3, 2.6
    span = decay_coordinate(hi, sigma_t, length) - decay_coordinate(lo, sigma_t, length)
    count = auto_reference_rays(float(span))
    for beta in np.linspace(lo, hi, 37):
        own = np.exp(-sigma_t * gamma * np.tan(0.5 * beta))
        mix = interpolated_kernel_reference(gamma, beta, lo, hi, sigma_t, length, count)
        assert np.abs(mix / mix.sum() - own / own.sum()).sum() < 0.05, beta
    one = interpolated_kernel_reference(gamma, lo, lo, hi, sigma_t, length, 1)
    own = np.exp(-sigma_t * gamma * np.tan(0.5 * lo))
    assert np.abs(one / one.sum() - own / own.sum()).sum() > 0.5


# --------------------------------------------------------------------------
# The exact visibility sum (integrators.fourier.exact)
# --------------------------------------------------------------------------

def _exact_inputs(name="sun_room", res=(24, 18)):
    """The rectified inputs of one fourier_filter render (channel 0)."""
    from integrators.core.capture import capture_camera
    from integrators.core.scene_params import SceneParams

    scene = _scene(name, res)
    integ = mi.load_dict({"type": "fourier_filter", "output": "scattering"})
    params = SceneParams.from_scene(scene)
    cap = capture_camera(params, spp=1, jitter=False, seed=0, surface=False)
    frame, slices, plan = integ.choose_rows(params, cap)
    from integrators.epipolar.queries import assign_queries
    queries = assign_queries(params, frame, slices, cap, integ.ring_degrees)
    captured = {}

    def spy(params_, queries_, rays, smap, cover, parts, sigma_t, length=0.0, beta_b=None,
            tail=None, kernels=None):
        captured.update(params=params_, queries=queries_, rays=rays, cover=cover, L=parts.L,
                        sigma_t=sigma_t, beta_b=beta_b)
        return parts.unshadowed(cover, queries_), dr.full(mi.Float, 1.0, queries_.count), None

    integ.channel_sums = spy
    integ.rectified_sums(params, cap, queries)
    return captured


def _exact_average_numpy(inp) -> np.ndarray:
    """NumPy oracle: the direct weighted sum of module fourier_exact, float64."""
    q, rays = inp["queries"], inp["rays"]
    d = rays.d
    row, beta = np.asarray(q.row), np.asarray(q.beta, np.float64)
    texel, frac = np.asarray(inp["cover"].texel), np.asarray(inp["cover"].frac, np.float64)
    _, gamma = rays.positions(0.0)
    gamma, L = np.asarray(gamma, np.float64), np.asarray(inp["L"], np.float64)
    beta_b = np.asarray(inp["beta_b"], np.float64)
    out = np.ones(len(beta))
    for i in range(len(beta)):
        g = np.arange(row[i] * d, texel[i] + 1)
        w = L[g] * np.exp(-inp["sigma_t"] * gamma[g] * np.tan(0.5 * beta[i]))
        w[-1] *= frac[i]
        if w.sum() > 0:
            out[i] = (w * (beta[i] <= beta_b[g])).sum() / w.sum()
    return out


import drjit as dr  # noqa: E402


def test_exact_average_matches_its_numpy_oracle():
    from integrators.fourier.exact import exact_average

    inp = _exact_inputs()
    args = (inp["params"], inp["queries"], inp["rays"], inp["beta_b"], inp["cover"], inp["L"],
            inp["sigma_t"])
    oracle = _exact_average_numpy(inp)
    for recurrence in (True, False):
        V = np.asarray(exact_average(*args, recurrence=recurrence))
        np.testing.assert_allclose(V, oracle, atol=2e-4)
    assert 0.05 < oracle.mean() < 0.95          # shadows in the rows: a real test


@pytest.mark.parametrize("name", ["sun_room", "hall"])
def test_exact_visibility_has_no_leak(name):
    """The filter (M = 32, the series alone) puts light on reference-black fog (receivers
    just behind their blockers); the exact sum (the default) far less (what
    is left: a sample answered on its nearest slice, blockers per texel)."""
    res = (64, 48)
    ref = _reference(name, res)
    peak = ref.max()
    black = ref.mean(-1) < 1e-4 * peak
    assert black.sum() > 100
    img = _render(name, res, "fourier_filter")
    filt = _render(name, res, "fourier_filter", coefficients=32, exact_fallback=False,
                   trace_ends=False)
    leak, leak_filter = (float(np.mean(x.mean(-1)[black])) / peak for x in (img, filt))
    assert leak < 0.5 * leak_filter, (leak, leak_filter)


def test_beam_shaft_edges_bounded_at_the_defaults():
    """``beam`` (a sun shaft through a ceiling hole, its edges along the
    slices): a sample answered on its nearest slice across the shaft's edge
    put 0.6-0.7 of the peak on reference-black pixels (relMSE 55.7 at
    320×240, 4.6e-2 here).  The default now shares each sample between its
    two slices and ray-marches those whose slices disagree
    (``remarch_disagreement``, the template's, as ``epipolar_tree``)."""
    from integrators.template.epipolar import EpipolarIntegrator

    res = (80, 60)
    ref = _reference("beam", res)
    integ = mi.load_dict({"type": "fourier_filter", "output": "scattering"})
    assert integ.slice_interpolation
    result = integ.render_layers(_scene("beam", res))      # the scene's sampler, as _render
    img = np.array(result["scattering"])
    assert result.stats["remarched"] > 0
    assert metrics.scale_free_relmse(img, ref) < 5e-3
    assert abs(metrics.mean_ratio(img, ref) - 1.0) < 0.02
    assert type(integ).remarch_disagreeing is EpipolarIntegrator.remarch_disagreeing
    # slices a pixel apart (the scene's samples would draw them closer)
    off = _render("beam", res, "fourier_filter", remarch_disagreement=1.0, slice_spacing=1.0)
    assert metrics.scale_free_relmse(off, ref) > 5e-3


# --------------------------------------------------------------------------
# The randomised stress set (experiments.random_scenes) at the defaults
# --------------------------------------------------------------------------

#: seed: what it was at commit db10601 (the README's first stress run) and
#: which shared fix bounds it now
RANDOM_SEEDS = {
    0: "spot 61x17: relMSE 2.4e-2; the nearest of slices too sparse for a small image "
       "(choose_slices: images under MIN_SLICE_PIXELS are sliced as if that wide)",
    2: "spot at the eye 24x18: relMSE 1.2e-2, mean 0.98; the same slices",
    4: "point 1e-2 px off a pixel's ray: mean 1.07; the ring's equiangular steps took 1/r² "
       "at midpoints (marching: exact ∫dt/r² per segment; 8x ring steps at the light)",
    7: "narrow spot 17x13: relMSE 28, mean 0.92; the same slices",
}


def _random_case(seed, **props):
    from experiments import common as c
    from experiments import random_scenes as rs

    scene = rs.random_scene(seed).load()
    ref = np.array(c.build("raymarch", {"visibility": "exact", "steps": 1024,
                                        "output": "scattering"}).render_layers(scene)["scattering"])
    img = np.array(c.build("fourier_filter", {"output": "scattering", **props}
                           ).render_layers(scene)["scattering"])
    return img, ref


@pytest.mark.parametrize("seed", sorted(RANDOM_SEEDS))
def test_random_local_lights_bounded_at_the_defaults(seed):
    img, ref = _random_case(seed)
    assert np.all(np.isfinite(img))
    relmse, ratio = metrics.scale_free_relmse(img, ref), metrics.mean_ratio(img, ref)
    assert relmse <= 5e-3 and abs(ratio - 1.0) <= 0.02, (RANDOM_SEEDS[seed], relmse, ratio)


def test_shared_slices_bound_a_narrow_spot_on_sparse_slices(monkeypatch):
    """Seed 7 (a narrow spot at 17×13) on the slices small images had
    before (``MIN_SLICE_PIXELS`` off): the nearest slice misses the cone
    (relMSE ≈ 30, mean 0.91); the default's two slices and the re-march of
    the samples they disagree on keep it bounded.  The lit cone's own
    slices and marched samples (issue 13) are off: they bound it alone."""
    from integrators.epipolar.light_rays import local as ell
    from integrators.epipolar import frame as epipolar_frame

    monkeypatch.setattr(epipolar_frame, "MIN_SLICE_PIXELS", 1)
    monkeypatch.setattr(ell, "CONE_MARCH_MIN", 0)
    monkeypatch.setattr(ell, "CONE_MARCH_FRACTION", 0.0)
    monkeypatch.setattr(ell, "MIN_LIT_SLICES", 0)
    img, ref = _random_case(7)
    nearest, _ = _random_case(7, slice_interpolation=False)
    assert metrics.scale_free_relmse(nearest, ref) > 1.0
    assert metrics.scale_free_relmse(img, ref) <= 5e-3
    assert abs(metrics.mean_ratio(img, ref) - 1.0) <= 0.02


def _unoccluded_peak(seed) -> float:
    from experiments import common as c
    from experiments import random_scenes as rs

    free = rs.random_scene(seed).load(occluders=False)
    return float(np.max(c.build("raymarch", {"visibility": "exact", "steps": 1024,
                                             "output": "scattering"}
                                ).render_layers(free)["scattering"]))


@pytest.mark.parametrize("props", [{}, {"visibility": "exact"}])
def test_no_leak_from_a_light_inside_a_closed_box(props):
    """Random stress seed 43 (33×25): a point light inside a closed box seen
    from outside, the exact reference black.  Before issue 12's fixes the
    defaults (the filter) put 1.3e-2 of the unoccluded peak there, the
    direct sum 2.3e-3 (bound 1e-3): the slice's plane puts the inside of the
    box, lit, on the last texels of rays that end on its shadowed side
    (traced now: integrators.fourier.tail), and the series blurs the step
    of rays grazing it (the exact sum there now: series_unreliable)."""
    img, ref = _random_case(43, **props)
    assert np.max(ref) == 0.0
    leak = float(np.max(img)) / _unoccluded_peak(43)
    assert leak <= 1e-4, leak


def test_end_runs_and_the_fallback_each_needed_for_the_closed_box():
    """Seed 43 with one of the two mechanisms off leaks above the stress
    bound (1e-3 of the unoccluded peak): the traced end runs alone leave the
    grazing rays' blur (the filter: 1.3e-2), the fallback alone the end runs
    of the direct sum (2.3e-3; with the disagreement re-march off, which
    since a lone sample's far-side query (epipolar_setup_queries._slice_shares)
    catches part of it: 5.8e-4)."""
    peak = _unoccluded_peak(43)
    no_fallback, _ = _random_case(43, exact_fallback=False)
    no_runs, _ = _random_case(43, visibility="exact", trace_ends=False, remarch_disagreement=1.0)
    assert float(np.max(no_fallback)) / peak > 1e-3
    assert float(np.max(no_runs)) / peak > 1e-3


def test_thick_directional_scene_keeps_its_own_unshadowed_sum():
    """Random stress seed 31 (σt·B = 22, directional, reference peak 4.4e-12,
    which a float64 quadrature of a few pixels reproduces to 1e-4): the
    direct sum's U from the separated kernel was negative or 2× off where a
    query's own sum is far below the row's largest weight (relMSE 1.09,
    pixels of 0); from its own kernel it is the direct sum's denominator."""
    from experiments.stability import random_stats

    img, ref = _random_case(31)
    stats = random_stats(img, ref, float("nan"))
    assert stats["bounded"] and stats["relmse"] < 1e-4, stats
