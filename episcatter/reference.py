"""Ground-truth and working-reference images, cached on disk (DESIGN §2).

Two kinds of reference are rendered from the *same* scene file:

``volpath``
    Mitsuba's ``volpath`` with ``max_depth=2``: the unbiased ground truth.
    The scene's own integrator is used when it already is ``volpath`` with
    ``max_depth=2``; otherwise a fresh ``volpath`` (``max_depth=2``) is built.
    The sidecar says which (``integrator_source``).
``exact``
    ``raymarch`` with ``visibility="exact"``, many ``steps`` and
    :data:`EXACT_BISECTIONS` boundary bisections
    (:func:`integrators.core.marching.march_bisected`): deterministic along each
    camera ray, the working reference once it agrees with volpath.  Its
    samples per pixel only antialias (jittered box filter).

Either is rendered in chunks of ``chunk`` samples per pixel with distinct
seeds (0, 1, 2, ...).  Even chunks accumulate into ``half_a``, odd chunks into
``half_b``: two statistically independent images with equal sample counts, so
:func:`episcatter.metrics.noise_relmse` estimates the noise of their mean (the
reference itself) without a second render.

Files: ``<stem>-<kind>-<key>-spp<N>.exr`` (layers ``full``, ``half_a``,
``half_b``) plus ``.json`` sidecar with the same stem, in :func:`default_cache_dir`.
``key`` hashes the scene file's bytes, the ``-D`` defines, the kind's
settings and the bytes of every file the scene loads (meshes, textures,
included XML; :mod:`episcatter.scene_files`): editing a mesh misses the
cache; the resolution is fixed by those two, and is recorded (and checked)
in the sidecar.  The chunk size is not part of the key (it does not change
what the image converges to).
"""
from __future__ import annotations

import datetime
import functools
import json
import math
import os
import platform
import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from . import metrics
from .chunk_store import ChunkStore
from .distributed import map_runs, uses_dask, worker_name
from .imageio import read_exr, write_exr
from .scene_files import dependency_digest, scene_files
from .scene_loading import (load_scene, make_integrator, prepare_scene_file, scene_key,
                            unwrap_render_error)

KINDS = ("volpath", "exact")
DEFAULT_SPP = {"volpath": 4096, "exact": 16}
DEFAULT_CHUNK = {"volpath": 64, "exact": 4}
DEFAULT_EXACT_STEPS = 2048
#: boundary bisections of the ``exact`` kind (raymarch ``boundary_bisections``):
#: the plain midpoint rule rounds a thin shaft's lit length to whole segments
#: (2048 steps: relMSE 2.0e-4 against 8192 on beam at 320×240, 5.5e-6 on the
#: grove); bisected, 2048 steps agree with 4096 (16 bisections) to 3e-10 on
#: beam (results/reference_convergence/).  Part of the cache key.
EXACT_BISECTIONS = 12
NOISE_BLOCKS = (1, 4, 8)
VOLPATH_CLASS = "VolumetricPathIntegrator"


# --------------------------------------------------------------------------
# Paths and cache
# --------------------------------------------------------------------------

def default_cache_dir() -> str:
    """``$EPISCATTER_CACHE`` if set, else ``~/.cache/episcatter/references``."""
    env = os.environ.get("EPISCATTER_CACHE")
    if env:
        return os.path.abspath(os.path.expanduser(env))
    return os.path.join(os.path.expanduser("~"), ".cache", "episcatter", "references")


#: settings that mark a version of the reference in its cache key but are
#: no property of the integrator (the behaviour is always on)
KEY_ONLY = ("crack_confirmation",)


def _kind_settings(kind: str, steps: int | None) -> dict:
    """The settings of a reference kind that change the image (part of the key)."""
    if kind == "volpath":
        return {"integrator": "volpath", "max_depth": 2}
    if kind == "exact":
        return {"integrator": "raymarch", "visibility": "exact",
                "steps": int(steps or DEFAULT_EXACT_STEPS),
                "boundary_bisections": EXACT_BISECTIONS,
                # lit rises confirmed by a shifted shadow ray (mesh cracks,
                # core.light_transport.visible_confirmed): references cached before differ
                "crack_confirmation": 1}
    raise ValueError(f"Reference kind '{kind}' is not one of {list(KINDS)}.")


