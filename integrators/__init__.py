"""episcatter's Mitsuba integrators.

``import integrators`` makes every method available to Mitsuba scene files
(``<integrator type="raymarch"/>`` ...) for the active variant, and for any
variant set later.  When no variant is active it sets ``llvm_ad_rgb``.

Before Dr.Jit is first imported it picks an LLVM that Dr.Jit can run with
(see :mod:`integrators.llvm`); with an unusable LLVM it raises
:class:`integrators.llvm.LLVMVersionError` naming the fix instead of letting
the process abort later.
"""
from . import llvm as _llvm

_llvm.configure()

import importlib  # noqa: E402

import mitsuba as mi  # noqa: E402

DEFAULT_VARIANT = "llvm_ad_rgb"

#: one module per method; each ends with its mi.register_integrator call.
METHOD_MODULES = (
    "integrators.raymarch",
    "integrators.epipolar_tree",
    "integrators.fourier_filter",
    "integrators.minmax_epipolar",
)


def _register_for_current_variant(*_):
    """(Re)load the method modules for the active variant: their classes
    subclass that variant's ``mi.SamplingIntegrator``, and each module
    registers its plugin when it is loaded."""
    variant = mi.variant()
    if variant is None:
        return
    _llvm.check(variant)
    importlib.reload(importlib.import_module("integrators.template"))
    for module in METHOD_MODULES:
        importlib.reload(importlib.import_module(module))


if mi.variant() is None:
    try:
        mi.set_variant(DEFAULT_VARIANT)
    except ImportError as err:  # Dr.Jit found no LLVM it accepts (e.g. only 14)
        raise _llvm.LLVMVersionError(f"{err} {_llvm.FIX}") from err
_register_for_current_variant()
mi.detail.add_variant_callback(_register_for_current_variant)
