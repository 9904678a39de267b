"""``episcatter compare TEST.exr REF.exr [--json] [--block K] [--eps E]``.

Compares the main RGB layer of a test EXR against a reference EXR with
:func:`episcatter.metrics.compare` and prints an aligned table, or a JSON
object with ``--json`` (non-finite numbers are written as ``null``).
The CLI (``episcatter/cli.py``) wires this module in through
:func:`add_arguments` and :func:`run`.
"""

from __future__ import annotations

import argparse
import errno
import json
import math
import os

from . import metrics
from .imageio import read_rgb

# (key, label) of the rows of the text table, in order.
_TABLE_ROWS = (
    ("relmse", "relMSE"),
    ("rmse", "RMSE"),
    ("mape", "MAPE"),
    ("max_error", "max abs error"),
    ("max_error_over_peak", "max abs error / ref peak"),
    ("mean_ratio", "mean ratio (test/ref)"),
    ("flip", "HDR-FLIP (mean)"),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``compare`` arguments to ``parser``."""
    parser.add_argument("test", help="test image (EXR; its main R,G,B layer is used)")
    parser.add_argument("ref", help="reference image (EXR)")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")
    parser.add_argument("--block", type=int, default=1, metavar="K",
                        help="average both images over KxK blocks first (default: 1)")
    parser.add_argument("--eps", type=float, default=metrics.DEFAULT_EPS, metavar="E",
                        help="regularizer of relMSE and MAPE (default: %(default)g)")
    parser.add_argument("--eps-mode", choices=metrics.EPS_MODES, default=metrics.DEFAULT_EPS_MODE,
                        help="relMSE regulariser: relative (scale-free, default) = "
                             "E*mean(ref)^2, absolute = E (the first sessions' numbers)")


def _load(path: str, role: str):
    if not os.path.isfile(path):
        raise FileNotFoundError(errno.ENOENT, f"{role} image not found", path)
    return read_rgb(path)


def _json_safe(value):
    """Replace non-finite floats by None so the output is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _format_table(result: dict) -> str:
    """Aligned two-column text table of a :func:`metrics.compare` result."""
    eps = result["eps"]
    rows = [("test", result["test"]), ("reference", result["ref"]),
            ("size", "x".join(map(str, result["test_shape"][1::-1]))),
            ("block", f"{result['block']} (compared at "
                      f"{'x'.join(map(str, result['compared_shape'][1::-1]))})")]
    for key, label in _TABLE_ROWS:
        if key == "relmse":
            label = f"{label} ({result['relmse_convention']})"
        elif key == "mape":
            label = f"{label} (eps={eps:g})"
        rows.append((label, f"{result[key]:.6g}"))
    rows.append(("non-finite pixels", f"test {result['nonfinite_test']}, ref {result['nonfinite_ref']}"))
    width = max(len(label) for label, _ in rows)
    lines = [f"{label:<{width}}  {value}" for label, value in rows]
    if result["nonfinite_test"] or result["nonfinite_ref"]:
        lines.append(f"warning: non-finite pixels excluded; metrics over {result['pixels_used']} pixels")
    if result["nonfinite_ref"]:
        lines.append("warning: the reference has non-finite pixels; a volpath reference of a "
                     "medium with a zero sigma_t channel is NaN (use sigma_t > 0 in every "
                     "channel, or the exact reference)")
    if "flip_error" in result:
        lines.append(f"warning: FLIP not computed: {result['flip_error']}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the comparison described by parsed ``args``; returns the exit status."""
    test = _load(args.test, "test")
    ref = _load(args.ref, "reference")
    metrics.check_eps(args.eps, args.eps_mode)
    result = {"test": args.test, "ref": args.ref}
    result.update(metrics.compare(test, ref, block=args.block, eps=args.eps,
                                  eps_mode=args.eps_mode))
    if args.json:
        print(json.dumps({k: _json_safe(v) for k, v in result.items()}, indent=2))
    else:
        print(_format_table(result))
    return 0
