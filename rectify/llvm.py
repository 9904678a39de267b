"""Finding an LLVM that Dr.Jit's LLVM backend can use.

Dr.Jit 1.5 loads ``libLLVM`` when ``drjit`` is first imported.  It refuses
LLVM 14 and, with LLVM 15, *aborts the whole process* at the first
``dr.maximum`` ("LLVM ERROR: Cannot select ... fmaximum").  LLVM 16 and newer
work (tested: Debian's ``libllvm19``, and LLVM 23 from the PyPI wheel
``karellen-llvm-core``).

:func:`configure` runs before ``drjit`` is imported: when the user has not set
``DRJIT_LIBLLVM_PATH`` it points Dr.Jit at the newest usable ``libLLVM`` it
finds (system library folders first, then the ``karellen-llvm-core`` wheel,
whose C++ runtime libraries it preloads).  :func:`check` runs after the
variant is set and raises :class:`LLVMVersionError` with the fix instead of
letting the process abort later.
"""
from __future__ import annotations

import ctypes
import glob
import os
import re
import sys

MIN_MAJOR = 16

FIX = (
    "Install a newer LLVM and re-run: either `apt-get install libllvm19` "
    "(Debian/Ubuntu, needs root) or `pip install karellen-llvm-core` "
    "(no root needed); `bash install.sh` does whichever is possible. "
    "To choose a library by hand set DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so "
    "before Python starts."
)

SYSTEM_DIRS = (
    "/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64",
    "/usr/lib", "/usr/local/lib", "/opt/homebrew/opt/llvm/lib",
    "/usr/local/opt/llvm/lib",
)


#: the variant ``import integrators`` / ``import rectify`` set when none is active
DEFAULT_VARIANT = "llvm_ad_rgb"


class LLVMVersionError(ImportError):
    """Dr.Jit's LLVM backend is missing or uses an LLVM it cannot run with."""


def _major_of(path: str) -> int | None:
    """LLVM major version encoded in a library file name, if any."""
    name = os.path.basename(os.path.realpath(path))
    m = re.search(r"LLVM[-.]?(?:so\.)?(\d+)", name)
    return int(m.group(1)) if m else None


def system_candidates() -> list[tuple[int, str]]:
    """(major, path) of every libLLVM >= MIN_MAJOR in the usual library folders."""
    found = {}
    for d in SYSTEM_DIRS:
        for p in glob.glob(os.path.join(d, "libLLVM*.so*")) + glob.glob(
                os.path.join(d, "llvm-*", "lib", "libLLVM*.so*")):
            major = _major_of(p)
            if major is not None and major >= MIN_MAJOR:
                found.setdefault(os.path.realpath(p), major)
    return sorted(((m, p) for p, m in found.items()), reverse=True)


def wheel_candidate() -> str | None:
    """libLLVM of the ``karellen-llvm-core`` wheel, if installed: the wheel
    puts it in ``<prefix>/lib`` (the environment's or the user base's)."""
    import site
    prefixes = [sys.prefix, getattr(site, "USER_BASE", None) or site.getuserbase()]
    for prefix in prefixes:
        hits = sorted(glob.glob(os.path.join(prefix, "lib", "libLLVM.so.*")))
        hits = [h for h in hits if (_major_of(h) or 0) >= MIN_MAJOR]
        if hits:
            return hits[-1]
    return None


def _preload_wheel_runtime(lib: str) -> None:
    """The wheel's libLLVM links against its own libc++ stack (in
    ``lib/<target-triple>/``): load it globally first."""
    libdir = os.path.dirname(lib)
    dirs = [libdir] + sorted(glob.glob(os.path.join(libdir, "*-linux-gnu")))
    for stem in ("libunwind", "libc++abi", "libc++"):
        for d in dirs:
            hits = sorted(glob.glob(os.path.join(d, stem + ".so.*")))
            if hits:
                ctypes.CDLL(hits[0], mode=ctypes.RTLD_GLOBAL)
                break


def configure() -> str | None:
    """Choose a libLLVM for Dr.Jit before it is imported; returns the path used."""
    if "drjit" in sys.modules:
        return None  # too late to choose: check() will judge what was loaded
    chosen = os.environ.get("DRJIT_LIBLLVM_PATH")
    if chosen:
        return chosen
    cands = system_candidates()
    if cands:
        chosen = cands[0][1]
    else:
        chosen = wheel_candidate()
        if chosen:
            _preload_wheel_runtime(chosen)
    if chosen:
        os.environ["DRJIT_LIBLLVM_PATH"] = chosen
    return chosen


def check(variant: str) -> None:
    """Raise LLVMVersionError unless the LLVM backend (if used) is safe."""
    if not variant.startswith("llvm"):
        return
    import drjit as dr
    try:
        version = tuple(dr.detail.llvm_version())
    except Exception:  # backend failed to initialise
        version = ()
    if not version or version[0] == 0:
        raise LLVMVersionError(
            f"Dr.Jit found no usable LLVM for the '{variant}' variant. " + FIX)
    if version[0] < MIN_MAJOR:
        raise LLVMVersionError(
            f"Dr.Jit loaded LLVM {'.'.join(map(str, version))}; it needs "
            f"LLVM >= {MIN_MAJOR} (LLVM 15 aborts the process at the first "
            f"dr.maximum, LLVM 14 is refused). " + FIX)


def set_default_variant() -> None:
    """Set :data:`DEFAULT_VARIANT` when no Mitsuba variant is active (after
    :func:`configure`); an unusable LLVM raises :class:`LLVMVersionError`."""
    import mitsuba as mi
    if mi.variant() is None:
        try:
            mi.set_variant(DEFAULT_VARIANT)
        except ImportError as err:  # Dr.Jit found no LLVM it accepts (e.g. only 14)
            raise LLVMVersionError(f"{err} {FIX}") from err
