"""Loading scene files and building integrators from command-line strings.

Shared by every CLI command and experiment: ``load_scene`` reads an ordinary
Mitsuba XML file with ``-D name=value`` defaults (building the suite's
generated meshes first when the file belongs to ``scenes/``), and
``make_integrator`` turns ``-i TYPE -p key=value`` into a Mitsuba integrator.
"""
from __future__ import annotations

import hashlib
import os

import integrators  # noqa: F401  (registers our plugins, checks LLVM)
import mitsuba as mi


def unwrap_render_error(err: BaseException) -> BaseException:
    """The error a user should see: ``mi.render`` runs the integrator inside
    a Dr.Jit custom operation, so a ``ValueError`` raised in ``render()``
    (e.g. an unsupported scene) arrives as the ``__cause__`` of a
    ``RuntimeError`` ('error while performing a custom differentiable
    operation').  Follows that chain to the first non-RuntimeError."""
    while isinstance(err, RuntimeError) and isinstance(err.__cause__, Exception):
        err = err.__cause__
    # Mitsuba's parser wraps an error raised while a plugin is built into a
    # RuntimeError ("failed to instantiate ... Traceback ..."): its last line
    # is the error itself
    lines = str(err).strip().splitlines()
    if isinstance(err, RuntimeError) and len(lines) > 1 and "Traceback" in str(err):
        kind, _, message = lines[-1].partition(": ")
        if kind in ("ValueError", "TypeError") and message:
            return ValueError(message)
    return err


def parse_value(text: str):
    """'true'/'false' -> bool, integers -> int, floats -> float, else str."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_assignments(items) -> dict:
    """['a=1', 'b=x'] -> {'a': 1, 'b': 'x'}; a clear error for a missing '='."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise ValueError(f"'{item}' is not of the form name=value.")
        key, value = item.split("=", 1)
        out[key.strip()] = parse_value(value)
    return out


def prepare_scene_file(path: str) -> str:
    """The absolute path of an existing scene file, after building the
    suite's generated meshes and textures when the file belongs to ``scenes/``."""
    path = os.path.abspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"Scene file '{path}' does not exist.")
    scenes_dir = os.path.join(os.path.dirname(os.path.dirname(__file__)), "scenes")
    if os.path.dirname(path) == os.path.abspath(scenes_dir):
        import scenes
        scenes.ensure_assets()
    return path


def load_scene(path: str, defines: dict | None = None, optimize: bool = True):
    """mi.load_file with XML defaults; suite assets are built on first use.
    ``optimize=False`` keeps every shape apart (Mitsuba otherwise merges
    meshes with identical BSDFs, and a moving shape must stay its own)."""
    path = prepare_scene_file(path)
    defines = {k: str(v) for k, v in (defines or {}).items()}
    return mi.load_file(path, optimize=optimize, **defines)


def make_integrator(kind: str | None, props: dict | None = None, scene=None):
    """Integrator ``kind`` with properties, or the scene's own if kind is None."""
    if kind is None:
        if props:
            raise ValueError("-p/--param needs -i/--integrator to say which integrator.")
        if scene is None:
            raise ValueError("No integrator type given and no scene to take it from.")
        if scene.integrator() is None:
            raise ValueError("The scene has no <integrator>: pass one with -i TYPE "
                             "(raymarch, epipolar_tree, fourier_filter, volpath) or add "
                             "<integrator type=\"...\"/> to the scene file.")
        return scene.integrator()
    d = {"type": kind}
    d.update(props or {})
    if kind == "volpath" and "max_depth" not in d:
        d["max_depth"] = 2
    return mi.load_dict(d)


def check_volpath_medium(scene) -> None:
    """Refuse what makes Mitsuba's ``volpath`` return NaN instead of an image:
    a sensor medium whose σt is zero in some channels but not all (volpath
    samples free-flight distances per channel and divides by σt).  Scenes our
    integrators do not read (no medium on the sensor, ...) are not checked."""
    from integrators.core.scene_params import SceneParams

    try:
        sigma_t = SceneParams.from_scene(scene).medium.sigma_t
    except ValueError:
        return
    if (sigma_t == 0).any() and (sigma_t > 0).any():
        raise ValueError(f"Medium sigma_t = {list(map(float, sigma_t))} is zero in some "
                         "channels: Mitsuba's volpath returns NaN for such media. Give every "
                         "channel sigma_t > 0 (e.g. 1e-4), or use the exact working reference "
                         "(raymarch visibility=exact: `--reference exact`, `--kind exact`).")


def scene_key(path: str, defines: dict | None = None, extra: str = "") -> str:
    """Hash of the scene file's bytes, the defines and ``extra``.  The
    reference cache adds the content of every file the scene loads through
    ``extra`` (:func:`episcatter.reference.reference_key`)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        h.update(f.read())
    for k in sorted((defines or {}).items()):
        h.update(repr(k).encode())
    h.update(extra.encode())
    return h.hexdigest()[:16]
