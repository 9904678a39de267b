"""The LLVM check: an unusable LLVM gives a clear error, never an abort."""
import glob
import os
import subprocess
import sys

import pytest

from rectify import llvm


@pytest.mark.parametrize("name,major", [
    ("libLLVM.so.23.1", 23), ("libLLVM-19.so", 19), ("libLLVM.so.19.1", 19),
    ("libLLVM-15.so.1", 15), ("libLLVM-14.0.6.so.1", 14)])
def test_major_version_from_file_name(name, major):
    assert llvm._major_of(name) == major


def test_active_llvm_is_usable():
    import drjit as dr
    assert dr.detail.llvm_version()[0] >= llvm.MIN_MAJOR


OLD = sorted(glob.glob("/usr/lib/*/libLLVM-15.so*") + glob.glob("/usr/lib/*/libLLVM-14.so*"))


@pytest.mark.skipif(not OLD, reason="no libLLVM 14/15 on this machine to try")
@pytest.mark.parametrize("lib", OLD[:1] + OLD[-1:])
def test_old_llvm_raises_instead_of_aborting(lib):
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=lib)
    proc = subprocess.run([sys.executable, "-c", "import integrators"], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr[-2000:]   # an exception, not SIGABRT (-6)
    assert "LLVMVersionError" in proc.stderr
    assert "libllvm19" in proc.stderr and "karellen-llvm-core" in proc.stderr
