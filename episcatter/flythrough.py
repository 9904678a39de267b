"""A fly-through: what an animation pays per frame (kernel recompiles).

An animation changes its scene in place between frames, the way any
Mitsuba program does: ``params = mi.traverse(scene)``, new values for the
sensor's ``to_world``, the emitter's ``to_world`` / ``position`` or the
medium's ``sigma_t``, then ``params.update()``.  If a value of the frame
enters a JIT kernel as a literal instead of an opaque parameter, every new
frame compiles that kernel again; :func:`fly_through` measures it.

Frame schedule (:func:`frame_change`): frame 0 is the scene as loaded (the
first render), then the changes cycle through :data:`CHANGES` -- the camera
moves by :attr:`Motion.camera_step` along its own x axis on frames 1 and 2,
the light moves on frame 3 (a point light by :attr:`Motion.light_step`
along world x, a directional or spot light turns by
:attr:`Motion.light_degrees` about its own x axis), σt is scaled by
:attr:`Motion.sigma_factor` on frame 4, all three change on frame 5, and so
on.  Each change gets a tiny random extra (:attr:`Motion.jitter`, seeded by
:attr:`Motion.seed`) so that a second run of the benchmark does not find a
frame's kernels in Dr.Jit's disk cache from the first run: a real animation's
cameras are new, too.

Per frame (:func:`measure_frame`): ``wall_s`` of the first render of the
frame (``mi.render(scene, integrator=..., spp=1)``, ``dr.eval`` +
``dr.sync_thread``), the JIT kernels it launched, compiled (not in memory
or on disk), took from the disk cache, and their compile time
(:mod:`episcatter.kernels`), then ``warm_s``: the median of
``warm_repeats`` more renders of the same frame.  ``compile_share =
compile_s / wall_s``, ``ratio = wall_s / warm_s``.  The parameter update
itself is timed apart (``update_s``).

:func:`format_frames` prints the per-frame table (``episcatter bench
--frames``); ``python -m experiments.frame_to_frame`` runs it on the suite.
"""
from __future__ import annotations

import math
import random
import statistics
import time
from dataclasses import asdict, dataclass

import drjit as dr
import mitsuba as mi

from .kernels import kernel_log

#: what changes on frames 1, 2, ... (cycled); frame 0 is "first"
CHANGES = ("camera", "camera", "light", "medium", "all")
#: per-frame columns of :func:`fly_through`'s rows, in order
FRAME_COLUMNS = ("frame", "change", "wall_s", "warm_s", "ratio", "compile_s", "compile_share",
                 "launched", "compiled", "from_disk", "warm_compiled", "update_s",
                 "update_launched", "update_compiled", "warm_repeats", "warm_times_s")


@dataclass(frozen=True)
class Motion:
    """How far each change moves the scene (meters, degrees, a factor)."""
    camera_step: float = 0.05
    light_step: float = 0.05
    light_degrees: float = 1.5
    sigma_factor: float = 1.03
    #: relative size of the random extra added to each step (0: none)
    jitter: float = 0.02
    #: seed of the extras (None: drawn from the clock; see ``Motion.fresh``)
    seed: int | None = None

    def fresh(self) -> "Motion":
        """This motion with a seed (drawn now when it has none)."""
        if self.seed is not None:
            return self
        return Motion(**{**asdict(self), "seed": random.SystemRandom().randrange(1 << 31)})


def frame_change(k: int) -> str:
    """What frame ``k`` changes: ``first`` for 0, else :data:`CHANGES` cycled."""
    return "first" if k == 0 else CHANGES[(k - 1) % len(CHANGES)]


@dataclass(frozen=True)
class AnimatedKeys:
    """The ``mi.traverse`` keys a fly-through writes (None: not present)."""
    camera: str
    light: str | None
    light_kind: str | None      # "position" or "to_world"
    sigma_t: str | None


