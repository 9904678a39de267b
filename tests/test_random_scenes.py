"""The randomised scene generator (experiments.random_scenes) and the
issue-13 failure classes it makes explicit: each listed seed failed the
stability bounds at ``epipolar_tree``'s defaults before the fix named in
its comment (experiments.stability.random_stats: scale-free relMSE <=
1e-2, max error <= 0.5 x peak, mean ratio within 2 %, pixel centres,
against raymarch visibility=exact)."""
import json

import numpy as np
import pytest

from experiments import random_scenes as rs
from experiments import stability as st


def test_generator_is_deterministic_and_plain_data():
    a, b = rs.random_scene(12), rs.random_scene(12)
    assert json.dumps(a.as_json()) == json.dumps(b.as_json())
    assert rs.random_scene(13).as_json() != a.as_json()
    assert {rs.kind_of_seed(s) for s in range(len(rs.KIND_CYCLE))} == set(rs.KINDS)


@pytest.mark.parametrize("kind", rs.KINDS)
def test_every_kind_loads(kind):
    spec = rs.random_scene(3, kind)
    assert spec.kind == kind
    spec.load()
    spec.load(occluders=False)


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="unknown scene kind"):
        rs.random_scene(0, "volcano")


def test_light_on_pixel_lies_on_a_pixel_ray():
    spec = rs.random_scene(4)
    assert spec.kind == "light_on_pixel"
    w = np.asarray(spec.light["position"]) - np.asarray(spec.origin)
    W, H = spec.res
    best = max(float(np.dot(w / np.linalg.norm(w), rs._pixel_ray_direction(spec, i, j)))
               for i in range(W) for j in range(H))
    assert best > 1 - 1e-6


def _tree_stats(seed, kind=None, method="epipolar_tree"):
    from episcatter.reference import render_rgb
    from experiments import common as c

    spec = rs.random_scene(seed, kind)
    scene = spec.load()
    ref = render_rgb(scene, c.build("raymarch", {"visibility": "exact", "steps": 2048,
                                                 "output": "scattering"}))
    img = render_rgb(scene, c.build(method, {"output": "scattering"}))
    return st.random_stats(img, ref, 1.0)


# seed: (class, what fixed it); numbers: commit 5413e8b's integrators
# (results/stability/logs/before_*.log, or the class-1 case rerun there)
CLASS_SEEDS = {
    49: "light_near_face (class 4): relMSE 25, mean +15 % at 3x5; slices and light rays of "
        "small images (>= 256 light rays)",
    2: "light_at_eye (class 2): spot 3e-4 B from the eye, relMSE 1.8e-2, mean -3.4 %; "
       "auto_light_rays >= 256",
    4: "light_on_pixel (class 3): mean +7.6 %, the 256-step ring's equiangular steps "
       "took 1/r² at midpoints (raymarch._steps correction)",
    7: "narrow_spot (class 5): relMSE 26, mean -23 %; slices and light rays of small images",
    18: "narrow_spot: a one-pixel beam running along the slices, relMSE 2.1e-2 (the blend "
        "of a lit and a dark slice); samples whose slices disagree are re-marched",
    95: "narrow_spot: relMSE 15, light blended onto pixels the reference renders black "
        "next to the beam; re-marched",
    161: "narrow_spot: relMSE 7.5e-2, beam edge along the slices; re-marched",
    84: "narrow_spot: mean -2.3 %; the light-ray spacing came from the widest row, a dark row "
        "[0, max γ_end], so the 2° cone got few light rays (local_light_ray_grid: lit rows)",
    180: "light_on_pixel (class 3): mean +4.1 % at 17x13 in thick fog (σt·B = 19), the pixel "
         "next to the light holds most of the energy and 256 ring steps missed its 1/r² peak "
         "by 4.7 %; ring samples within a pixel of the light take 8x the steps",
    29: "narrow_spot: mean -20 %, relMSE 1.5e-2; the spot's dark rows (γ from 0) set the "
        "separated kernel's domain, whose relative tolerance then left the cone 80° from the "
        "eye all error (epipolar.kernel.local.lit_domain)",
    # session 3 (fail on main 1155186, pass after; main's numbers)
    72: "thick directional (σt·B = 11): relMSE 0.78, max error 0.21 x peak; a view ray toward "
        "the light sums K·L ≈ e^{-10} of ∫K, the rank's relative tolerance was all error there "
        "(epipolar.kernel.separation.checked_tolerances: N 7 -> 11)",
    86: "thick directional (σt·B = 12): relMSE 3.4e-2, max error 0.43 x peak; checked "
        "tolerances (N 3 -> 6)",
    117: "narrow spot (0.75°, 9 lit slices): relMSE 9.9e-3, mean -4.6 %; denser slices in the "
         "cone (resolve_lit_cone), its few samples re-marched with steps inside the cone",
    227: "narrow textured spot (0.8°, one lit pixel): mean +48 %; its sample re-marched "
         "(cone_samples) with the ring's 256 steps inside the cone (spacing 'cone'), not ~1 of "
         "them",
    216: "narrow textured spot (1.6°, 11 lit slices): mean +5.4 % with denser slices alone; "
         "cone_samples + 'cone' spacing",
    # issue 13, task h20 (fail on main d3b6932, pass after; main's numbers)
    79: "light_at_eye: point light 3e-4 B behind the eye, mean -2.3 %, relMSE 1.0e-3; the rise "
        "of E within 1e-4 rad of each view ray's asymptote made the separated kernel miss its "
        "tolerance at rank 24 (error 0.13): banded kernel + exact cell means in the last cells "
        "(asymptote_band_correction), Gauss-Legendre near segment",
    266: "light_at_eye: mean -2.6 %, relMSE 9.8e-4; as seed 79",
}


