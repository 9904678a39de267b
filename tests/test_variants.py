"""Variants: the three integrators render in ``llvm_ad_rgb``, then
``llvm_ad_mono``, then ``llvm_ad_rgb`` again in one process (a subprocess, so
the switching does not disturb the other tests), each close to the exact
marcher of the same variant; variants the code cannot serve raise a
ValueError naming the supported ones before any work."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: scale-free relMSE bound against raymarch exact (24x18, pixel centres);
#: the test scene's errors are 2e-7 (raymarch) .. 2e-3 (fourier_filter, spot)
BOUND = 5e-3


def run_script(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=1800)


@pytest.mark.slow
def test_rgb_mono_rgb_in_one_process():
    proc = run_script("tests.variant_switch_script", "llvm_ad_rgb", "llvm_ad_mono", "llvm_ad_rgb")
    assert proc.returncode == 0, proc.stderr[-3000:]
    # Mitsuba's log (e.g. the mono film warning) shares stdout: rows are marked
    rows = [json.loads(line.split("ROW ", 1)[1]) for line in proc.stdout.splitlines()
            if "ROW " in line]
    assert len(rows) == 3 * 2 * 3
    for r in rows:
        assert r["finite"] and r["relmse"] < BOUND, r
        assert r["channels"] == (1 if "mono" in r["variant"] else 3), r
    first, again = rows[:6], rows[12:]
    assert first == again      # switching variants back and forth changes nothing


UNSUPPORTED = """
import integrators, mitsuba as mi
from integrators.template.base import check_variant
for v in {variants!r}:
    try:
        check_variant(v)
        print("accepted", v)
    except ValueError as e:
        print("ValueError", v, e)
    mi.set_variant(v)
    for kind in ("raymarch", "epipolar_tree", "fourier_filter"):
        try:
            mi.load_dict({{"type": kind}})
            print("loaded", v, kind)
        except Exception as e:
            print("refused", v, kind, "ValueError" in str(e) and "llvm_ad_rgb" in str(e))
"""


def test_unsupported_variants_raise_a_clear_error():
    variants = ["scalar_rgb", "llvm_ad_spectral"]
    proc = subprocess.run([sys.executable, "-c", UNSUPPORTED.format(variants=variants)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout.splitlines()
    for v in variants:
        line = next(x for x in out if x.split()[:2] == ["ValueError", v])
        assert "llvm_ad_rgb" in line and "llvm_ad_mono" in line, line
        for kind in ("raymarch", "epipolar_tree", "fourier_filter"):
            assert f"refused {v} {kind} True" in out, out