def animated_keys(scene, params=None) -> AnimatedKeys:
    """The sensor's ``to_world``, the emitter's ``position`` (point light)
    or ``to_world`` (directional, spot) and the sensor medium's ``sigma_t``
    keys of ``scene`` (a ValueError if the camera has none)."""
    params = mi.traverse(scene) if params is None else params
    keys = set(params.keys())
    sensor = scene.sensors()[0]
    camera = f"{sensor.id()}.to_world"
    if camera not in keys:
        raise ValueError(f"the sensor has no '{camera}' parameter to move")
    light = kind = None
    emitters = [e for e in scene.emitters() if e.id()]
    if emitters:
        eid = emitters[0].id()
        for kind in ("position", "to_world"):
            if f"{eid}.{kind}" in keys:
                light = f"{eid}.{kind}"
                break
        else:
            kind = None
    medium = sensor.get_medium() if hasattr(sensor, "get_medium") else None
    sigma = None
    prefixes = [f"{medium.id()}." if medium is not None and medium.id() else ""]
    for key in sorted(keys, key=len):
        if any(key.startswith(p) for p in prefixes) and (
                key.endswith(".sigma_t") or ".sigma_t." in key):
            sigma = key
            break
    return AnimatedKeys(camera, light, kind, sigma)


def apply_change(params, keys: AnimatedKeys, change: str, motion: Motion, rng) -> dict:
    """Write frame change ``change`` into ``params`` (not yet updated);
    returns what moved, for the record."""
    def step(x):
        return x * (1.0 + motion.jitter * rng.random())

    done = {}
    if change in ("camera", "all"):
        dx = step(motion.camera_step)
        params[keys.camera] = params[keys.camera] @ mi.Transform4f().translate([dx, 0.0, 0.0])
        done["camera_dx"] = dx
    if change in ("light", "all") and keys.light is not None:
        if keys.light_kind == "position":
            dx = step(motion.light_step)
            params[keys.light] = params[keys.light] + mi.Point3f(dx, 0.0, 0.0)
            done["light_dx"] = dx
        else:
            deg = step(motion.light_degrees)
            params[keys.light] = params[keys.light] @ mi.Transform4f().rotate([1.0, 0.0, 0.0], deg)
            done["light_deg"] = deg
    if change in ("medium", "all") and keys.sigma_t is not None:
        f = 1.0 + (motion.sigma_factor - 1.0) * (1.0 + motion.jitter * rng.random())
        params[keys.sigma_t] = params[keys.sigma_t] * f
        done["sigma_factor"] = f
    return done


