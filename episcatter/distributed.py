"""Independent runs (reference chunks, benchmark jobs) on Dask, or in this process.

:func:`map_runs` is the one entry point: ``map_runs(fn, items)`` calls
``fn(item)`` for every item and returns the results in item order.  With
neither ``scheduler`` nor ``workers`` it is a plain loop in this process
and Dask is not imported (it is an optional extra:
``pip install -e ".[distributed]"``).  With ``scheduler="tcp://host:8786"``
the runs are tasks on that cluster; with ``workers=K`` a local cluster of K
worker processes is started on the loopback interface for the call, its
dashboard address printed, and closed afterwards.

Results reach the client as they complete (``on_result(index, result)``,
e.g. to store a finished chunk at once); the returned list is in item order
whatever the completion order, so merging is deterministic.  A worker that
dies mid-task loses nothing: the scheduler runs its tasks again elsewhere.

Worker processes: each is set up once by
:class:`episcatter.dask_setup.EpiscatterSetup` (a Dask worker plugin):
``import integrators`` (registers the plugins, configures LLVM), the
client's Mitsuba variant, and Dr.Jit's thread pool sized so the workers of
one machine do not oversubscribe its cores (``dr.set_thread_count``).  Workers run one task at a time (``nthreads=1``).

Timing stays pinned (``timed=True``): a timed task requires the worker
resource ``machine=1``.  Every worker this module starts has it, and a local
cluster for timed runs has a single worker with all the cores, so a timed
render never shares a machine's cores with another task.  On a cluster,
start one worker per machine with that resource::

    dask scheduler                                   # prints tcp://HOST:8786
    OPENBLAS_NUM_THREADS=1 dask worker tcp://HOST:8786 --nworkers 1 --nthreads 1 --resources machine=1
"""
from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import sys

EXTRA_HINT = ('Dask is not installed: --scheduler/--workers need the optional extra, '
              'pip install -e ".[distributed]" (dask[distributed]).')
#: the worker resource a timed task requires (one per machine)
MACHINE_RESOURCE = "machine"
PLUGIN_NAME = "episcatter-setup"


def require_dask():
    """The ``distributed`` module, or an ImportError naming the extra to install."""
    try:
        import distributed
    except ImportError as err:
        raise ImportError(EXTRA_HINT) from err
    return distributed


def uses_dask(scheduler=None, workers=None) -> bool:
    """Whether these arguments ask for Dask (checks they do not conflict)."""
    if scheduler and workers:
        raise ValueError("Give either --scheduler ADDRESS (an existing cluster) or "
                         "--workers K (a local cluster), not both.")
    if workers is not None and int(workers) < 1:
        raise ValueError(f"workers = {workers} must be >= 1.")
    return bool(scheduler) or workers is not None


