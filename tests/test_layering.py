"""The import layers of DESIGN §6, checked on the source (no imports run):
``rectify/`` is a leaf (it imports nothing from ``integrators``), no plugin
module imports another plugin module (nor does any shared stage import a
plugin, which would register it), and no private ``_name`` is imported
across modules."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("integrators", "rectify", "episcatter", "experiments")
#: the plugin modules: class + docstring + registration
#: the plugin modules: every module of integrators/ that registers one
PLUGINS = tuple(sorted(
    "integrators." + ".".join(p.relative_to(ROOT / "integrators").with_suffix("").parts)
    for p in (ROOT / "integrators").rglob("*.py")
    if "mi.register_integrator(" in p.read_text(encoding="utf-8")))


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path):
    """(imported module, imported names) of every import statement in ``path``."""
    return imports_in(path.read_text(), module_name(path), path.name == "__init__.py")


def imports_in(source: str, module: str, is_package: bool = False):
    """(imported module, imported names) of every import statement of
    ``source`` (module ``module``), relative imports resolved."""
    tree = ast.parse(source)
    package = module.split(".")
    if not is_package:
        package = package[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            names = tuple(a.name for a in node.names)
            yield mod, names
            for name in names:   # `from . import x` imports the module x
                yield f"{mod}.{name}", ()


def library_files():
    for top in LIBRARY:
        yield from sorted((ROOT / top).rglob("*.py"))


def test_library_files_are_found():
    names = {module_name(p) for p in library_files()}
    assert set(PLUGINS) <= names and "rectify.slices" in names
    assert {"integrators.raymarch", "integrators.epipolar_tree", "integrators.fourier_filter",
            "integrators.minmax_epipolar"} <= set(PLUGINS)


@pytest.mark.parametrize("path", sorted((ROOT / "rectify").rglob("*.py")),
                         ids=lambda p: p.name)
def test_rectify_is_a_leaf(path):
    bad = [m for m, _ in imports_of(path) if m == "integrators" or m.startswith("integrators.")
           or m == "episcatter" or m.startswith("episcatter.")]
    assert not bad, f"{module_name(path)} imports {bad}: rectify/ must not import up the layers"


@pytest.mark.parametrize("path", list(library_files()), ids=module_name)
def test_no_plugin_imports_a_plugin(path):
    """Only the registry (``integrators/__init__``) and code above the
    integrators (episcatter, experiments) may name a plugin module."""
    me = module_name(path)
    if me == "integrators" or not me.startswith("integrators"):
        return
    bad = [m for m, _ in imports_of(path) if m in PLUGINS and m != me]
    assert not bad, f"{me} imports plugin module(s) {bad}; move the shared code to a stage module"


@pytest.mark.parametrize("path", list(library_files()), ids=module_name)
def test_no_private_name_crosses_modules(path):
    bad = [(m, n) for m, names in imports_of(path) for n in names
           if n.startswith("_") and not n.startswith("__")
           and (m.split(".")[0] in LIBRARY)]
    assert not bad, f"{module_name(path)} imports private names {bad}: make them public"


def test_checker_resolves_relative_and_private_imports():
    """The checks above would see a module that breaks the rules."""
    src = "from integrators.template.base import _x\nfrom . import slices\nfrom ..integrators import a\n"
    found = list(imports_in(src, "rectify.probe"))
    assert ("integrators.template.base", ("_x",)) in found
    assert ("rectify.slices", ()) in found
    assert ("integrators", ("a",)) in found


#: the sub-packages of ``integrators`` in layer order (DESIGN §6): a module
#: imports only from its own package or from a lower layer; the plugins
#: (the modules directly in ``integrators/``) sit above them all
PACKAGE_LAYERS = {"core": 0, "epipolar": 1, "partial": 2, "tree": 3, "fourier": 3, "minmax": 3,
                  "template": 4}
PLUGIN_LAYER = 5


def layer_of(module: str) -> tuple[str, int] | None:
    """(package, layer) of an ``integrators`` module, None for the registry."""
    parts = module.split(".")
    if parts[0] != "integrators" or len(parts) == 1:
        return None
    if parts[1] in PACKAGE_LAYERS:
        return parts[1], PACKAGE_LAYERS[parts[1]]
    return parts[1], PLUGIN_LAYER


def test_every_integrators_package_has_a_layer():
    packages = {p.name for p in (ROOT / "integrators").iterdir()
                if p.is_dir() and (p / "__init__.py").exists()}
    assert packages == set(PACKAGE_LAYERS), "give each integrators/ package a layer"


@pytest.mark.parametrize("path", sorted((ROOT / "integrators").rglob("*.py")), ids=module_name)
def test_imports_go_down_the_layers(path):
    me = layer_of(module_name(path))
    if me is None:
        return
    bad = []
    for m, _ in imports_of(path):
        other = layer_of(m)
        if other is None or other[0] == me[0]:
            continue
        if other[1] >= me[1]:
            bad.append(m)
    assert not bad, (f"{module_name(path)} (layer {me[1]}) imports {sorted(set(bad))}: "
                     "imports go only down the layers (tests/test_layering.py PACKAGE_LAYERS)")