@pytest.mark.parametrize("seed", sorted(CLASS_SEEDS))
def test_issue13_class_is_bounded(seed):
    s = _tree_stats(seed)
    assert s["bounded"], (CLASS_SEEDS[seed], s)


# fourier_filter at its defaults (issue 12, task h25; fail on main 553f14e, pass after;
# main's numbers): the same class as the tree's seeds 79 and 266
FILTER_CLASS_SEEDS = {
    79: "light_at_eye: point light 3e-4 B behind the eye, mean -2.9 %, max error 0.075 x peak; "
        "U came from the unbanded separated kernel, which cannot hold the rise of E within "
        "1e-4 rad of each view ray's asymptote: banded kernel + exact cell means in the band "
        "(fourier_filter.unshadowed_band)",
    233: "light_at_eye: mean -2.9 %, max error 0.081 x peak; as seed 79",
    266: "light_at_eye: mean -2.7 %, max error 0.078 x peak; as seed 79",
}


@pytest.mark.parametrize("seed", sorted(FILTER_CLASS_SEEDS))
def test_issue13_class_is_bounded_for_the_filter(seed):
    s = _tree_stats(seed, method="fourier_filter")
    assert s["bounded"], (FILTER_CLASS_SEEDS[seed], s)


def test_issue13_class1_sun_on_the_view_axis_is_bounded():
    """Class 1 (the sun within 0.5° of the view axis, a dozen occluders):
    seed 126 as ``sun_axis`` at 8x6 had relMSE 50, mean ratio 1.98, max
    error 18x the peak at commit 5413e8b (dense slices and >= 256 light
    rays on small images fixed it)."""
    s = _tree_stats(126, "sun_axis")
    assert s["bounded"], s


def test_disagreeing_slices_are_remarched(monkeypatch):
    """The fall-back is what bounds seed 18 (stats["remarched"] counts it);
    remarch_disagreement=1 turns it off.  (Its narrow spot's few samples
    are also marched by cone_samples and its cone gets denser slices
    (resolve_lit_cone), both switched off here.)"""
    from episcatter.reference import render_rgb
    from experiments import common as c
    from integrators.epipolar.light_rays import local as ell

    monkeypatch.setattr(ell, "CONE_MARCH_MIN", 0)
    monkeypatch.setattr(ell, "CONE_MARCH_FRACTION", 0.0)
    monkeypatch.setattr(ell, "MIN_LIT_SLICES", 0)

    spec = rs.random_scene(18)
    scene = spec.load()
    ref = render_rgb(scene, c.build("raymarch", {"visibility": "exact", "steps": 2048,
                                                 "output": "scattering"}))
    stats = {}
    for tol in (0.25, 1.0):
        integ = c.build("epipolar_tree", {"output": "scattering", "remarch_disagreement": tol})
        res = integ.render_layers(scene, spp=1)
        stats[tol] = (res.stats["remarched"], st.random_stats(np.array(res["scattering"]), ref, 1.0))
    assert stats[1.0][0] == 0 and not stats[1.0][1]["bounded"]
    assert stats[0.25][0] > 0 and stats[0.25][1]["bounded"], stats