def reference_key(scene_path, defines=None, kind="volpath", steps=None) -> str:
    """Cache key: hash of the scene file, the defines, the kind's settings
    and the content of every file the scene loads (meshes, textures,
    included XML: :func:`episcatter.scene_files.scene_files`).  A scene that
    loads no file keeps the key of the XML, defines and settings alone."""
    scene_path = prepare_scene_file(scene_path)
    defines = _str_defines(defines)
    extra = json.dumps(_kind_settings(kind, steps), sort_keys=True)
    files = dependency_digest(scene_files(scene_path, defines))
    if files:
        extra += "\nfiles:\n" + files
    return scene_key(scene_path, defines, extra=extra)


def reference_path(scene_path, defines=None, spp=None, kind="volpath", steps=None,
                   cache_dir=None) -> str:
    """Path of the cached EXR of this reference (whether or not it exists)."""
    spp = int(spp or DEFAULT_SPP[kind])
    stem = os.path.splitext(os.path.basename(scene_path))[0]
    key = reference_key(scene_path, defines, kind, steps)
    return os.path.join(cache_dir or default_cache_dir(), f"{stem}-{kind}-{key}-spp{spp}.exr")


#: references shipped with the repository (small; see references/README.md)
SHIPPED_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                           "references")


def find_cached_reference(scene_path, defines=None, kind="volpath", steps=None,
                          cache_dir=None) -> str | None:
    """The cached reference EXR of this scene file + defines with the most
    samples per pixel (any spp), looked up in ``cache_dir`` (default: the
    user cache) and in the repository's shipped ``references/``; None if
    there is none."""
    stem = os.path.splitext(os.path.basename(scene_path))[0]
    prefix = f"{stem}-{kind}-{reference_key(scene_path, defines, kind, steps)}-spp"
    best, best_spp = None, -1
    for folder in (cache_dir or default_cache_dir(), SHIPPED_DIR):
        if not os.path.isdir(folder):
            continue
        for name in os.listdir(folder):
            if not (name.startswith(prefix) and name.endswith(".exr")):
                continue
            spp_text = name[len(prefix):-len(".exr")]
            path = os.path.join(folder, name)
            if spp_text.isdigit() and int(spp_text) > best_spp and \
                    os.path.isfile(sidecar_path(path)):
                best, best_spp = path, int(spp_text)
    return best


def sidecar_path(exr_path) -> str:
    """The JSON sidecar next to a reference EXR."""
    return os.path.splitext(os.fspath(exr_path))[0] + ".json"


def load_reference(path) -> tuple[np.ndarray, dict]:
    """(full RGB image (H, W, 3) float32, sidecar dict) of a reference EXR.

    The sidecar holds the halves' layer names; they are read with
    :func:`load_halves`.  A missing sidecar gives an empty info dict.
    """
    layers = read_exr(path)
    info = {}
    side = sidecar_path(path)
    if os.path.isfile(side):
        with open(side) as f:
            info = json.load(f)
        info["path"] = os.path.abspath(os.fspath(path))
    return np.ascontiguousarray(layers["full"][..., :3]), info


def load_halves(path) -> tuple[np.ndarray, np.ndarray]:
    """The two independent half images stored in a reference EXR."""
    layers = read_exr(path)
    return layers["half_a"], layers["half_b"]


def _str_defines(defines) -> dict:
    return {str(k): str(v) for k, v in (defines or {}).items()}


# --------------------------------------------------------------------------
# Rendering helpers (also used by episcatter.bench)
# --------------------------------------------------------------------------

