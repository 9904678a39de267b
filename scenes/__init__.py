"""The episcatter scene suite: ordinary Mitsuba 3 XML scenes.

Each scene renders unchanged with its own ``volpath`` integrator
(``max_depth=2``) or with an episcatter integrator swapped in.  Conventions
every scene follows (other code relies on them):

- ``-D`` overridable defaults ``res_x`` (320), ``res_y`` (240), ``spp`` (64),
  ``sigma_t`` (per meter), ``albedo`` and, for Henyey-Greenstein media, ``g``;
- one ``perspective`` sensor (id ``camera``) with a box-filtered ``hdrfilm``,
  sitting inside the ``homogeneous`` medium ``medium``;
- that medium is bounded by exactly one axis-aligned null-BSDF ``cube``
  (id ``medium_box``) that encloses the camera, all geometry and the light;
- one emitter (id ``light``): ``directional``, ``point`` or ``spot`` --
  several (ids ``light``, ``light_2``, ...) in ``MULTI_LIGHT_SUITE``
  (:mod:`scenes.several_lights`);
- all other shapes are ``diffuse``: black in the plain scenes (only scattered
  light shows), coloured in the ``<name>_lit`` variants.

``SUITE`` lists the plain scenes, ``LIT_SUITE`` their lit variants,
``STRESS_SUITE`` the scenes of :mod:`scenes.fourier_stress` (also with ``_lit``).  Large
meshes and textures are generated, not committed: :func:`path` builds them on
first use (``python -m scenes.generate`` rewrites everything).
"""
from __future__ import annotations

from .assets import SCENE_DIR, ensure_assets
from .catalog import SCENES
from .fourier_stress import EMITTER_TYPE as STRESS_EMITTER_TYPE
from .fourier_stress import SCENES as STRESS_SCENES
from .several_lights import EMITTER_TYPES as MULTI_LIGHT_EMITTER_TYPES
from .several_lights import SCENES as MULTI_LIGHT_SCENES

#: the plain (black-surface) scenes, in suite order
SUITE: list[str] = list(SCENES)
#: the lit variants, ``<name>_lit``
LIT_SUITE: list[str] = [f"{name}_lit" for name in SUITE]
#: scenes that stress ``fourier_filter`` (issue 12, :mod:`scenes.fourier_stress`)
STRESS_SUITE: list[str] = list(STRESS_SCENES)
#: scenes lit by several lights (:mod:`scenes.several_lights`)
MULTI_LIGHT_SUITE: list[str] = list(MULTI_LIGHT_SCENES)
#: every scene file stem
ALL_SCENES: list[str] = (SUITE + LIT_SUITE + STRESS_SUITE + [f"{n}_lit" for n in STRESS_SUITE]
                         + MULTI_LIGHT_SUITE + [f"{n}_lit" for n in MULTI_LIGHT_SUITE])

#: emitter plugin of each plain scene (the lit variant has the same)
EMITTER_TYPE: dict[str, str] = {
    "nave_offscreen": "directional", "nave_onscreen": "directional",
    "grove": "directional", "terrain": "directional", "spot_room": "spot",
    "point_fog": "point", "beam": "directional", **STRESS_EMITTER_TYPE,
}
#: emitter plugins of every plain scene, in document order
EMITTER_TYPES: dict[str, tuple[str, ...]] = {
    **{name: (kind,) for name, kind in EMITTER_TYPE.items()}, **MULTI_LIGHT_EMITTER_TYPES}


def path(name: str) -> str:
    """Absolute path of ``scenes/<name>.xml``, after building missing assets.

    ``name`` is a scene stem such as ``"grove"`` or ``"grove_lit"``.
    """
    if name not in ALL_SCENES:
        raise ValueError(f"unknown scene {name!r}; choose one of {ALL_SCENES}")
    ensure_assets()
    return str(SCENE_DIR / f"{name}.xml")


__all__ = ["SUITE", "LIT_SUITE", "STRESS_SUITE", "MULTI_LIGHT_SUITE", "ALL_SCENES", "EMITTER_TYPE",
           "EMITTER_TYPES", "SCENE_DIR",
           "ensure_assets", "path"]