def add_cluster_arguments(parser, runs: str, note: str = "") -> None:
    """Add ``--scheduler ADDRESS | --workers K`` (mutually exclusive) to a
    command's argparse ``parser``; ``runs`` names what becomes tasks."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", default=None,
                       help=f"run the {runs} on the Dask cluster of this scheduler "
                            f"(tcp://host:8786; needs the [distributed] extra){note}")
    where.add_argument("--workers", type=int, metavar="K", default=None,
                       help=f"run the {runs} on a local Dask cluster of K worker processes")


def worker_name() -> str:
    """The address of the Dask worker running this code, or ``'local'``."""
    if "distributed" not in sys.modules:
        return "local"
    try:
        return sys.modules["distributed"].get_worker().address
    except ValueError:  # not inside a worker
        return "local"


def _has_dashboard(verbose) -> bool:
    """Whether the Dask dashboard can run (it needs bokeh); says so if not."""
    if importlib.util.find_spec("bokeh") is None:
        if verbose:
            print("Dask dashboard: off (bokeh is not installed; `pip install bokeh` for it)")
        return False
    return True


@contextlib.contextmanager
def dask_client(scheduler=None, workers=None, timed=False, drjit_threads=None, verbose=True):
    """A ``distributed.Client`` with :class:`~episcatter.dask_setup.EpiscatterSetup` registered.

    ``scheduler``: address of a running scheduler.  ``workers``: start a
    local cluster of that many single-threaded worker processes on
    127.0.0.1 (one if ``timed``), each with ``drjit_threads`` Dr.Jit threads
    (default: the CPU count divided among the workers).  Closed on exit.
    """
    import mitsuba as mi

    uses_dask(scheduler, workers)
    distributed = require_dask()
    from .dask_setup import EpiscatterSetup

    with contextlib.ExitStack() as stack:
        if scheduler:
            client = stack.enter_context(distributed.Client(scheduler))
        else:
            k, drjit_threads = _local_size(int(workers), timed, drjit_threads, verbose)
            dashboard = _has_dashboard(verbose)
            cluster = stack.enter_context(distributed.LocalCluster(
                n_workers=k, threads_per_worker=1, processes=True, host="127.0.0.1",
                resources={MACHINE_RESOURCE: 1}, env={"OPENBLAS_NUM_THREADS": "1"},
                dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR))
            client = stack.enter_context(distributed.Client(cluster))
            if verbose:
                link = f", dashboard {cluster.dashboard_link}" if dashboard else ""
                print(f"started a local Dask cluster: {k} worker process(es), one task each at "
                      f"a time, {drjit_threads} Dr.Jit thread(s) each{link}")
        client.register_plugin(EpiscatterSetup(mi.variant(), drjit_threads), name=PLUGIN_NAME)
        if timed:
            _check_machine_resource(client)
        yield client


def _local_size(k, timed, drjit_threads, verbose):
    """(worker processes, Dr.Jit threads each) of a local cluster."""
    if timed and k > 1:
        if verbose:
            print(f"timed runs: 1 local worker with every core instead of {k} "
                  "(a timed render never shares the machine)")
        k = 1
    return k, drjit_threads or max(1, (os.cpu_count() or 1) // k)


def _check_machine_resource(client) -> None:
    workers = client.scheduler_info().get("workers", {})
    if not any(MACHINE_RESOURCE in (w.get("resources") or {}) for w in workers.values()):
        raise ValueError(
            f"Timed runs need workers with the resource '{MACHINE_RESOURCE}=1' (one per "
            f"machine), and none of the {len(workers)} workers has it: start them as "
            f"`dask worker ADDRESS --nworkers 1 --nthreads 1 --resources {MACHINE_RESOURCE}=1`.")


def map_runs(fn, items, scheduler=None, workers=None, progress=True, desc="runs",
             unit="run", timed=False, on_result=None, collect=True,
             drjit_threads=None) -> list:
    """``[fn(item) for item in items]``, locally or as Dask tasks.

    ``fn`` and the items must be picklable for Dask (a module-level function,
    ``functools.partial`` of one).  ``on_result(index, result)`` runs on the
    client as each run completes (completion order); the returned list is in
    item order (``collect=False``: not kept, None each; for large results
    that ``on_result`` stores).  ``timed``: the runs measure time, see the
    module docstring; ``drjit_threads``: of each local worker.
    A tqdm bar on the client shows completed/total runs and throughput.  A
    failing run raises its exception on the client (the other tasks are
    cancelled); results already passed to ``on_result`` stay delivered.
    """
    from tqdm.auto import tqdm

    items = list(items)
    results = [None] * len(items)
    if not uses_dask(scheduler, workers) or not items:
        with tqdm(total=len(items), desc=desc, unit=unit, disable=not progress) as bar:
            for i, item in enumerate(items):
                _deliver(results, i, fn(item), on_result, collect)
                bar.update()
        return results
    with dask_client(scheduler, workers, timed, drjit_threads, verbose=progress) as client, \
            tqdm(total=len(items), desc=desc, unit=unit, disable=not progress) as bar:
        distributed = require_dask()
        resources = {MACHINE_RESOURCE: 1} if timed else None
        futures = [client.submit(fn, item, pure=False, resources=resources) for item in items]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for future in distributed.as_completed(futures):
                result = future.result()
                future.release()
                _deliver(results, index[future.key], result, on_result, collect)
                bar.update()
        finally:
            client.cancel([f for f in futures if not f.done()])
    return results


def _deliver(results, i, result, on_result, collect) -> None:
    if on_result is not None:
        on_result(i, result)
    if collect:
        results[i] = result
