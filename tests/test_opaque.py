"""integrators.core.opaque: frame constants as kernel parameters, exact."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators.core.opaque import Divisor, reciprocal, scalar

DIVISORS = list(range(1, 130)) + [255, 256, 257, 1023, 1024, 1025, 4095, 4096, 4097, 65535,
                                  65536, 65537, 123456789, 2**31 - 1, 2**31, 2**32 - 1]


@pytest.mark.parametrize("d", DIVISORS)
def test_divisor_is_exact_on_every_kind_of_numerator(d):
    """Against NumPy's integer division: random 32-bit numerators, the
    small ones, multiples of d and their neighbours, the extremes."""
    rng = np.random.default_rng(d)
    k = np.arange(0, 2000, dtype=np.uint64) * d
    n = np.concatenate([rng.integers(0, 2**32, 20000, dtype=np.uint64), np.arange(3000),
                        k, k + 1, np.maximum(k, 1) - 1, [2**32 - 1, 2**31, 2**31 - 1]])
    n = n[n < 2**32].astype(np.uint32)
    q, r = Divisor(d).divmod(mi.UInt32(n))
    assert np.array_equal(np.asarray(q), n // d)
    assert np.array_equal(np.asarray(r), n % d)


def test_divisor_keeps_int32_lanes_int32():
    n = np.arange(0, 100000, dtype=np.int32)
    q, r = Divisor(7).divmod(mi.Int32(n))
    assert isinstance(q, mi.Int32)
    assert np.array_equal(np.asarray(q), n // 7) and np.array_equal(np.asarray(r), n % 7)


def test_divisor_refuses_zero():
    with pytest.raises(ValueError):
        Divisor(0)


def test_reciprocal_is_the_division_by_a_literal():
    """x · reciprocal(c) is bit for bit the x / c of a kernel with the literal c."""
    x = dr.arange(mi.Float, 1000) * 0.37 + 0.01
    for c in (3.0, 0.1, 7.3e-3, 1234.5):
        assert np.array_equal(np.asarray(x * reciprocal(c)), np.asarray(x / c))


def test_equal_values_are_separate_variables():
    """Two opaque scalars of equal value are two kernel parameters: values
    equal in one frame and not in the next (a light's coordinate and σt)
    must not change the kernel."""
    a, b = scalar(1.5), scalar(1.5)
    assert a.index != b.index
    a += 1.0
    assert float(b[0]) == 1.5


def test_opaque_scalars_keep_the_sign_of_zero_and_refuse_fractions():
    """-0.0 and +0.0 keep their signs (1/x, atan2 tell them apart); an
    integer scalar takes whole numbers only; scalars are made without a
    kernel."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    import pytest

    from rectify._dr import opaque_scalar

    pos, neg = opaque_scalar(mi.Float, 0.0), opaque_scalar(mi.Float, -0.0)
    assert np.array(dr.rcp(pos))[0] == np.inf and np.array(dr.rcp(neg))[0] == -np.inf
    with pytest.raises(ValueError, match="whole number"):
        opaque_scalar(mi.UInt32, 3.7)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    a, b = opaque_scalar(mi.UInt32, 5), opaque_scalar(mi.UInt32, 5)
    assert [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT] == []
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert a.index != b.index and np.array(a)[0] == 5


def test_equal_sizes_in_one_frame_and_not_the_next_write_one_kernel():
    """Whether two opaque scalars are equal does not change the kernel
    (shared by value, it did)."""
    import drjit as dr
    import mitsuba as mi

    from episcatter.kernels import kernel_log
    from rectify._dr import opaque_scalar

    def frame(r, d):
        x = dr.arange(mi.UInt32, 64)
        y = x * opaque_scalar(mi.UInt32, r) + opaque_scalar(mi.UInt32, d)
        dr.eval(y)

    frame(7, 9)
    with kernel_log() as log:
        frame(8, 8)
        frame(5, 6)
    assert log.launched == 2 and log.compiled == 0