def render_once(scene, integrator, spp: int = 1, seed: int = 0) -> tuple[object, float]:
    """(image, wall seconds) of one finished ``mi.render``."""
    t0 = time.perf_counter()
    img = mi.render(scene, integrator=integrator, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return img, time.perf_counter() - t0


def measure_frame(scene, integrator, warm_repeats: int = 3, spp: int = 1) -> dict:
    """The first render of the current frame (time and kernels) and the
    median of ``warm_repeats`` more renders of it."""
    with kernel_log() as log:
        _, wall = render_once(scene, integrator, spp)
    warm = []
    with kernel_log() as wlog:
        for _ in range(max(int(warm_repeats), 0)):
            warm.append(render_once(scene, integrator, spp)[1])
    warm_s = statistics.median(warm) if warm else math.nan
    compile_s = log.compile_seconds
    return {"wall_s": wall, "warm_s": warm_s,
            "ratio": wall / warm_s if warm and warm_s > 0 else math.nan,
            "compile_s": compile_s, "compile_share": compile_s / wall if wall > 0 else math.nan,
            "launched": log.launched, "compiled": log.compiled,
            "from_disk": log.compiled_from_disk, "warm_compiled": wlog.compiled,
            "warm_repeats": len(warm), "warm_times_s": [round(t, 6) for t in warm]}


def fly_through(scene, integrator, frames: int = 6, warm_repeats: int = 3, spp: int = 1,
                motion: Motion | None = None, on_frame=None) -> list[dict]:
    """Render ``frames`` frames of a fly-through of ``scene`` (changed in
    place) with ``integrator``; one dict per frame (:data:`FRAME_COLUMNS`
    plus what moved).  ``on_frame(row)`` is called after each frame."""
    if int(frames) < 1:
        raise ValueError(f"frames = {frames} must be >= 1")
    motion = (motion or Motion()).fresh()
    rng = random.Random(motion.seed)
    params = mi.traverse(scene)
    keys = animated_keys(scene, params)
    rows = []
    for k in range(int(frames)):
        change = frame_change(k)
        moved, update = {}, {"update_s": 0.0, "update_launched": 0, "update_compiled": 0}
        if k > 0:
            with kernel_log() as ulog:
                t0 = time.perf_counter()
                moved = apply_change(params, keys, change, motion, rng)
                params.update()
                dr.sync_thread()
                seconds = time.perf_counter() - t0
            update = {"update_s": seconds, "update_launched": ulog.launched,
                      "update_compiled": ulog.compiled}
        row = {"frame": k, "change": change,
               **measure_frame(scene, integrator, warm_repeats, spp), **update, **moved}
        rows.append({c: row[c] for c in FRAME_COLUMNS if c in row}
                    | {c: v for c, v in row.items() if c not in FRAME_COLUMNS})
        if on_frame is not None:
            on_frame(rows[-1])
    return rows


def summarize_frames(rows: list[dict]) -> dict:
    """One fly-through's summary: the first render, the new frames (1..)
    and the warm renders."""
    first = rows[0]
    new = rows[1:]

    def stat(fn, key, among):
        vals = [r[key] for r in among if isinstance(r.get(key), (int, float))
                and math.isfinite(r[key])]
        return fn(vals) if vals else math.nan

    return {
        "first_s": first["wall_s"], "first_compile_s": first["compile_s"],
        "first_compiled": first["compiled"], "first_from_disk": first["from_disk"],
        "first_launched": first["launched"],
        "new_frames": len(new),
        "new_mean_s": stat(statistics.mean, "wall_s", new),
        "new_max_s": stat(max, "wall_s", new),
        "warm_s": stat(statistics.median, "warm_s", rows),
        "max_ratio": stat(max, "ratio", new),
        "max_compile_share": stat(max, "compile_share", new),
        "new_compile_mean_s": stat(statistics.mean, "compile_s", new),
        "launched_mean": stat(statistics.mean, "launched", rows),
        "launched_min": stat(min, "launched", rows), "launched_max": stat(max, "launched", rows),
        "compiled_mean": stat(statistics.mean, "compiled", new),
        "compiled_max": stat(max, "compiled", new),
        "from_disk_new": stat(sum, "from_disk", new),
        "warm_compiled_max": stat(max, "warm_compiled", rows),
    }


def _num(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}g}"


def format_frames(rows: list[dict], title: str = "") -> str:
    """The per-frame table of one fly-through (markdown)."""
    header = ["frame", "change", "wall s", "warm s", "ratio", "compile s", "compile share",
              "launched", "compiled", "from disk", "warm compiled"]
    lines = ([f"### {title}", ""] if title else []) + [
        "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        cells = [r["frame"], r["change"], _num(r["wall_s"]), _num(r["warm_s"]), _num(r["ratio"]),
                 _num(r["compile_s"]), f"{100 * r['compile_share']:.0f} %"
                 if math.isfinite(r["compile_share"]) else "-",
                 r["launched"], r["compiled"], r["from_disk"], r["warm_compiled"]]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)


__all__ = ["CHANGES", "FRAME_COLUMNS", "Motion", "AnimatedKeys", "frame_change",
           "animated_keys", "apply_change", "render_once", "measure_frame", "fly_through",
           "summarize_frames", "format_frames"]
