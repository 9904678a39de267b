"""The files a Mitsuba scene file loads, found the way Mitsuba finds them.

A reference is only valid for the exact content of the scene (DESIGN §2):
the XML text *and every file it loads*.  :func:`scene_files` walks the XML
as Mitsuba 3's parser does and lists those files:

- ``<default name value>`` defines ``$name`` unless the caller (``-D``)
  already did; ``$name`` is substituted in every attribute, longest names
  first, with the parameters known at that element;
- ``<include filename>`` is resolved with the file resolver and walked with
  the same parameters (it is itself a dependency);
- ``<path value>`` prepends a folder to the resolver (relative: first to the
  XML file's folder, then through the resolver);
- ``<string name="filename" value>`` (meshes ``obj``/``ply``/``serialized``,
  ``bitmap`` textures, ``envmap``, volume grids, measured data, ...) and
  ``<spectrum filename>`` are the loaded files; plugins resolve them at
  instantiation, i.e. with every ``<path>`` of the scene prepended.

The resolver starts as Mitsuba's ``load_file`` makes it: the scene file's
folder, then the thread's resolver (``mi.file_resolver()``; by default the
working directory and Mitsuba's folder).  A relative name that no folder
holds resolves to itself (relative to the working directory), as in Mitsuba.

:func:`dependency_digest` turns the list into text for a cache key: role,
name as written and SHA-256 of the content (``missing`` for a file that
does not exist, so creating it changes the key too).
"""
from __future__ import annotations

import hashlib
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

#: Mitsuba's ``<include>`` recursion limit
MAX_INCLUDE_DEPTH = 15
_CHUNK = 1 << 20


@dataclass(frozen=True)
class SceneFile:
    """One file a scene loads: ``role`` (``include``, ``filename`` or
    ``spectrum``), ``name`` as written (after ``$`` substitution) and the
    resolved absolute ``path``."""
    role: str
    name: str
    path: str


def default_search_paths() -> list[str]:
    """The folders of Mitsuba's thread file resolver (``mi.file_resolver()``)."""
    import mitsuba as mi

    resolver = mi.file_resolver() if hasattr(mi, "file_resolver") else \
        mi.Thread.thread().file_resolver()
    return [str(p) for p in resolver]


def resolve(name: str, search_paths) -> str:
    """Mitsuba's ``FileResolver.resolve``: an absolute name is itself; a
    relative one is the first ``folder/name`` that exists, else ``name``
    relative to the working directory."""
    if os.path.isabs(name):
        return os.path.normpath(name)
    for folder in search_paths:
        candidate = os.path.join(folder, name)
        if os.path.exists(candidate):
            return os.path.normpath(os.path.abspath(candidate))
    return os.path.normpath(os.path.abspath(name))


def substitute(value: str, params: dict) -> str:
    """Replace ``$name`` by its value, longest parameter names first (as
    Mitsuba does, so ``$res_x`` is not read as ``$res`` + ``_x``)."""
    if "$" not in value:
        return value
    for name in sorted(params, key=len, reverse=True):
        value = value.replace("$" + name, str(params[name]))
    return value


def scene_files(scene_path, defines=None, search_paths=None) -> list[SceneFile]:
    """Every file the scene file loads (includes, meshes, textures, spectra),
    in order of appearance, each once; see the module docstring for the rules.

    ``defines`` are the ``-D`` parameters; ``search_paths`` replaces
    Mitsuba's thread resolver (default :func:`default_search_paths`).
    """
    scene_path = os.path.abspath(os.fspath(scene_path))
    folders = [os.path.dirname(scene_path)] + list(
        default_search_paths() if search_paths is None else search_paths)
    params = {str(k): str(v) for k, v in (defines or {}).items()}
    found: list[tuple[str, str]] = []   # (role, name); resolved at the end
    includes: list[SceneFile] = []
    _walk_file(scene_path, params, folders, found, includes, depth=0)
    out, seen = [], set()
    for entry in includes + [SceneFile(role, name, resolve(name, folders))
                             for role, name in found]:
        if entry.path not in seen:
            seen.add(entry.path)
            out.append(entry)
    return out


def _walk_file(path, params, folders, found, includes, depth) -> None:
    if depth > MAX_INCLUDE_DEPTH:
        raise ValueError(f"Scene file '{path}': <include> nested more than "
                         f"{MAX_INCLUDE_DEPTH} deep (Mitsuba's limit); remove the include cycle.")
    root = ET.parse(path).getroot()
    _walk_node(root, os.path.dirname(path), params, folders, found, includes, depth)


def _walk_node(node, xml_dir, params, folders, found, includes, depth) -> None:
    attrs = {k: substitute(v, params) for k, v in node.attrib.items()}
    tag = node.tag
    if tag == "default":
        params.setdefault(attrs.get("name", ""), attrs.get("value", ""))
        return
    if tag == "path":
        value = attrs.get("value", "")
        folder = value if os.path.isabs(value) else os.path.join(xml_dir, value)
        if not os.path.exists(folder):
            folder = resolve(value, folders)
        folders.insert(0, os.path.abspath(folder))
        return
    if tag == "include":
        name = attrs.get("filename", "")
        path = resolve(name, folders)
        includes.append(SceneFile("include", name, path))
        if os.path.isfile(path):
            _walk_file(path, params, folders, found, includes, depth + 1)
        return
    if tag == "string" and attrs.get("name") == "filename" and "value" in attrs:
        found.append(("filename", attrs["value"]))
    elif tag == "spectrum" and "filename" in attrs:
        found.append(("spectrum", attrs["filename"]))
    for child in node:
        _walk_node(child, xml_dir, params, folders, found, includes, depth)


def file_sha256(path) -> str | None:
    """SHA-256 of a file's bytes, or None if it does not exist."""
    if not os.path.isfile(path):
        return None
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def dependency_digest(files) -> str:
    """Text naming each file (role, name as written) and its content hash,
    one line per file; empty for a scene that loads no file."""
    return "\n".join(f"{f.role}:{f.name}:{file_sha256(f.path) or 'missing'}" for f in files)