def render_rgb(scene, integrator, spp: int = 0, seed: int = 0) -> np.ndarray:
    """``mi.render`` to a finished (H, W, 3) float32 NumPy image.

    Waits for the kernels (``dr.eval`` + ``dr.sync_thread``) and re-raises an
    integrator's ``ValueError`` itself instead of Dr.Jit's wrapper.
    """
    import drjit as dr
    import mitsuba as mi

    try:
        img = mi.render(scene, integrator=integrator, spp=int(spp), seed=int(seed))
        dr.eval(img)
        dr.sync_thread()
    except RuntimeError as exc:
        cause = unwrap_render_error(exc)
        if cause is exc:
            raise
        raise cause from None
    arr = np.array(img, dtype=np.float32)
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=-1)
    return np.ascontiguousarray(arr[..., :3])


def _is_volpath_depth2(integrator) -> bool:
    """Whether a Mitsuba integrator is volpath with max_depth = 2."""
    if integrator is None or integrator.class_name() != VOLPATH_CLASS:
        return False
    text = str(integrator).replace(" ", "")
    return "max_depth=2," in text or "max_depth=2\n" in text


def exact_description(steps: int | None = None) -> str:
    """What the ``exact`` kind renders, e.g. 'raymarch visibility=exact
    steps=2048 boundary_bisections=12'."""
    return (f"raymarch visibility=exact steps={int(steps or DEFAULT_EXACT_STEPS)} "
            f"boundary_bisections={EXACT_BISECTIONS}")


def exact_props(steps: int | None = None) -> dict:
    """The ``raymarch`` properties of the ``exact`` kind (what a script that
    renders the working reference itself should pass)."""
    settings = _kind_settings("exact", steps)
    return {k: v for k, v in settings.items() if k not in ("integrator",) + KEY_ONLY}


def reference_integrator(scene, kind: str, steps: int | None = None):
    """(integrator, source, description) for a reference of ``kind``."""
    settings = _kind_settings(kind, steps)
    if kind == "volpath":
        own = scene.integrator()
        if _is_volpath_depth2(own):
            return own, "scene", "the scene's own volpath (max_depth=2)"
        integ = make_integrator("volpath", {"max_depth": 2})
        return integ, "fresh", "a fresh volpath (max_depth=2); the scene's integrator was " \
            f"{own.class_name() if own is not None else 'none'}"
    props = exact_props(steps)
    integ = make_integrator("raymarch", props)
    return integ, "fresh", exact_description(props["steps"])


