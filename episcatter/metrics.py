"""Error metrics between a test rendering and a reference (NumPy only).

Inputs are linear RGB images of shape (H, W, 3) (the pixel-wise metrics
accept any matching shapes).  All pixel-wise metrics average over pixels
*and* channels.  :func:`compare` bundles everything, optionally at a coarser
pixel footprint (``block``), and handles non-finite pixels explicitly.
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_EPS = 1e-2
"""Default regularizer of :func:`relmse`, :func:`mape` and :func:`noise_relmse`."""

EPS_MODES = ("relative", "absolute")
"""How relMSE's regulariser is meant (DESIGN §2): ``relative`` = ``eps *
mean(ref)**2`` (:func:`scale_free_relmse`, the default everywhere), or
``absolute`` = ``eps`` itself (:func:`relmse_absolute`, the numbers of the first
sessions)."""
DEFAULT_EPS_MODE = "relative"


def check_eps(eps, eps_mode: str = DEFAULT_EPS_MODE) -> float:
    """``eps`` as a float if it is a usable relMSE regulariser, else a
    ``ValueError`` naming the fix (``eps <= 0`` divides by zero on black
    reference pixels; an unknown mode is not one of :data:`EPS_MODES`)."""
    if eps_mode not in EPS_MODES:
        raise ValueError(f"eps mode '{eps_mode}' is not one of {list(EPS_MODES)}.")
    try:
        value = float(eps)
    except (TypeError, ValueError):
        raise ValueError(f"eps = {eps!r} is not a number; use e.g. {DEFAULT_EPS:g}.") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"eps = {eps!r} must be a finite number > 0 (relMSE divides by "
                         f"ref^2 + eps, which is 0 on black pixels); use e.g. {DEFAULT_EPS:g}.")
    return value


def eps_text(eps: float, eps_mode: str = DEFAULT_EPS_MODE) -> str:
    """The relMSE convention in words, for tables and printed output."""
    if eps_mode == "relative":
        return f"scale-free relMSE, eps {eps:g}·mean(ref)²"
    return f"absolute-eps relMSE, eps {eps:g}"


def _as_float(img) -> np.ndarray:
    return np.asarray(img, dtype=np.float64)


def _check_same_shape(test: np.ndarray, ref: np.ndarray) -> None:
    if test.shape != ref.shape:
        raise ValueError(f"shape mismatch: test image {test.shape} vs reference image {ref.shape}")


def _pair(test, ref) -> tuple[np.ndarray, np.ndarray]:
    test, ref = _as_float(test), _as_float(ref)
    _check_same_shape(test, ref)
    return test, ref


def _check_rgb(img: np.ndarray, what: str) -> None:
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"{what} image must have shape (H, W, 3), got {img.shape}")


# --------------------------------------------------------------------------
# Pixel footprint
# --------------------------------------------------------------------------

def block_average(img, k: int) -> np.ndarray:
    """Average ``img`` over non-overlapping k x k pixel blocks.

    ``img`` is (H, W) or (H, W, C); the result is (H // k, W // k[, C]) in
    float64.  The remainder rows/columns (the last ``H % k`` rows and
    ``W % k`` columns) are cropped away, not padded.  ``k == 1`` returns the
    image unchanged (as float64).  Used to compare renderings at a matched
    pixel footprint (e.g. a k-times supersampled reference).
    """
    img = _as_float(img)
    if isinstance(k, bool) or int(k) != k or k < 1:
        raise ValueError(f"block size must be a positive integer, got {k!r}")
    k = int(k)
    if img.ndim not in (2, 3):
        raise ValueError(f"expected an (H, W) or (H, W, C) image, got shape {img.shape}")
    h, w = img.shape[0] // k, img.shape[1] // k
    if h == 0 or w == 0:
        raise ValueError(f"block size {k} is larger than the image ({img.shape[0]} x {img.shape[1]})")
    if k == 1:
        return img
    cropped = img[: h * k, : w * k]
    blocks = cropped.reshape((h, k, w, k) + img.shape[2:])
    return blocks.mean(axis=(1, 3))


# --------------------------------------------------------------------------
# Pixel-wise metrics
# --------------------------------------------------------------------------

def relmse_absolute(test, ref, eps: float = DEFAULT_EPS) -> float:
    """Relative mean squared error with an *absolute* regulariser, mean over
    pixels and channels of ``(test - ref)**2 / (ref**2 + eps)``; default
    ``eps = 1e-2`` (added to the *squared* reference, so it matters where
    |ref| is below ~0.1: for dim images it is MSE / eps, and it depends on
    the exposure -- the default everywhere is :func:`relmse`, scale-free)."""
    test, ref = _pair(test, ref)
    return float(np.mean((test - ref) ** 2 / (ref**2 + eps)))


def scale_free_relmse(test, ref, eps: float = DEFAULT_EPS) -> float:
    """Scale-free relative MSE (DESIGN §2): mean over pixels and channels of
    ``(test - ref)**2 / (ref**2 + eps * mean(ref)**2)``, default
    ``eps = 1e-2``.  The regulariser is relative to the reference's own mean,
    so multiplying both images by any positive constant leaves the value
    unchanged; an all-black reference gives 0 where ``test == ref`` and
    ``inf`` elsewhere."""
    test, ref = _pair(test, ref)
    floor = eps * float(np.mean(ref)) ** 2
    if floor <= 0.0:
        diff = (test - ref) ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(diff == 0.0, 0.0, diff / (ref**2))
        return float(np.mean(q))
    return float(np.mean((test - ref) ** 2 / (ref**2 + floor)))


#: the relMSE every table reports: :func:`scale_free_relmse` (the
#: exposure-dependent form is :func:`relmse_absolute`)
relmse = scale_free_relmse


def relmse_floor(ref, eps: float = DEFAULT_EPS, eps_mode: str = DEFAULT_EPS_MODE) -> float:
    """The term added to ``ref**2`` in relMSE's denominator: ``eps *
    mean(ref)**2`` (``relative``) or ``eps`` (``absolute``)."""
    if eps_mode == "absolute":
        return float(eps)
    check_eps(eps, eps_mode)
    return float(eps) * float(np.mean(_as_float(ref))) ** 2


def relmse_by_mode(test, ref, eps: float = DEFAULT_EPS,
                   eps_mode: str = DEFAULT_EPS_MODE) -> float:
    """:func:`scale_free_relmse` (``relative``, the default) or
    :func:`relmse_absolute` (``absolute``)."""
    check_eps(eps, eps_mode)
    if eps_mode == "absolute":
        return relmse_absolute(test, ref, eps)
    return scale_free_relmse(test, ref, eps)


def rmse(test, ref) -> float:
    """Root mean squared error over pixels and channels."""
    test, ref = _pair(test, ref)
    return float(np.sqrt(np.mean((test - ref) ** 2)))


def mape(test, ref, eps: float = DEFAULT_EPS) -> float:
    """Mean absolute percentage error (as a fraction), mean over pixels and
    channels of ``|test - ref| / (|ref| + eps)``; default ``eps = 1e-2``."""
    test, ref = _pair(test, ref)
    return float(np.mean(np.abs(test - ref) / (np.abs(ref) + eps)))


def max_error(test, ref) -> float:
    """Largest absolute per-channel difference."""
    test, ref = _pair(test, ref)
    return float(np.max(np.abs(test - ref)))


def max_error_over_peak(test, ref) -> float:
    """:func:`max_error` divided by the reference's largest value (scale-free,
    DESIGN §2); NaN for an all-black (or negative) reference."""
    test, ref = _pair(test, ref)
    peak = float(np.max(ref))
    return max_error(test, ref) / peak if peak > 0.0 else float("nan")


def mean_ratio(test, ref) -> float:
    """``mean(test) / mean(ref)`` over all pixels and channels (1 means no
    overall energy bias); NaN if ``mean(ref) == 0``."""
    test, ref = _pair(test, ref)
    denom = float(np.mean(ref))
    return float(np.mean(test)) / denom if denom != 0.0 else float("nan")


# --------------------------------------------------------------------------
# FLIP
# --------------------------------------------------------------------------

# Below this reference peak luminance FLIP's automatic exposure range becomes
# invalid (start > stop) and the native library terminates the process.
_FLIP_MIN_PEAK = 1e-4


def _flip_input(img: np.ndarray) -> np.ndarray:
    """Non-negative, finite, contiguous float32 copy (what HDR-FLIP expects)."""
    img = np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0)
    return np.ascontiguousarray(np.clip(img, 0.0, None), dtype=np.float32)


def flip(test, ref, parameters: dict | None = None) -> float:
    """Mean HDR-FLIP error of ``test`` against ``ref`` (both (H, W, 3) linear RGB).

    Uses ``flip_evaluator.evaluate(ref, test, "HDR")`` on in-memory arrays
    (never file paths).  Negative and non-finite values are set to 0 first.
    ``parameters`` is passed to FLIP (e.g. ``{"ppd": 67.0}``; default: FLIP's
    own defaults, including its automatic exposure range from the reference).

    If the reference peak luminance is below 1e-4, both images are scaled by
    the same factor so that it becomes 1: FLIP's automatic exposure range is
    invalid for such dark references and the native library would terminate
    the whole process.  An all-black reference raises ValueError, as does
    any argument that makes FLIP call ``sys.exit``.
    """
    import flip_evaluator

    test, ref = _pair(test, ref)
    _check_rgb(test, "test")
    ref_f, test_f = _flip_input(ref), _flip_input(test)
    peak = float(np.max(ref_f @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)))
    if peak <= 0.0:
        raise ValueError("HDR-FLIP is undefined for an all-black reference image")
    if peak < _FLIP_MIN_PEAK:
        ref_f, test_f = ref_f / peak, test_f / peak
    try:
        _, mean_error, _ = flip_evaluator.evaluate(
            ref_f, test_f, "HDR", applyMagma=False, computeMeanError=True,
            parameters=dict(parameters or {}))
    except SystemExit as exc:
        raise ValueError(f"flip_evaluator rejected its arguments (parameters={parameters!r})") from exc
    return float(mean_error)


# --------------------------------------------------------------------------
# Bundles
# --------------------------------------------------------------------------

def _nonfinite_pixels(img: np.ndarray) -> np.ndarray:
    """Boolean (H, W) mask of pixels with at least one non-finite channel."""
    return ~np.all(np.isfinite(img), axis=-1)


def compare(test, ref, block: int = 1, eps: float = DEFAULT_EPS,
            eps_mode: str = DEFAULT_EPS_MODE) -> dict:
    """All metrics of ``test`` against ``ref`` (both (H, W, 3) linear RGB).

    Both images are first block-averaged with ``block`` (see
    :func:`block_average`).  Returns a dict with

    - ``relmse`` (:func:`relmse_by_mode`: scale-free by default,
      ``eps_mode="absolute"`` for the absolute form), ``rmse``, ``mape``
      (absolute ``eps``), ``max_error``, ``max_error_over_peak``,
      ``mean_ratio``: computed over the (block) pixels where both images
      are finite;
    - ``flip``: mean HDR-FLIP on the block-averaged images with non-finite
      values set to 0 (NaN, with ``flip_error`` giving the reason, if FLIP
      cannot be evaluated, e.g. for an all-black reference);
    - ``nonfinite_test`` / ``nonfinite_ref``: number of full-resolution
      pixels with a NaN/Inf channel; ``pixels_used``: number of (block)
      pixels the pixel-wise metrics were computed on;
    - ``test_shape``, ``ref_shape``, ``compared_shape``, ``block``, ``eps``,
      ``eps_mode`` and ``relmse_convention`` (:func:`eps_text`).

    Raises ValueError if the shapes differ (naming both) or are not (H, W, 3),
    or if ``eps`` is not > 0 (:func:`check_eps`).
    """
    eps = check_eps(eps, eps_mode)
    test, ref = _as_float(test), _as_float(ref)
    _check_same_shape(test, ref)
    _check_rgb(test, "test")
    result: dict = {
        "test_shape": list(test.shape),
        "ref_shape": list(ref.shape),
        "block": int(block),
        "eps": float(eps),
        "eps_mode": eps_mode,
        "relmse_convention": eps_text(eps, eps_mode),
        "nonfinite_test": int(_nonfinite_pixels(test).sum()),
        "nonfinite_ref": int(_nonfinite_pixels(ref).sum()),
    }
    test_b, ref_b = block_average(test, block), block_average(ref, block)
    result["compared_shape"] = list(test_b.shape)

    valid = ~(_nonfinite_pixels(test_b) | _nonfinite_pixels(ref_b))
    result["pixels_used"] = int(valid.sum())
    t, r = test_b[valid], ref_b[valid]
    if t.size:
        result.update(relmse=relmse_by_mode(t, r, eps, eps_mode), rmse=rmse(t, r),
                      mape=mape(t, r, eps), max_error=max_error(t, r),
                      max_error_over_peak=max_error_over_peak(t, r), mean_ratio=mean_ratio(t, r))
    else:
        result.update({k: float("nan") for k in ("relmse", "rmse", "mape", "max_error",
                                                  "max_error_over_peak", "mean_ratio")})

    try:
        result["flip"] = flip(test_b, ref_b)
    except ValueError as exc:
        result["flip"] = float("nan")
        result["flip_error"] = str(exc)
    return result


def noise_relmse(half_a, half_b, block: int = 1, eps: float = DEFAULT_EPS,
                 eps_mode: str = DEFAULT_EPS_MODE) -> float:
    """Estimate the relMSE noise level of a Monte Carlo image from two halves.

    ``half_a`` and ``half_b`` are two statistically independent renderings
    of the same image with equal sample counts; the estimate of interest is
    their mean ``m = (a + b) / 2``.  If each half has per-pixel variance
    ``s**2``, then ``E[(a - b)**2] = 2 s**2`` while ``Var[m] = s**2 / 2``, so
    ``(a - b)**2 / 4`` is an unbiased per-pixel estimate of ``Var[m]``.  The
    return value is the mean over pixels and channels of
    ``(a - b)**2 / 4 / (m**2 + floor)`` with :func:`relmse_floor` of ``m``,
    i.e. the expected :func:`relmse_by_mode` (same ``eps`` and
    ``eps_mode``) of ``m`` against the noise-free image, up
    to the small error of using the noisy ``m`` in the denominator.  It
    measures variance only, not bias.  With ``block > 1`` both halves are
    block-averaged first, giving the noise at that pixel footprint.
    """
    a, b = _pair(half_a, half_b)
    a, b = block_average(a, block), block_average(b, block)
    variance_of_mean = (a - b) ** 2 / 4.0
    mean = (a + b) / 2.0
    return float(np.mean(variance_of_mean / (mean**2 + relmse_floor(mean, eps, eps_mode))))


def noise_relmse_from_variance(mean, variance, block: int = 1, eps: float = DEFAULT_EPS,
                               eps_mode: str = DEFAULT_EPS_MODE) -> float:
    """relMSE noise of a Monte Carlo image ``mean`` from its per-pixel
    variance-of-the-mean estimate ``variance`` (e.g. from K independent
    chunks: Σ(x_c - x̄)² / (K(K-1)), K-1 degrees of freedom instead of the
    one of :func:`noise_relmse`; same ``eps`` and ``eps_mode``).  Pixels are
    independent, so a k×k block's variance is the block mean of the pixel
    variances divided by k²."""
    m, v = _pair(mean, variance)
    m = block_average(m, block)
    v = block_average(v, block) / float(block * block)
    return float(np.mean(v / (m**2 + relmse_floor(m, eps, eps_mode))))
