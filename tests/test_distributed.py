"""References and runs on a real dask.distributed LocalCluster (issue 17).

The fixture starts two worker processes on the loopback interface, one task
each at a time, and closes them at the end of the module.  A reference
rendered on them must equal the local render bit for bit, also when a
worker is killed mid-run, and an interrupted run must resume with exactly
the missing chunks.
"""
import functools
import os
import signal
import sys
import threading
import time

import numpy as np
import pytest

from episcatter import cli, distributed, reference
from episcatter.imageio import read_exr

SCENE = os.path.join(os.path.dirname(__file__), "data", "tiny_scene.xml")
#: 12 chunks of 32 spp at 48x36: long enough per chunk to kill a worker
#: mid-run, short enough for a loaded 2-core machine
DEFINES = {"res_x": 48, "res_y": 36}
SPP, CHUNK = 384, 32
N_CHUNKS = len(reference.chunk_plan(SPP, CHUNK))

dask_distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    import logging

    with dask_distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
            dashboard_address="127.0.0.1:0", resources={distributed.MACHINE_RESOURCE: 1},
            env={"OPENBLAS_NUM_THREADS": "1"}, silence_logs=logging.ERROR) as c:
        yield c


@pytest.fixture(scope="module")
def client(cluster):
    with dask_distributed.Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def local_reference(tmp_path_factory):
    """The reference rendered in this process: what every distributed run must equal."""
    folder = tmp_path_factory.mktemp("local")
    _, info = reference.render_reference(SCENE, DEFINES, spp=SPP, chunk=CHUNK,
                                         cache_dir=str(folder), progress=False)
    assert info["chunks_rendered"] == N_CHUNKS
    return read_exr(info["path"])


def render_on(cluster, **kw):
    return reference.render_reference(SCENE, DEFINES, spp=SPP, chunk=CHUNK, progress=False,
                                      scheduler=cluster.scheduler_address, **kw)


def assert_same_bits(info, layers):
    got = read_exr(info["path"])
    assert set(got) == set(layers)
    for name in layers:
        assert np.array_equal(got[name], layers[name], equal_nan=True), name
    assert [c["seed"] for c in info["chunks"]] == list(range(N_CHUNKS))


def test_distributed_reference_equals_local_bit_for_bit(cluster, cache, local_reference):
    rgb, info = render_on(cluster)
    assert info["chunks_rendered"] == N_CHUNKS
    assert all(c["worker"].startswith("tcp://127.0.0.1") for c in info["chunks"])
    assert np.array_equal(rgb, local_reference["full"])
    assert_same_bits(info, local_reference)


def test_killed_worker_loses_no_chunk(cluster, client, cache, local_reference):
    first_done, box = threading.Event(), {}

    def run():
        try:
            box["info"] = render_on(cluster, on_chunk=lambda done, total: first_done.set())[1]
        except BaseException as err:  # noqa: BLE001 -- re-raised below
            box["error"] = err

    thread = threading.Thread(target=run)
    thread.start()
    assert first_done.wait(120), "no chunk finished"
    pids = client.run(os.getpid)
    victim, deadline = None, time.monotonic() + 30
    while victim is None and time.monotonic() < deadline:
        busy = [w for w, keys in client.processing().items() if keys]
        victim = busy[0] if busy else None
    assert victim is not None, "no worker was busy after the first chunk"
    os.kill(pids[victim], signal.SIGKILL)      # mid-run: it holds a chunk
    thread.join(180)
    assert not thread.is_alive()
    if "error" in box:
        raise box["error"]
    info = box["info"]
    assert info["chunks_rendered"] == N_CHUNKS
    assert_same_bits(info, local_reference)
    assert pids[victim] not in client.run(os.getpid).values()


class Interrupt(KeyboardInterrupt):
    """Raised by an on_chunk hook to stop a render as Ctrl-C would."""


