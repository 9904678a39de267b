"""The user-style held-out scenes (experiments.user_scenes): every
archetype loads, is lit, and the same seed gives the same scene."""
import mitsuba as mi
import numpy as np
import pytest

from experiments.user_scenes import ARCHETYPES, user_scene


@pytest.mark.parametrize("seed", list(range(len(ARCHETYPES))) + [6, 15, 17])
def test_every_archetype_loads_and_is_lit(seed):
    """... and coloured media (seeds 2, 6, 15, 17: σt an RGB value times a scale)."""
    spec = user_scene(seed).at_resolution(16, 12)
    assert (spec.archetype == ARCHETYPES[seed % len(ARCHETYPES)]
            and spec.name.startswith(f"user {seed} ("))
    img = np.asarray(mi.render(spec.load(), integrator=mi.load_dict(
        {"type": "raymarch", "visibility": "exact", "steps": 32}), spp=1))
    assert img.shape == (12, 16, 3) and np.isfinite(img).all() and img.max() > 0


def test_a_seed_is_one_scene():
    a, b = user_scene(11), user_scene(11)
    assert a.scene_dict().keys() == b.scene_dict().keys()
    assert a.medium == b.medium and a.light == b.light and a.camera == b.camera
    assert user_scene(12).medium != a.medium