def test_logs_of_a_split_run_summarise_and_compare(tmp_path):
    """parse_log reads the progress lines of --random runs; summarise_logs
    merges a run split over several logs (first log wins on a repeated
    seed), compare_logs keeps the seeds both sides cover."""
    a = tmp_path / "a.log"
    b = tmp_path / "b.log"
    a.write_text(
        "[1/2] seed 0 (random, spot, 9x7): epipolar_tree ok relMSE 1e-05 max/peak 0.01 mean 1 leak -\n"
        "[2/2] seed 1 (enclosed, point, 3x5): epipolar_tree ok relMSE - max/peak - mean - leak 0\n")
    b.write_text(
        "[1/2] seed 1 (enclosed, point, 3x5): epipolar_tree UNBOUNDED relMSE - max/peak - mean - "
        "leak 0.5\n"
        "[2/2] seed 2 (thick, directional, 1x1): epipolar_tree UNBOUNDED relMSE 0.5 max/peak 2 "
        "mean 1.5 leak -\n")
    s = st.summarise_logs([a, b], tmp_path, "merged")["epipolar_tree"]
    assert (s["scenes"], s["bounded"], s["lit"], s["black"]) == (3, 2, 2, 1)
    assert s["unbounded_seeds"] == [2]
    assert (tmp_path / "merged.md").exists() and (tmp_path / "merged.csv").exists()
    cmp = st.compare_logs([a], [b], tmp_path)
    assert cmp["seeds"] == [1] and cmp["before"]["bounded"] == 1 and cmp["after"]["bounded"] == 0


@pytest.mark.parametrize("seed", [43, 98])
def test_enclosed_light_does_not_leak(seed):
    """Seeds 43 and 98 (a point light inside a closed box that sticks out
    of the medium box): with the reference black (light_transport's gap
    tests), the tree leaked 4.6e-3 and 3.1e-3 of the unoccluded peak
    (bound 1e-3) through first_blocker's untested gaps."""
    row = st.run_random_scene(rs.random_scene(seed), ("epipolar_tree",))[0]
    assert row["ref_class"] == "black" and row["bounded"], row


def test_cone_spacing_puts_the_steps_in_a_narrow_beam():
    """raymarch spacing='cone' (the tree's ring / re-march spacing for spot
    lights) with 256 steps matches 'equiangular' with 32768 on seed 227's
    0.8° textured spot (its one lit pixel), where 'equiangular' with 256
    steps spends ~1 step in the beam."""
    from episcatter.reference import render_rgb
    from experiments import common as c

    scene = rs.random_scene(227).load()

    def img(spacing, steps):
        return render_rgb(scene, c.build("raymarch", {"visibility": "exact", "steps": steps,
                                                      "spacing": spacing,
                                                      "output": "scattering"}))
    fine = img("equiangular", 32768)
    y, x = np.unravel_index(np.argmax(fine.max(-1)), fine.shape[:2])
    cone = img("cone", 256)[y, x]
    coarse = img("equiangular", 256)[y, x]
    np.testing.assert_allclose(cone, fine[y, x], rtol=5e-3)
    assert np.max(np.abs(coarse / fine[y, x] - 1)) > 0.05


def test_narrow_cone_gets_dense_slices_and_its_samples_marched():
    """resolve_lit_cone: seed 117's 0.75° spot crossed 9 automatic slices,
    now at least MIN_LIT_SLICES; a point light's slices are left alone.
    cone_samples lists the samples the cone reaches (few: all of them)."""
    import integrators  # noqa: F401 -- registers the plugins
    from integrators.epipolar.light_rays import local as ell
    from integrators.epipolar.frame import choose_slices, epipolar_frame_of
    from integrators.core.scene_params import SceneParams

    p = SceneParams.from_scene(rs.random_scene(117).load())
    frame = epipolar_frame_of(p)
    plain = choose_slices(frame)
    dense = ell.resolve_lit_cone(p, frame, plain)
    lit = lambda sl: int(np.array(ell.cone_interval(p, frame, sl.alpha)[2]).sum())  # noqa: E731
    assert lit(plain) < ell.MIN_LIT_SLICES <= lit(dense)
    assert dense.count < 2 * plain.count
    q = SceneParams.from_scene(rs.random_scene(0, "light_on_pixel").load())
    qf = epipolar_frame_of(q)
    assert ell.resolve_lit_cone(q, qf, choose_slices(qf)) is not None
    assert ell.resolve_lit_cone(q, qf, choose_slices(qf)).count == choose_slices(qf).count


