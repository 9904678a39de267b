"""The Fenwick-tree sweep (Baran et al. 2010, Fig. 6) against its NumPy oracle."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from integrators.tree import partial_sum_tree as pst
from integrators.epipolar.blockers import BlockerModes
from integrators.tree.partial_sum_tree import integrate_slices
from integrators.tree.partial_sum_reference import integrate_slices_reference

INF = np.float32(np.inf)


def magnitude(D, A, B, L=None, delta_gamma=1.0):
    """Largest possible |result|: all leaves lit, full depth, absolute values."""
    n, d = D.shape[0], np.shape(A)[-3] if np.ndim(A) == 4 else np.shape(A)[-2]
    S = np.full((n, d), INF)
    full = np.full_like(D, INF)
    absL = None if L is None else np.abs(L)
    return float(np.abs(integrate_slices_reference(
        full, S, np.abs(A), np.abs(B), L=absL, delta_gamma=delta_gamma)).max())


def check(D, S, A, B, rtol=1e-5, **kw):
    """Fast kernel (tree and skip paths) == oracle to float32 accuracy."""
    ref = integrate_slices_reference(D, S, A, B, **kw)
    extra = {k: v for k, v in kw.items() if k in ("L", "delta_gamma")}
    atol = rtol * max(magnitude(D, A, B, **extra), 1e-30)
    for skip in (True, False):
        out = np.array(integrate_slices(D, S, A, B, skip_unblocked=skip, **kw))
        assert out.shape == ref.shape
        np.testing.assert_allclose(out, ref, rtol=rtol, atol=atol)
    return ref


def random_case(rng, n, d, r, N, M=1, coloured=False, with_L=True, ragged=False,
                blocked=0.6):
    """D with fractional, integer, negative, > d and infinite depths."""
    D = rng.uniform(-0.3 * d, 1.3 * d, (n, r)).astype(np.float32)
    D[rng.uniform(size=D.shape) < 0.2] = rng.integers(0, d + 1)
    D[rng.uniform(size=D.shape) < 0.05] = INF
    beta = rng.uniform(-2, r / blocked, (n, d, M)).astype(np.float32)
    whole = rng.uniform(size=beta.shape) < 0.3          # some integer β too
    beta[whole] = np.floor(beta[whole])
    if M == 1:
        S = np.floor(beta[..., 0])
    else:
        w = rng.uniform(0, 1, (n, d, M)) * (rng.uniform(size=(n, d, M)) < 0.8)
        w = (w / np.maximum(w.sum(-1, keepdims=True), 1e-9)).astype(np.float32)
        S = BlockerModes(beta, w)               # real β: acts from ⌈β⌉ on
    C = (3,) if coloured else ()
    A = rng.uniform(0.0, 1.0, (n if rng.uniform() < 0.5 else 1, d) + C + (N,))
    B = rng.uniform(-1.0, 1.0, (n if rng.uniform() < 0.5 else 1, r) + C + (N,))
    L = rng.uniform(0.2, 1.0, (n, d) + C).astype(np.float32) if with_L else None
    kw = dict(L=L)
    if ragged:
        kw.update(r_count=rng.integers(0, r + 1, n), d_count=rng.integers(0, d + 1, n))
    return D, S, A.astype(np.float32), B.astype(np.float32), kw


# --- the semantics, by hand --------------------------------------------------

def test_hand_computed_example():
    """d=4 leaves of value 1, S = [1, never, 0, 2]: a leaf is zeroed *before*
    the query at its blocker β; D lerps the covered fraction of a leaf."""
    D = np.array([[4.0, 2.5, 1.5]], np.float32)
    S = np.array([[1, INF, 0, 2]], np.float32)
    A, B = np.ones((4, 1), np.float32), np.ones((3, 1), np.float32)
    expected = np.array([[3.0, 1.0, 0.5]])
    np.testing.assert_allclose(integrate_slices_reference(D, S, A, B), expected)
    np.testing.assert_allclose(np.array(integrate_slices(D, S, A, B)), expected)
    # Δγ and B scale linearly; a real-valued blocker at 0.5 acts from β = 1.
    S2 = np.array([[0.5, INF, INF, INF]], np.float32)
    out = np.array(integrate_slices(D, S2, A, 2 * B, delta_gamma=0.25))
    np.testing.assert_allclose(out, [[2.0, 0.75, 0.25]])


def test_fractional_modes_by_hand():
    """§7: a light ray with modes (β=1, w=0.25) and (β=2, w=0.75)."""
    beta = np.array([[[1, 2]]], np.float32)
    weight = np.array([[[0.25, 0.75]]], np.float32)
    D = np.full((1, 3), 1.0, np.float32)
    A, B = np.full((1, 1), 2.0, np.float32), np.ones((3, 1), np.float32)
    expected = [[2.0, 1.5, 0.0]]
    modes = BlockerModes(beta, weight)
    np.testing.assert_allclose(integrate_slices_reference(D, modes, A, B), expected)
    np.testing.assert_allclose(np.array(integrate_slices(D, modes, A, B)), expected,
                               atol=1e-6)


def test_depth_clamping_and_nan():
    d = 6
    D = np.array([[-1.0, 0.0, np.nan, 2.25, 6.0, 7.5, np.inf]], np.float32)
    S = np.full((1, d), INF)
    A = np.arange(1, d + 1, dtype=np.float32)[:, None]
    B = np.ones((7, 1), np.float32)
    expected = [[0.0, 0.0, 0.0, 1 + 2 + 0.25 * 3, 21.0, 21.0, 21.0]]
    np.testing.assert_allclose(integrate_slices_reference(D, S, A, B), expected, rtol=1e-6)
    check(D, S, A, B)


# --- fast kernel == oracle -----------------------------------------------------

@pytest.mark.parametrize("N", [1, 2, 3, 4])
@pytest.mark.parametrize("M", [1, 3])
def test_random_matches_oracle(N, M):
    rng = np.random.default_rng(10 * N + M)
    D, S, A, B, kw = random_case(rng, n=9, d=37, r=29, N=N, M=M, ragged=True)
    check(D, S, A, B, **kw)


def test_colour_broadcast():
    rng = np.random.default_rng(7)
    D, S, A, B, kw = random_case(rng, n=5, d=23, r=11, N=2, M=2, coloured=True)
    ref = check(D, S, A, B, **kw)
    assert ref.shape == (5, 11, 3)
    # Colour only in L: A and B without colour axis broadcast against it.
    check(D, S, A[..., 0, :], B[..., 0, :], L=kw["L"])
    # Colour channel c equals a scalar run on channel c.
    mono = np.array(integrate_slices(D, S, A[..., 1, :], B[..., 1, :], L=kw["L"][..., 1]))
    np.testing.assert_allclose(ref[..., 1], mono, rtol=1e-5, atol=1e-5 * np.abs(ref).max())


def test_empty_and_degenerate_slices():
    rng = np.random.default_rng(3)
    D, S, A, B, kw = random_case(rng, n=6, d=17, r=13, N=2)
    r_count = np.array([0, 13, 5, 0, 13, 1])
    d_count = np.array([17, 0, 0, 1, 17, 17])
    ref = check(D, S, A, B, r_count=r_count, d_count=d_count, **kw)
    assert not ref[0].any() and not ref[1].any() and not ref[3].any()
    assert not ref[2, 5:].any()
    for shape in [(3, 0), (0, 5)]:                      # no view rays / slices
        Dz = np.zeros(shape, np.float32)
        out = integrate_slices(Dz, np.zeros((shape[0], 4)), np.ones((4, 1)),
                               np.ones((shape[1], 1)))
        assert tuple(out.shape) == shape
    out = integrate_slices(np.ones((2, 3)), np.zeros((2, 0)), np.ones((0, 1)),
                           np.ones((3, 1)))              # no light rays
    assert not np.array(out).any()


def test_all_blocked_gives_zero():
    rng = np.random.default_rng(4)
    D, _, A, B, kw = random_case(rng, n=4, d=40, r=9, N=3)
    for S in (np.zeros((4, 40)), np.full((4, 40), -3.0)):
        check(D, S, A, B, **kw)
        out = np.array(integrate_slices(D, S, A, B, **kw))
        assert np.abs(out).max() <= 1e-5 * magnitude(D, A, B, kw["L"])


def test_blockers_outside_the_view_take_the_fast_path(monkeypatch):
    """No blocker acts (β ≥ r, weight 0, γ ≥ d_count): the closed form (shared
    table and per-slice local variant) equals the tree and the oracle."""
    rng = np.random.default_rng(5)
    D, S, A, B, kw = random_case(rng, n=5, d=31, r=12, N=2, M=2)
    S = BlockerModes(S.beta + 20, S.weight)
    calls = []
    monkeypatch.setattr(pst, "_run_tree", lambda *a: calls.append(a))
    for L in (None, kw["L"]):
        for A_ in (A[:1], np.repeat(A[:1], 5, axis=0)):
            ref = integrate_slices_reference(D, S, A_, B, L=L)
            out = np.array(integrate_slices(D, S, A_, B, L=L))
            np.testing.assert_allclose(out, ref, rtol=1e-5,
                                       atol=1e-5 * magnitude(D, A_, B, L))
    assert not calls
    monkeypatch.undo()
    check(D, S, A, B, **kw)


def test_mixed_blocked_and_free_slices():
    rng = np.random.default_rng(6)
    D, S, A, B, kw = random_case(rng, n=8, d=20, r=10, N=1)
    S[::2] = INF
    check(D, S, A[:1], B, r_count=np.arange(3, 11), **kw)
    check(D, S, A[:1], B)


@pytest.mark.parametrize("d", [1, 2, 3, 1000])
def test_d_not_power_of_two(d):
    rng = np.random.default_rng(d)
    D, S, A, B, kw = random_case(rng, n=3, d=d, r=16, N=2, M=2)
    check(D, S, A, B, **kw)


def test_large_d_few_slices():
    rng = np.random.default_rng(8)
    D, S, A, B, kw = random_case(rng, n=2, d=4096, r=40, N=2)
    check(D, S, A, B, **kw)


def test_components_split_over_several_sweeps(monkeypatch):
    """When d·(C·N + 1) exceeds the local budget the components are chunked."""
    rng = np.random.default_rng(9)
    D, S, A, B, kw = random_case(rng, n=3, d=64, r=10, N=4, M=2, coloured=True)
    monkeypatch.setattr(pst, "LOCAL_BUDGET", 256 + 65 * 5)   # 5 of 12 per sweep
    check(D, S, A, B, **kw)


def test_dr_jit_inputs_equal_numpy_inputs():
    rng = np.random.default_rng(11)
    D, S, A, B, kw = random_case(rng, n=4, d=19, r=7, N=2, M=2)
    T = pst.jt.TensorXf
    out_np = np.array(integrate_slices(D, S, A, B, **kw))
    out_dr = integrate_slices(T(D), BlockerModes(T(S.beta), T(S.weight)), T(A), T(B),
                              L=T(kw["L"]))
    np.testing.assert_array_equal(np.array(out_dr), out_np)


def test_from_flat_builds_dense_modes():
    sl, ga = np.array([1, 0, 1, 1]), np.array([2, 0, 2, 0])
    be, we = np.array([3, 1, 5, 2.0]), np.array([0.5, 1, 0.25, 1])
    modes = BlockerModes.from_flat(2, 3, sl, ga, be, we)
    assert modes.beta.shape == (2, 3, 2)
    assert modes.beta[1, 2].tolist() == [3, 5] and modes.weight[1, 2].tolist() == [0.5, 0.25]
    assert modes.weight[0, 1].sum() == 0 and np.isinf(modes.beta[0, 1]).all()
    D = np.full((2, 6), 2.5, np.float32)
    check(D, modes, np.ones((3, 1)), np.ones((6, 1)))


def test_bad_shapes_are_rejected():
    D, S = np.zeros((2, 3)), np.zeros((2, 4))
    with pytest.raises(ValueError):
        integrate_slices(D, S, np.ones((5, 1)), np.ones((3, 1)))       # d mismatch
    with pytest.raises(ValueError):
        integrate_slices(D, S, np.ones((4, 2)), np.ones((3, 1)))       # N mismatch
    with pytest.raises(ValueError):
        integrate_slices(D, np.zeros((3, 4)), np.ones((4, 1)), np.ones((3, 1)))


def test_too_many_light_rays_is_an_error():
    d = 40000                       # tree + visibilities exceed local memory
    with pytest.raises(ValueError, match="light rays"):
        integrate_slices(np.ones((1, 2)), np.zeros((1, d)), np.ones((d, 1)),
                         np.ones((2, 1)))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 4),
       d=st.sampled_from([1, 5, 16, 37]), r=st.sampled_from([1, 7, 20]),
       N=st.integers(1, 4), M=st.sampled_from([1, 2]), with_L=st.booleans(),
       ragged=st.booleans())
def test_property_matches_oracle(seed, n, d, r, N, M, with_L, ragged):
    rng = np.random.default_rng(seed)
    D, S, A, B, kw = random_case(rng, n, d, r, N, M, with_L=with_L, ragged=ragged)
    check(D, S, A, B, **kw)
