"""The Dask worker plugin that prepares a worker process for Mitsuba renders.

Imported only when Dask is used (:mod:`episcatter.distributed` imports it
after checking that the optional extra is installed).
"""
from __future__ import annotations

from distributed.diagnostics.plugin import WorkerPlugin


class EpiscatterSetup(WorkerPlugin):
    """Runs once in every worker process, also in one restarted after a
    crash: ``import integrators`` (registers the plugins, configures LLVM),
    sets the client's Mitsuba ``variant`` and Dr.Jit's thread count
    (``drjit_threads``; None leaves Dr.Jit's default, all cores)."""

    def __init__(self, variant: str, drjit_threads: int | None = None):
        self.variant = variant
        self.drjit_threads = drjit_threads

    def setup(self, worker):
        import integrators  # noqa: F401  (registers plugins, configures LLVM)
        import drjit as dr
        import mitsuba as mi

        if mi.variant() != self.variant:
            mi.set_variant(self.variant)
        if self.drjit_threads:
            dr.set_thread_count(int(self.drjit_threads))