# issue 13, task h23 (fail on main 9fae9b5, pass after; main's numbers against the oracle)
ORACLE_SEEDS = {
    31: "thick directional (σt·B = 22) seen away from the light from deep inside the box: the "
        "light-side path shrinks along the slices, so L grows by e^24 along a row while the "
        "view ray's kernel decays as fast; the separated sum was 28x the exact one (relMSE "
        "1.68, max error 7.7x peak) and the rounding flush, bounded by the whole row's "
        "magnitude, zeroed lit pixels: prefix magnitude, unresolved sums re-marched",
    206: "grazing sun through a face nearly parallel to the light rays: the light-side depth "
         "changed by 0.6 mean free paths per light ray, mean ratio 0.975 (converging as "
         "1/d²); the automatic light rays resolve it (light_side_step)",
}


@pytest.mark.parametrize("seed", sorted(ORACLE_SEEDS))
def test_issue13_tree_matches_the_float64_oracle(seed):
    """The tree at its defaults against a float64 NumPy quadrature of the
    unshadowed scattering (tests.oracles.unshadowed_directional, 20000
    midpoint steps per pixel centre; these seeds' occluders cast no shadow
    into the view, so they are left out)."""
    from episcatter.reference import render_rgb
    from experiments import common as c
    from integrators.core.scene_params import SceneParams
    from tests import oracles

    spec = rs.random_scene(seed)
    scene = spec.load(occluders=False)
    phase = 1 / (4 * np.pi) if spec.g is None else oracles.henyey_greenstein(spec.g)
    ref = oracles.unshadowed_directional(SceneParams.from_scene(scene), spec.res,
                                         samples=20000, phase=phase)
    img = render_rgb(scene, c.build("epipolar_tree", {"output": "scattering"}))
    s = st.random_stats(img, ref, 1.0)
    assert s["ref_class"] == "lit" and s["bounded"], (ORACLE_SEEDS[seed], s)


def test_unresolved_sums_are_remarched(monkeypatch):
    """Seed 31's bound comes from re-marching the samples whose unshadowed
    separated sum is below 1e-2 of its magnitude or off its direct sum
    (stats["unresolved"]); with both tests off (UNRESOLVED_RATIO = 0
    leaves only the negative sums, always unresolved; KERNEL_DEPTH = inf
    checks no direct sum) the separated kernel's error is left (relMSE
    ~1); either test alone bounds it."""
    from episcatter.reference import render_rgb
    from experiments import common as c
    from integrators.epipolar import direct_sum as ds
    from integrators.epipolar import last_interval as es

    scene = rs.random_scene(31).load()
    ref = render_rgb(scene, c.build("raymarch", {"visibility": "exact", "steps": 2048,
                                                 "output": "scattering"}))
    out = {}
    for ratio, depth in ((1e-2, ds.KERNEL_DEPTH), (0.0, np.inf), (1e-2, np.inf),
                         (0.0, ds.KERNEL_DEPTH)):
        monkeypatch.setattr(es, "UNRESOLVED_RATIO", ratio)
        monkeypatch.setattr(ds, "KERNEL_DEPTH", depth)
        res = c.build("epipolar_tree", {"output": "scattering"}).render_layers(scene, spp=1)
        out[ratio, depth] = (res.stats["unresolved"],
                             st.random_stats(np.array(res["scattering"]), ref, 1.0))
    default, off, *alone = out.values()
    assert off[0] < default[0] and not off[1]["bounded"], out
    assert default[0] > 0 and default[1]["bounded"], out
    assert all(a[0] > off[0] and a[1]["bounded"] for a in alone), out


def test_asymptote_band_only_where_a_view_ray_reaches_it(make_scene):
    """The tree's asymptote band (issue 13, light at the eye) is taken only
    when some view ray ends within a few light-ray cells of its limit angle
    π − β: a point light far from the eye renders exactly as without the
    band (the band made such renders 1.2–1.4× slower for nothing), a light at
    the eye (seed 79) takes it."""
    import mitsuba as mi
    from integrators.epipolar_tree import EpipolarTreeIntegrator

    scene = make_scene(light="point", res=(24, 18))
    result = mi.load_dict({"type": "epipolar_tree"}).render_layers(scene, spp=1)
    assert result.stats["asymptote_band"] == 0
    plain = type("NoBand", (EpipolarTreeIntegrator,), {"ASYMPTOTE_BAND": 0})
    np.testing.assert_array_equal(
        np.array(result["full"]),
        np.array(plain(mi.Properties("epipolar_tree")).render_layers(scene, spp=1)["full"]))
    at_eye = rs.random_scene(79).load()
    stats = mi.load_dict({"type": "epipolar_tree"}).render_layers(at_eye, spp=1).stats
    assert stats["asymptote_band"] == EpipolarTreeIntegrator.ASYMPTOTE_BAND
