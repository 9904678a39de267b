"""fourier_filter (Klehm et al. 2014) against raymarch with exact visibility
and against the direct rectified sum (the oracle of the partial-sum tree)."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators.capture import capture_camera
from integrators.epipolar_setup import (assign_queries, blocker_modes, choose_slices,
                                        epipolar_frame_of, light_side_factor, rectified_depth)
from integrators.epipolar_tree import separated_kernel
from integrators.fourier_setup import Coverage, query_beta_range, rectified_shadow_map
from integrators.partial_sum_tree import integrate_slices_reference
from integrators.scene_params import SceneParams
from tests.conftest import scene_dict
from tests.oracles import unshadowed_directional
from tests.test_epipolar_tree import SCENES, normalised_relmse, reference, render

RES = (32, 24)
#: coarse -> fine: coefficients, slices, light rays and the kernel's rank grow
SETTINGS = [
    dict(coefficients=8, slices=24, light_rays=48),
    dict(coefficients=32, slices=96, light_rays=128),
    dict(coefficients=128, slices=300, light_rays=300, svd_tolerance=1e-5, ring_steps=2048),
]
FINE = dict(slices=300, light_rays=300, svd_tolerance=1e-5, ring_steps=2048)


def scene(sigma_t=0.3, phase=None, name="behind_off_screen", res=RES, **kw):
    return mi.load_dict(scene_dict(res=res, sigma_t=sigma_t, phase=phase, **SCENES[name], **kw))


# --------------------------------------------------------------------------
# Against the working reference (raymarch, exact visibility)
# --------------------------------------------------------------------------

@pytest.mark.parametrize("name,phase", [
    ("behind_off_screen", None),
    ("on_screen", {"type": "hg", "g": 0.5}),
    ("away_on_screen", {"type": "hg", "g": -0.5}),
    ("parallel_to_image", None),
])
def test_exact_weights_converge_to_exact_raymarch(name, phase):
    """Measured (relMSE of mean-normalised images, SETTINGS coarse -> fine):
    behind_off_screen 3.2e-4 -> 1.8e-5 -> 1.2e-6; on_screen hg 0.5:
    3.3e-3 -> 2.3e-4 -> 3.1e-5; away_on_screen hg -0.5: 1.5e-4 -> 1.1e-5 ->
    1.4e-6; parallel_to_image: 2.2e-4 -> 1.4e-5 -> 2.0e-6."""
    sc = scene(phase=phase, name=name)
    ref = reference(sc)
    errors = [normalised_relmse(render(sc, "fourier_filter", weights="exact", **s)[0], ref)
              for s in SETTINGS]
    assert errors[2] < errors[1] < errors[0], errors
    assert errors[-1] < 5e-5, errors


def test_error_falls_with_the_number_of_coefficients():
    """Fine rectification, M = 4, 16, 64: measured 2.4e-4, 1.1e-5, 1.6e-6."""
    sc = scene()
    ref = reference(sc)
    errors = [normalised_relmse(render(sc, "fourier_filter", weights="exact", coefficients=M,
                                       **FINE)[0], ref) for M in (4, 16, 64)]
    assert errors[2] < errors[1] < errors[0], errors
    assert errors[2] < 5e-6, errors


def test_weight_approximations_in_a_thick_medium():
    """σt = 1 (≈ 4 mean free paths across the fog box, light from behind the
    camera): transmittance varies strongly along the light rays, and the
    kernel of each view ray differs from its slice's reference ray.
    Measured relMSE (M = 64, 300 slices and light rays): average 1.9e-3,
    reference_ray 9.9e-6 (bisectrix; 9.6e-6 with ``reference=optimal``),
    exact 2.0e-7."""
    sc = scene(sigma_t=1.0)
    ref = reference(sc)

    def error(**kw):
        return normalised_relmse(render(sc, "fourier_filter", coefficients=64, **FINE,
                                        **kw)[0], ref)

    average, bisectrix = error(weights="average"), error(weights="reference_ray")
    optimal, exact = error(weights="reference_ray", reference="optimal"), error(weights="exact")
    assert exact < 0.1 * bisectrix and bisectrix < 0.02 * average, (average, bisectrix, exact)
    assert exact < 0.1 * optimal and exact < 1e-6, (optimal, exact)


def test_coloured_medium_filters_every_channel():
    """σt = (0.1, 0.4, 0.9): one filter set per channel.  Measured
    (SETTINGS[1] -> SETTINGS[2]): average 1.7e-3 -> 1.7e-3, reference_ray
    6.5e-5 -> 4.0e-5, exact 2.4e-5 -> 2.5e-6."""
    sc = scene(sigma_t={"type": "rgb", "value": [0.1, 0.4, 0.9]}, name="away_on_screen")
    ref = reference(sc)
    exact = normalised_relmse(render(sc, "fourier_filter", weights="exact", **SETTINGS[2])[0],
                              ref)
    ray = normalised_relmse(render(sc, "fourier_filter", **SETTINGS[2])[0], ref)
    assert exact < 5e-6 and exact < 0.2 * ray, (exact, ray)


@pytest.mark.parametrize("weights", ["average", "reference_ray", "exact"])
def test_default_settings_are_close(weights):
    """Measured with the defaults on the on-screen epipole scene: average
    2.2e-4, reference_ray 1.8e-4, exact 1.8e-4 (epipolar_tree: 2.5e-4)."""
    sc = scene(name="on_screen")
    img, integ = render(sc, "fourier_filter", weights=weights)
    assert normalised_relmse(img, reference(sc)) < 5e-4
    for stage in ("rectify", "blockers", "svd", "prefilter", "evaluate", "unrectify", "ring"):
        assert stage in integ.timings


def test_full_depth_range_is_worse_than_the_slice_range():
    """``depth_range=full`` (z = β/π for every texel) spends the series on
    all possible view rays and sends every texel through it; measured at
    M = 8 on the on-screen scene: full 3.1e-2, slice 2.5e-3."""
    sc = scene(name="on_screen")
    ref = reference(sc)
    full, sl = (normalised_relmse(render(sc, "fourier_filter", weights="exact",
                                         depth_range=r, **SETTINGS[0])[0], ref)
                for r in ("full", "slice"))
    assert sl < 0.1 * full, (sl, full)


def test_regions_and_fit_depth_stay_accurate():
    """Measured (SETTINGS[1], on-screen): 1.8e-4 plain, regions=3 1.9e-4,
    fit_depth 1.8e-4, both 1.8e-4."""
    sc = scene(name="on_screen")
    ref = reference(sc)
    base = normalised_relmse(render(sc, "fourier_filter", **SETTINGS[1])[0], ref)
    for kw in (dict(regions=3), dict(fit_depth=True), dict(regions=2, fit_depth=True)):
        err = normalised_relmse(render(sc, "fourier_filter", **SETTINGS[1], **kw)[0], ref)
        assert err < 1.2 * base, (kw, err, base)


def test_resampled_shadow_map_converges():
    sc = scene(name="on_screen")
    ref = reference(sc)
    errors = [normalised_relmse(render(sc, "fourier_filter", blockers="resampled",
                                       shadowmap_resolution=r, **SETTINGS[1])[0], ref)
              for r in (16, 1024)]
    assert errors[1] < errors[0] and errors[1] < 3e-4, errors   # measured 3.1e-2, 1.9e-4


# --------------------------------------------------------------------------
# Closed form, extremes, invariants
# --------------------------------------------------------------------------

@pytest.mark.parametrize("weights", ["average", "exact"])
def test_unshadowed_medium_matches_the_closed_form(weights):
    """No blocker: every row takes the closed form U (no filter), which must
    equal ∫ σs f_p E e^{-σt τ(x(t))} e^{-σt t} dt per pixel (to the nearest
    slice's light-side factor, as in epipolar_tree's test)."""
    res = (8, 6)
    sc = mi.load_dict(scene_dict(surface=0.0, blocker=None, floor=None, res=res,
                                 sigma_t={"type": "rgb", "value": [0.1, 0.3, 0.9]}))
    p = SceneParams.from_scene(sc)
    out, integ = render(sc, "fourier_filter", weights=weights, slices=400, light_rays=512,
                        svd_tolerance=1e-6)
    assert integ.timings.get("prefilter", 0.0) < 0.05       # no filter ran
    expected = unshadowed_directional(p, res, samples=20000)
    np.testing.assert_allclose(out, expected, rtol=2e-3)


@pytest.mark.parametrize("sigma_t", [1e-4, 1e-2, 1.0, 10.0])
@pytest.mark.parametrize("name", ["on_screen", "away_on_screen"])
@pytest.mark.parametrize("weights", ["reference_ray", "exact"])
def test_thin_and_thick_media_are_finite(sigma_t, name, weights):
    sc = scene(sigma_t=sigma_t, name=name, res=(16, 12))
    integ = mi.load_dict({"type": "fourier_filter", "weights": weights})
    layers = {k: np.array(v) for k, v in integ.render_layers(sc).items()}
    for key, img in layers.items():
        assert np.all(np.isfinite(img)) and np.all(img >= 0), key


def test_full_output_adds_the_surface():
    sc = scene(res=(16, 12))
    ff = {k: np.array(v) for k, v in
          mi.load_dict({"type": "fourier_filter"}).render_layers(sc).items()}
    march = {k: np.array(v) for k, v in
             mi.load_dict({"type": "raymarch", "visibility": "exact"}).render_layers(sc).items()}
    np.testing.assert_allclose(ff["full"], ff["surface"] + ff["scattering"], rtol=1e-6)
    np.testing.assert_allclose(ff["surface"], march["surface"], rtol=1e-6)


# --------------------------------------------------------------------------
# The rectified sums against the direct sum (partial_sum_tree's oracle)
# --------------------------------------------------------------------------

def rectified_case(name="on_screen", sigma_t=0.3, **props):
    """(integrator, queries, RectifiedSums) of a small scene."""
    sc = scene(sigma_t=sigma_t, name=name)
    params = SceneParams.from_scene(sc)
    cap = capture_camera(params, spp=1, jitter=False, seed=0, surface=False)
    frame = epipolar_frame_of(params)
    queries = assign_queries(params, frame, choose_slices(frame, 48), cap, 2.0)
    integ = mi.load_dict({"type": "fourier_filter", "light_rays": 64, **props})
    return params, integ, queries, integ.rectified_sums(params, cap, queries)


def direct_sums(params, queries, rect, integ, blocked=True):
    """Σ_γ L K_N V cover per query by the slow NumPy oracle of the tree."""
    rays = rect.rays
    modes = blocker_modes(queries, rays, rect.beta_b, 1)
    if not blocked:
        modes = type(modes)(modes.beta, dr.zeros(mi.TensorXf, modes.weight.shape))
    A, B = separated_kernel(params, queries, rays, integ.svd_rank, integ.svd_tolerance)
    out = integrate_slices_reference(rectified_depth(queries, rays), modes, A, B,
                                     L=light_side_factor(params, queries, rays),
                                     r_count=np.array(queries.r_count))
    return out.reshape(queries.n * queries.r)[np.array(queries.slot)]


def test_unshadowed_sum_is_the_direct_sum():
    params, integ, queries, rect = rectified_case()
    U = np.array(rect.U[0])
    np.testing.assert_allclose(U, direct_sums(params, queries, rect, integ, blocked=False),
                               rtol=2e-5, atol=1e-6 * U.max())


def test_exact_weights_reproduce_the_direct_sum():
    """``weights=exact`` is Σ_γ L K_N V_M cover: with many coefficients it is
    the direct sum up to the series' blur next to each shadow step.
    Measured mean |error| / mean: 4.1e-5 (M = 16), 3.7e-6 (M = 256)."""
    errors = []
    for M in (16, 256):
        params, integ, queries, rect = rectified_case(weights="exact", coefficients=M,
                                                      clamp=False)
        S = np.array(rect.U[0] * rect.V[0])
        ref = direct_sums(params, queries, rect, integ)
        errors.append(np.abs(S - ref).mean() / ref.mean())
    assert errors[1] < 0.2 * errors[0] and errors[1] < 2e-3, errors


@pytest.mark.parametrize("weights", ["average", "reference_ray", "exact"])
def test_clamp_keeps_the_visibility_in_the_unit_interval(weights):
    """One harmonic (M = 2) of the series as published (every texel through
    it, no exact bounds) overshoots to ≈ 1.14 half a period from a step;
    clamped V̄ stays in [0, 1] (Appendix A), unclamped it leaves it."""
    V = {}
    for clamp in (True, False):
        *_, rect = rectified_case("parallel_to_image", weights=weights, coefficients=2,
                                  clamp=clamp, depth_range="full", exact_bounds=False)
        V[clamp] = np.array(rect.V[0])
    assert V[True].min() >= 0.0 and V[True].max() <= 1.0
    assert V[False].max() > 1.05        # measured 1.11 (all three weights)


def test_rectified_shadow_map_classes():
    """Texels lit for every query of the row, shadowed for all of them, or
    in the series; query depths in [0, 1/2] (module doc of fourier_setup)."""
    params, integ, queries, rect = rectified_case()
    smap = rectified_shadow_map(queries, rect.rays, rect.beta_b, "slice")
    d = rect.rays.d
    beta_b = np.array(rect.beta_b).reshape(queries.n, d)
    lo, hi = (np.array(x) for x in query_beta_range(queries))
    lit = np.array(smap.lit).reshape(queries.n, d)
    series = np.array(smap.series).reshape(queries.n, d)
    np.testing.assert_array_equal(lit, beta_b >= hi[:, None])
    np.testing.assert_array_equal(series, (beta_b >= lo[:, None]) & (beta_b < hi[:, None]))
    z_r = np.array(smap.z_r)
    assert z_r.min() >= 0.0 and z_r.max() <= 0.5
    assert np.array(smap.filtered).sum() == smap.n_filtered
    assert 0 < smap.n_filtered < queries.n           # blocked and free rows both occur


def test_coverage_sums():
    params, integ, queries, rect = rectified_case()
    cover = Coverage.of(queries, rect.rays)
    d = rect.rays.d
    w = np.random.default_rng(1).random(queries.n * d).astype(np.float32)
    D = np.array(queries.gamma_end) / np.array(rect.rays.delta_gamma)[np.array(queries.row)]
    g = np.arange(d)
    expected = [(w.reshape(-1, d)[r] * np.clip(Di - g, 0, 1)).sum()
                for r, Di in zip(np.array(queries.row), D)]
    np.testing.assert_allclose(np.array(cover.sum(mi.Float(w))), expected, rtol=1e-4)


# --------------------------------------------------------------------------
# What it refuses
# --------------------------------------------------------------------------

@pytest.mark.parametrize("light", ["point", "spot"])
def test_point_and_spot_lights_are_refused(light):
    sc = mi.load_dict(scene_dict(light=light, res=(8, 6)))
    with pytest.raises(ValueError, match=f"{light} light, but only directional lights"):
        mi.load_dict({"type": "fourier_filter"}).render(sc)


@pytest.mark.parametrize("props", [{"coefficients": 7}, {"coefficients": 0},
                                   {"weights": "linear"}, {"regions": 0},
                                   {"clamp": 1}, {"depth_range": "half"},
                                   {"rectification": "projective"},
                                   {"blockers": "warped"}, {"light_rays": 1.5}])
def test_invalid_properties(props):
    # Mitsuba's plugin loader re-raises the constructor's ValueError as RuntimeError
    with pytest.raises((ValueError, RuntimeError), match=f"Property '{next(iter(props))}'"):
        mi.load_dict({"type": "fourier_filter", **props})


def test_projective_rectification_is_refused_by_name():
    with pytest.raises((ValueError, RuntimeError), match="not implemented yet"):
        mi.load_dict({"type": "fourier_filter", "rectification": "projective"})
