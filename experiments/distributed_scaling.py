"""Scaling of a volpath reference on Dask workers (issue 17), and the cost per chunk.

A volpath reference (``episcatter.reference.render_reference``) is rendered
in this process, then on a local Dask cluster of 1 and of 2 worker
processes (one task at a time each, Dr.Jit threads = cores / workers), every
run re-rendering all chunks (``force``).  The clusters are started and
warmed up (kernels compiled on every worker) before the timed runs: times
are the wall time of ``render_reference`` (submit, render, transfer, store,
merge, write), the median of ``--repeats`` runs.

The cost per chunk is measured apart with many 1-spp chunks, where the
render itself is short: (wall time on 1 worker - wall time in this process)
- the client's connection, timed apart) / chunks = what Dask adds to one
chunk (task round trip, the image's transfer, pickling) on top of what both
paths do (storing the chunk).

Writes ``results/distributed_scaling/``: ``runs.csv`` (every run),
``scaling.csv``, ``table.md``, ``scaling.json`` (settings, environment and
machine load before and after each configuration).  The machine is shared:
read the load next to every number.
"""
from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import tempfile
import time

from episcatter import distributed
from episcatter.reference import chunk_plan, render_reference

from . import common

NAME = "distributed_scaling"


def settings_for(quick: bool) -> dict:
    if quick:
        return {"scene": "nave_offscreen", "res": (32, 24), "spp": 16, "chunk": 4,
                "overhead_spp": 8, "workers": [1, 2]}
    return {"scene": "nave_offscreen", "res": (320, 240), "spp": 256, "chunk": 16,
            "overhead_spp": 64, "workers": [1, 2]}


def timed_references(scene, defines, spp, chunk, repeats, cache_dir, scheduler=None):
    """Run rows of ``repeats`` forced renders of one reference."""
    rows = []
    for r in range(repeats):
        t0 = time.perf_counter()
        _, info = render_reference(scene, defines, spp=spp, chunk=chunk, cache_dir=cache_dir,
                                   progress=False, force=True, scheduler=scheduler)
        wall = time.perf_counter() - t0
        rows.append({"repeat": r, "wall_s": wall, "chunks": len(info["seeds"]),
                     "chunk_render_s": sum(info["chunk_time_s"]),
                     "workers_used": len({c["worker"] for c in info["chunks"]})})
    return rows


def measure(config, workers, s, repeats, cache_dir):
    """Rows of the scaling runs and of the 1-spp overhead runs of one configuration."""
    scene = common.scene_file(s["scene"])
    defines = common.resolution(*s["res"])
    with (distributed.dask_client(workers=workers, verbose=False) if workers
          else contextlib.nullcontext()) as client:
        scheduler = client.scheduler.address if client is not None else None
        # warm-up: every worker compiles the kernels (4 chunks per worker)
        render_reference(scene, defines, spp=8 * max(workers, 1), chunk=1, cache_dir=cache_dir,
                         progress=False, force=True, scheduler=scheduler)
        load_before = common.load_average()
        runs = timed_references(scene, defines, s["spp"], s["chunk"], repeats, cache_dir,
                                scheduler)
        over = timed_references(scene, defines, s["overhead_spp"], 1, repeats, cache_dir,
                                scheduler)
        for r in over:   # each render_reference call connects a client: a cost per call
            r["connect_s"] = _connect_seconds(scheduler)
        load_after = common.load_average()
    base = {"config": config, "workers": workers, "load_before": load_before,
            "load_after": load_after}
    return ([{**base, "kind": "scaling", **r} for r in runs],
            [{**base, "kind": "overhead", **r} for r in over])


def _connect_seconds(scheduler) -> float:
    """Seconds to connect a client and register the worker plugin (0 locally)."""
    if scheduler is None:
        return 0.0
    t0 = time.perf_counter()
    with distributed.dask_client(scheduler=scheduler, verbose=False):
        pass
    return time.perf_counter() - t0


