"""A misspelled or unknown integrator property is an error naming the
closest valid one, never a silent render at the defaults."""
import mitsuba as mi
import pytest

CASES = [("raymarch", "visiblity", "exact", "visibility"),
         ("epipolar_tree", "slice_spacng", 2.0, "slice_spacing"),
         ("fourier_filter", "qualty", "auto", "quality"),
         ("minmax_epipolar", "initial_stp", 4, "initial_step")]


@pytest.mark.parametrize("plugin, wrong, value, right", CASES)
def test_a_misspelled_property_names_the_right_one(plugin, wrong, value, right):
    with pytest.raises(Exception) as err:
        mi.load_dict({"type": plugin, wrong: value})
    last = str(err.value).strip().splitlines()[-1]
    assert f"'{wrong}'" in last and f"did you mean '{right}'" in last


def test_a_misspelled_property_in_xml_is_an_error():
    xml = """<scene version="3.0.0"><integrator type="epipolar_tree">
             <float name="slice_spacng" value="2"/></integrator></scene>"""
    with pytest.raises(Exception, match="slice_spacing"):
        mi.load_string(xml)


@pytest.mark.parametrize("plugin", [c[0] for c in CASES])
def test_valid_properties_load(plugin):
    mi.load_dict({"type": plugin, "output": "scattering"})


def _cli_error(capsys, tmp_path, *args):
    """(exit code, stderr lines) of ``episcatter render`` on the tiny scene."""
    from episcatter.cli import main

    rc = main(["render", "tests/data/tiny_scene.xml", "-i", "raymarch", *args,
               "-o", str(tmp_path / "x.exr")])
    return rc, capsys.readouterr().err.strip().splitlines()


def test_the_cli_says_what_is_wrong_in_one_line(capsys, tmp_path):
    """``-p visiblity=exact``: the first line of the error names the property
    and the fix, not Mitsuba's "failed to instantiate" wrapper."""
    rc, err = _cli_error(capsys, tmp_path, "-p", "visiblity=exact")
    assert rc == 2 and len(err) == 1
    assert "Unknown raymarch property 'visiblity' (did you mean 'visibility'?)" in err[0]


def test_the_cli_names_a_bad_value_in_one_line(capsys, tmp_path):
    rc, err = _cli_error(capsys, tmp_path, "-p", "visibility=exakt")
    assert rc == 2 and len(err) == 1
    assert "Property 'visibility' = 'exakt' is not one of" in err[0]


def test_a_sampler_with_no_samples_is_a_clear_error(capsys, tmp_path):
    """``-D spp=0`` (a sampler with sample_count 0) used to fail inside a
    Dr.Jit division ("incompatible sizes")."""
    rc, err = _cli_error(capsys, tmp_path, "-D", "spp=0")
    err = "\n".join(err)
    assert rc == 2 and "sample_count = 0" in err and "at least 1" in err


@pytest.mark.parametrize("plugin", ["epipolar_tree", "minmax_epipolar"])
def test_the_old_name_of_blockers_says_the_new_one(plugin):
    """``rectification`` (traced | resampled) is ``blockers`` in every
    plugin; in ``fourier_filter`` ``rectification`` is the epipolar or
    projective map."""
    with pytest.raises(Exception) as err:
        mi.load_dict({"type": plugin, "rectification": "resampled"})
    assert "'rectification' (now called 'blockers')" in str(err.value)
    assert mi.load_dict({"type": plugin, "blockers": "resampled"}).blockers == "resampled"


def test_fourier_visibility_auto_says_its_new_name():
    with pytest.raises(Exception, match="now called 'exact_directional'"):
        mi.load_dict({"type": "fourier_filter", "visibility": "auto"})
    integ = mi.load_dict({"type": "fourier_filter"})
    assert integ.visibility == "exact_directional" and integ.visibility_used == "exact"
    assert mi.load_dict({"type": "fourier_filter", "coefficients": 32}).visibility_used == "filter"
