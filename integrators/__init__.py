"""episcatter's Mitsuba integrators.

``import integrators`` makes every method available to Mitsuba scene files
(``<integrator type="raymarch"/>`` ...) for the active variant, and for any
variant set later.  When no variant is active it sets ``llvm_ad_rgb``.

Before Dr.Jit is first imported it picks an LLVM that Dr.Jit can run with
(see :mod:`rectify.llvm`); with an unusable LLVM it raises
:class:`rectify.llvm.LLVMVersionError` naming the fix instead of letting
the process abort later.
"""
from rectify import llvm as _llvm  # configures LLVM and the default variant on import

import importlib  # noqa: E402

import mitsuba as mi  # noqa: E402


DEFAULT_VARIANT = _llvm.DEFAULT_VARIANT

#: the modules defining integrator base classes (subclasses of the active
#: variant's ``mi.SamplingIntegrator``), reloaded first, in this order
TEMPLATE_MODULES = (
    "integrators.template.base",
    "integrators.template.epipolar",
)
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
    for module in TEMPLATE_MODULES + METHOD_MODULES:
        importlib.reload(importlib.import_module(module))


_register_for_current_variant()
mi.detail.add_variant_callback(_register_for_current_variant)