def summarize(rows):
    out = []
    local = {k: statistics.median(r["wall_s"] for r in rows
                                  if r["config"] == "local" and r["kind"] == k)
             for k in ("scaling", "overhead")}
    for config in dict.fromkeys(r["config"] for r in rows):
        pick = {k: [r for r in rows if r["config"] == config and r["kind"] == k]
                for k in ("scaling", "overhead")}
        wall = statistics.median(r["wall_s"] for r in pick["scaling"])
        over = statistics.median(r["wall_s"] for r in pick["overhead"])
        connect = statistics.median(r["connect_s"] for r in pick["overhead"])
        n_over = pick["overhead"][0]["chunks"]
        # wall time not covered by the workers' render time, per chunk
        outside = statistics.median(
            (r["wall_s"] - r["chunk_render_s"] / r["workers_used"]) / r["chunks"]
            for r in pick["overhead"])
        out.append({"config": config, "workers": pick["scaling"][0]["workers"],
                    "chunks": pick["scaling"][0]["chunks"], "wall_s": wall,
                    "wall_min_s": min(r["wall_s"] for r in pick["scaling"]),
                    "speedup_vs_local": local["scaling"] / wall,
                    "overhead_wall_s": over,
                    "connect_s": connect,
                    "overhead_per_chunk_s": (over - connect - local["overhead"]) / n_over,
                    "outside_render_per_chunk_s": outside,
                    "load_before": pick["scaling"][0]["load_before"],
                    "load_after": pick["scaling"][0]["load_after"]})
    return out


def report(summary, s, repeats) -> str:
    w, h = s["res"]
    n = len(chunk_plan(s["spp"], s["chunk"]))
    head = (f"volpath reference of {s['scene']} at {w}x{h}, {s['spp']} spp in {n} chunks of "
            f"{s['chunk']} spp; wall time of render_reference, median of {repeats}; "
            f"cost per chunk from {s['overhead_spp']} chunks of 1 spp against this process, "
            "less the client's connection (once per call); 'not rendering': (wall - the "
            "chunks' render seconds / workers) / chunks of those 1-spp runs")
    rows = [[r["config"], common.fmt(r["wall_s"]), common.fmt(r["speedup_vs_local"]),
             ("-" if r["config"] == "local" else f"{1e3 * r['overhead_per_chunk_s']:.0f} ms"),
             ("-" if r["config"] == "local" else f"{r['connect_s']:.2f} s"),
             f"{1e3 * r['outside_render_per_chunk_s']:.0f} ms",
             f"{r['load_before'][0]:.1f} / {r['load_after'][0]:.1f}"] for r in summary]
    return head + "\n\n" + common.markdown_table(
        ["configuration", "wall time (s)", "speed-up vs this process",
         "Dask cost per chunk", "connect once per call", "not rendering, per chunk", "load (1 min) before / after"], rows)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="tiny sizes (seconds)")
    p.add_argument("--repeats", type=int, default=None, help="runs per configuration (3)")
    p.add_argument("--out", default=None)
    p.add_argument("--resummarize", action="store_true",
                   help="rewrite scaling.csv and table.md from the runs in scaling.json")
    args = p.parse_args(argv)
    s = settings_for(args.quick)
    repeats = args.repeats or (1 if args.quick else 3)
    out = common.output_dir(NAME, args.out, args.quick)
    if args.resummarize:
        return _resummarize(out)
    rows = []
    with tempfile.TemporaryDirectory() as cache_dir:
        for config, workers in [("local", 0)] + [(f"{k} worker(s)", k) for k in s["workers"]]:
            scaling, overhead = measure(config, workers, s, repeats, cache_dir)
            rows += scaling + overhead
            print(f"{config}: {statistics.median(r['wall_s'] for r in scaling):.2f} s "
                  f"(load {common.load_average()})", flush=True)
    summary = summarize(rows)
    text = report(summary, s, repeats)
    print(text)
    settings = {"name": NAME, **s, "repeats": repeats, "quick": args.quick,
                "command": "python3 -m experiments.distributed_scaling " + " ".join(argv or sys.argv[1:]),
                "workers_setup": "local Dask cluster on 127.0.0.1, one task per worker at a time, "
                                 "Dr.Jit threads = cpu_count / workers; warmed up before timing"}
    common.write_csv(out / "runs.csv", rows)
    common.write_csv(out / "scaling.csv", summary)
    common.write_json(out / "scaling.json", settings, rows, summary=summary)
    common.write_text(out / "table.md", text)


def _resummarize(out):
    import json

    with open(out / "scaling.json") as f:
        doc = json.load(f)
    summary = summarize(doc["rows"])
    text = report(summary, doc["settings"], doc["settings"]["repeats"])
    print(text)
    doc["summary"] = summary
    with open(out / "scaling.json", "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    common.write_csv(out / "scaling.csv", summary)
    common.write_text(out / "table.md", text)


if __name__ == "__main__":
    main()