def test_interrupted_distributed_run_resumes_with_the_missing_chunks(cluster, cache,
                                                                     local_reference):
    def stop_after_4(done, total):
        if done >= 4:
            raise Interrupt

    with pytest.raises(Interrupt):
        render_on(cluster, on_chunk=stop_after_4)
    path = reference.reference_path(SCENE, DEFINES, SPP)
    store = reference.ChunkStore(reference.chunk_folder(path))
    plan = list(enumerate(reference.chunk_plan(SPP, CHUNK)))
    stored = set(store.stored(plan))
    assert len(stored) == 4 and not os.path.exists(path)

    _, info = render_on(cluster)
    assert (info["chunks_rendered"], info["chunks_resumed"]) == (N_CHUNKS - 4, 4)
    assert {c["seed"] for c in info["chunks"] if c["run"] == "this"} == \
        {seed for seed, _ in plan} - stored
    assert_same_bits(info, local_reference)


def test_map_runs_keeps_item_order_locally_and_on_the_cluster(cluster):
    items = [5, 1, 4, 2, 3, 0]
    fn = functools.partial(pow, 3)
    seen = []
    local = distributed.map_runs(fn, items, progress=False, on_result=lambda i, r: seen.append(i))
    assert local == [3 ** i for i in items] and seen == list(range(len(items)))
    remote = distributed.map_runs(fn, items, scheduler=cluster.scheduler_address,
                                  progress=False, timed=True)
    assert remote == local


def test_timed_runs_need_the_machine_resource():
    class NoResources:
        def scheduler_info(self):
            return {"workers": {"tcp://a": {"resources": {}}}}

    with pytest.raises(ValueError, match="--resources machine=1"):
        distributed._check_machine_resource(NoResources())


def test_scheduler_and_workers_conflict():
    assert not distributed.uses_dask()
    assert distributed.uses_dask("tcp://127.0.0.1:8786") and distributed.uses_dask(workers=2)
    with pytest.raises(ValueError, match="not both"):
        distributed.uses_dask("tcp://127.0.0.1:8786", 2)
    with pytest.raises(ValueError, match=">= 1"):
        distributed.uses_dask(workers=0)


def test_without_dask_local_runs_work_and_dask_options_name_the_extra(monkeypatch, capsys,
                                                                      cache):
    for name in [m for m in sys.modules if m == "distributed" or m.startswith("distributed.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "distributed", None)     # import fails
    assert distributed.map_runs(abs, [-1, 2], progress=False) == [1, 2]
    with pytest.raises(ImportError, match=r'pip install -e "\.\[distributed\]"'):
        distributed.require_dask()
    status = cli.main(["reference", SCENE, "--spp", "2", "--chunk", "1", "-D", "res_x=8",
                       "-D", "res_y=6", "--workers", "2", "--no-progress"])
    assert status == 2
    assert '".[distributed]"' in capsys.readouterr().err


def test_workers_start_a_local_cluster_with_pinned_timing(capsys):
    # timed runs: the 2 workers asked for become 1 with every core
    out = distributed.map_runs(functools.partial(pow, 2), [3, 1], workers=2, timed=True)
    assert out == [8, 2]
    text = capsys.readouterr().out
    assert "1 local worker with every core instead of 2" in text
    assert "started a local Dask cluster: 1 worker process(es)" in text
    assert f"{os.cpu_count()} Dr.Jit thread(s)" in text
    assert "dashboard" in text            # its address, or why there is none


def test_bench_jobs_run_as_tasks(cluster, tmp_path):
    from episcatter import bench

    # volpath on the scene of the references above: its kernels are compiled on the workers
    results = bench.run_bench([SCENE], ["volpath"], sweeps={"spp": [2, 4]},
                              defines={"res_x": 16, "res_y": 12}, reference=None,
                              out_dir=str(tmp_path / "bench"), repeats=1, progress=False,
                              scheduler=cluster.scheduler_address)
    assert [r["spp"] for r in results] == [2, 4]
    assert not any(r.get("error") for r in results)
    assert all(r["time_s"] > 0 for r in results)