def chunk_plan(spp: int, chunk: int) -> list[int]:
    """Samples per pixel of each chunk: an even number of chunks of at most
    ``chunk`` spp, half of the samples in the even chunks and half in the odd
    ones, so the two halves have equal sample counts."""
    spp, chunk = int(spp), int(chunk)
    if spp < 2 or spp % 2:
        raise ValueError(f"spp = {spp} must be even and >= 2: the reference is two "
                         "independent halves of spp/2 samples each.")
    if chunk < 1:
        raise ValueError(f"chunk = {chunk} must be >= 1.")
    per_half = math.ceil((spp // 2) / chunk)
    half_spp = spp // 2
    sizes = [half_spp // per_half + (1 if i < half_spp % per_half else 0)
             for i in range(per_half)]
    return [s for s in sizes for _ in range(2)]


def environment() -> dict:
    """Versions, platform, CPU count and the date (UTC), for sidecars and benchmarks."""
    import drjit as dr
    import mitsuba as mi

    return {"mitsuba": mi.__version__, "drjit": dr.__version__, "variant": mi.variant(),
            "numpy": np.__version__, "python": platform.python_version(),
            "platform": platform.platform(), "cpu_count": os.cpu_count(),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def noise_levels(half_a, half_b, eps: float = metrics.DEFAULT_EPS,
                 blocks=NOISE_BLOCKS) -> dict:
    """relMSE noise of the mean of two halves at several block sizes."""
    out = {"eps": float(eps)}
    h, w = np.shape(half_a)[:2]
    for k in blocks:
        if k <= min(h, w):
            out[f"block_{k}"] = metrics.noise_relmse(half_a, half_b, block=k, eps=eps)
    return out


def chunk_noise_levels(mean, variance, eps: float = metrics.DEFAULT_EPS,
                       blocks=NOISE_BLOCKS) -> dict:
    """relMSE noise from the per-chunk variance layer at several block sizes."""
    out = {"eps": float(eps)}
    if not np.all(np.isfinite(variance)):
        return out
    h, w = np.shape(mean)[:2]
    for k in blocks:
        if k <= min(h, w):
            out[f"block_{k}"] = metrics.noise_relmse_from_variance(mean, variance, k, eps)
    return out


def load_variance(path) -> np.ndarray | None:
    """The per-pixel variance-of-the-mean layer of a reference EXR, if stored."""
    return read_exr(path).get("variance")


# --------------------------------------------------------------------------
# The reference itself
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class ChunkJob:
    """Everything a process (this one or a Dask worker) needs to render
    chunks of one reference: plain values, picklable.  ``key`` is the
    reference key the client computed; a process whose scene files give
    another key refuses to render (different or edited files)."""
    scene_path: str
    defines: tuple
    kind: str
    steps: int | None
    key: str


@lru_cache(maxsize=1)
def _chunk_scene(job: ChunkJob, variant: str):
    """(scene, integrator, source, description) of a job, loaded once per
    process and variant (a worker renders many chunks of one reference)."""
    key = reference_key(job.scene_path, dict(job.defines), job.kind, job.steps)
    if key != job.key:
        raise ValueError(
            f"The scene files of '{job.scene_path}' seen by {worker_name()} give the cache "
            f"key {key}, the client's give {job.key}: the files differ between the machines "
            "(or were edited during the render). Make the same files visible to every "
            "worker at the same path, then run again.")
    scene = load_scene(job.scene_path, dict(job.defines))
    return (scene, *reference_integrator(scene, job.kind, job.steps))


def render_chunk(job: ChunkJob, item) -> dict:
    """Render one chunk ``item = (seed, spp)`` of a reference.

    Returns ``{'seed', 'spp', 'image'`` (float32 (H, W, 3), as rendered)
    ``, 'seconds', 'worker', 'integrator', 'integrator_source'}``.  The same
    function runs locally and on Dask workers, so both give the same bits.
    """
    import mitsuba as mi

    seed, spp = int(item[0]), int(item[1])
    scene, integrator, source, description = _chunk_scene(job, mi.variant())
    t0 = time.perf_counter()
    image = render_rgb(scene, integrator, spp=spp, seed=seed)
    return {"seed": seed, "spp": spp, "image": image, "seconds": time.perf_counter() - t0,
            "worker": worker_name(), "integrator": description, "integrator_source": source}


def merge_chunks(images, sizes):
    """(half_a, half_b, variance) of chunk images given in chunk order.

    Even chunks (seeds 0, 2, ...) average into ``half_a``, odd ones into
    ``half_b``, each weighted by its samples per pixel; ``variance`` is the
    per-pixel variance of the mean from the K chunk means (K - 1 degrees of
    freedom; NaN for one chunk).  Sums run in chunk order, so a reference
    merges to the same bits whichever order its chunks finished in.
    """
    halves = [None, None]
    weights = [0, 0]
    sum_sq = 0.0
    for seed, (image, n) in enumerate(zip(images, sizes)):
        img = np.asarray(image).astype(np.float64)
        side = seed % 2
        halves[side] = img * n if halves[side] is None else halves[side] + img * n
        weights[side] += n
        sum_sq = sum_sq + img * img
    half_a, half_b = halves[0] / weights[0], halves[1] / weights[1]
    # chunks hold (nearly) equal sample counts
    K = len(sizes)
    mean = 0.5 * (half_a + half_b)
    variance = np.maximum(sum_sq / K - mean * mean, 0.0) / max(K - 1, 1) if K > 1 else \
        np.full_like(mean, np.nan)
    return half_a, half_b, variance


def chunk_folder(path) -> str:
    """Folder of the stored chunks of the reference EXR ``path``."""
    return os.path.splitext(os.fspath(path))[0] + ".chunks"


def _render_chunks(job, plan, store, scheduler, workers, progress, on_chunk):
    """Render the chunks of ``plan`` missing from ``store``, storing each as
    it completes; returns {seed: meta} of every chunk and the seeds rendered now."""
    metas = {seed: meta for seed, (_, meta) in store.stored(plan).items()}
    missing = [item for item in plan if item[0] not in metas]
    for meta in metas.values():
        meta["run"] = "earlier"

    def keep(_, result):
        meta = {k: v for k, v in result.items() if k != "image"}
        store.save(result["seed"], result["spp"], result["image"], meta)
        metas[result["seed"]] = dict(meta, run="this")
        if on_chunk is not None:
            on_chunk(len(metas), len(plan))

    desc = f"{job.kind} reference {os.path.basename(job.scene_path)}"
    if metas:
        desc += f" ({len(metas)} chunks stored)"
    try:
        map_runs(functools.partial(render_chunk, job), missing, scheduler=scheduler,
                 workers=workers, progress=progress, desc=desc, unit="chunk",
                 on_result=keep, collect=False)
    finally:
        if not uses_dask(scheduler, workers):
            _chunk_scene.cache_clear()   # free the scene of a local render
    return metas, [seed for seed, _ in missing]


def _write_atomic(path, layers, info) -> None:
    """EXR then sidecar, each written to a temporary name and renamed, so a
    concurrent reader never sees a partial file."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.{os.getpid()}.tmp.exr"
    write_exr(tmp, layers, metadata={"episcatter_reference": json.dumps(info, sort_keys=True)})
    os.replace(tmp, path)
    side = sidecar_path(path)
    tmp_side = f"{side}.{os.getpid()}.tmp"
    with open(tmp_side, "w") as f:
        json.dump(info, f, indent=2, sort_keys=True)
        f.write("\n")
    os.replace(tmp_side, side)


def _cached(path, spp, kind):
    """The cached (rgb, info) at ``path`` if complete and consistent, else None."""
    if not (os.path.isfile(path) and os.path.isfile(sidecar_path(path))):
        return None
    rgb, info = load_reference(path)
    if info.get("spp") != spp or info.get("kind") != kind:
        return None
    res = info.get("resolution")
    if res and list(rgb.shape[1::-1]) != list(res):
        return None
    return rgb, info


def render_reference(scene_path, defines=None, spp=None, chunk=None, cache_dir=None,
                     progress=True, force=False, kind="volpath", steps=None,
                     eps=metrics.DEFAULT_EPS, scheduler=None, workers=None,
                     on_chunk=None, keep_chunks=False) -> tuple[np.ndarray, dict]:
    """Render (or load from the cache) a reference image of a scene file.

    Parameters
    ----------
    scene_path, defines:
        Scene XML and its ``-D`` defaults (``{'res_x': 64, ...}``).
    spp, chunk:
        Total samples per pixel (even) and samples per chunk.  Defaults:
        volpath 4096 / 64, exact 16 / 4.
    cache_dir:
        Where the EXR + JSON go (default :func:`default_cache_dir`).
    progress:
        tqdm bar over the chunks.
    force:
        Re-render even if the cache holds this reference.
    kind, steps:
        ``volpath`` (ground truth) or ``exact`` (``raymarch
        visibility=exact steps=steps boundary_bisections=12``, default
        2048 steps: :func:`exact_props`).
    eps:
        Regularizer of the relMSE noise estimate.
    scheduler, workers:
        Render the chunks as Dask tasks on the cluster at ``scheduler``, or
        on a local cluster of ``workers`` processes
        (:func:`episcatter.distributed.map_runs`); neither: in this process.
        The result is the same bit for bit.
    on_chunk:
        ``on_chunk(done, total)`` after each chunk is stored.
    keep_chunks:
        Keep the stored chunks after the reference is written (default:
        removed; they are only needed to resume an interrupted render).

    Every finished chunk is stored at once (:mod:`episcatter.chunk_store`,
    folder :func:`chunk_folder`), so an interrupted render resumes: the next
    call renders only the missing chunks.  Chunks merge in chunk order
    (:func:`merge_chunks`).  ``force`` also discards stored chunks.

    Returns ``(rgb, info)``: the (H, W, 3) float32 image (mean of the two
    halves) and the sidecar dict (see module docstring and
    ``info['path']``; ``info['chunks']`` lists each chunk's seed, spp,
    seconds, worker and whether it was rendered in this run or an earlier,
    interrupted one).  A cache hit only reads the files.
    """
    if kind not in KINDS:
        raise ValueError(f"Reference kind '{kind}' is not one of {list(KINDS)}.")
    spp = int(spp or DEFAULT_SPP[kind])
    chunk = int(chunk or DEFAULT_CHUNK[kind])
    sizes = chunk_plan(spp, chunk)
    scene_path = os.path.abspath(scene_path)
    defines = _str_defines(defines)
    path = reference_path(scene_path, defines, spp, kind, steps, cache_dir)
    if not force:
        hit = _cached(path, spp, kind)
        if hit is not None:
            hit[1]["cached"] = True
            return hit

    t0 = time.perf_counter()
    key = reference_key(scene_path, defines, kind, steps)
    job = ChunkJob(scene_path, tuple(sorted(defines.items())), kind, steps, key)
    plan = list(enumerate(sizes))
    store = ChunkStore(chunk_folder(path))
    if force:
        store.clear()
    # The exact marcher in 1-spp chunks samples every pixel centre with no
    # random number: every chunk is the same image, so it is rendered once.
    deterministic = kind == "exact" and all(n == 1 for n in sizes)
    todo = plan[:1] if deterministic else plan
    metas, rendered = _render_chunks(job, todo, store, scheduler, workers, progress, on_chunk)
    if deterministic:
        metas = {seed: dict(metas[0], seconds=0.0, run="copy of seed 0 (deterministic)")
                 if seed else metas[0] for seed, _ in plan}
    images = [store.load(seed, n)[0] for seed, n in todo]
    if deterministic:
        images = images * len(plan)      # every chunk is chunk 0's image
    half_a, half_b, variance = merge_chunks(images, sizes)
    wall = time.perf_counter() - t0
    full = 0.5 * (half_a + half_b)
    chunks = [{"seed": seed, "spp": n, "seconds": metas[seed]["seconds"],
               "worker": metas[seed]["worker"], "run": metas[seed]["run"]} for seed, n in plan]
    info = {
        "kind": kind,
        "settings": _kind_settings(kind, steps),
        "integrator": metas[0]["integrator"],
        "integrator_source": metas[0]["integrator_source"],
        "spp": spp,
        "chunk": chunk,
        "chunk_spp": sizes,
        "seeds": [seed for seed, _ in plan],
        "chunks": chunks,
        "chunks_rendered": len(rendered),
        "chunks_resumed": len(todo) - len(rendered),
        "halves": {"half_a": "even chunks (seeds 0, 2, ...)",
                   "half_b": "odd chunks (seeds 1, 3, ...)",
                   "spp_each": spp // 2},
        "wall_time_s": wall,
        "chunk_time_s": [c["seconds"] for c in chunks],
        "distributed": {"scheduler": scheduler, "workers": workers},
        "resolution": [int(full.shape[1]), int(full.shape[0])],
        "scene": scene_path,
        "defines": defines,
        "scene_key": key,
        "relmse_noise": noise_levels(half_a, half_b, eps),
        "relmse_noise_chunks": chunk_noise_levels(full, variance, eps),
        "variance": "layer 'variance': per-pixel variance of the mean from the "
                    f"{len(sizes)} chunk means ({len(sizes) - 1} degrees of freedom)",
        "path": path,
        **environment(),
    }
    _write_atomic(path, {"full": full, "half_a": half_a, "half_b": half_b,
                         "variance": variance}, info)
    if not keep_chunks:
        store.clear()
    info["cached"] = False
    return full.astype(np.float32), info
