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
