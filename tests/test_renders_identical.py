"""experiments.renders_identical: the check that a refactoring left every
render bit for bit as it was."""
import numpy as np

from experiments import renders_identical as ri


def test_same_renders_compare_identical_and_a_changed_one_does_not(tmp_path):
    for out in ("a", "b"):
        assert ri.save(tmp_path / out, [(8, 6)], ["raymarch"], ["point_fog"]) == 1
    assert ri.compare(tmp_path / "a", tmp_path / "b") == []
    image = tmp_path / "b" / "8x6" / "raymarch" / "point_fog.npy"
    changed = np.load(image)
    changed.flat[0] = np.nextafter(changed.flat[0], np.inf)    # one ulp
    np.save(image, changed)
    assert len(ri.compare(tmp_path / "a", tmp_path / "b")) == 1
    image.unlink()
    assert "missing" in ri.compare(tmp_path / "a", tmp_path / "b")[0]
    assert ri.main(["compare", str(tmp_path / "a"), str(tmp_path / "b")]) == 1
