"""Reading integrator properties with one error message per mistake: the
property's name and the values allowed in the first line, and unknown or
misspelled names refused with the closest valid one (DESIGN §4).
"""
from __future__ import annotations

import difflib
import math


def read_choice(props, name, default, choices):
    value = props.get(name, default)
    if value not in choices:
        raise ValueError(f"Property '{name}' = '{value}' is not one of {list(choices)}.")
    return value


def read_number(props, name, default, minimum=None, maximum=None, integer=False):
    value = props.get(name, default)
    if isinstance(value, str):      # <string name=... value="32"/>, a dict's "32"
        try:
            value = float(value)
        except ValueError:
            raise ValueError(f"Property '{name}' = {value!r} must be a finite number "
                             f"(e.g. <float name=\"{name}\" value=\"{default}\"/>).") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"Property '{name}' = {value!r} must be a finite number.")
    if integer and int(value) != value:
        raise ValueError(f"Property '{name}' = {value} must be an integer.")
    if minimum is not None and value < minimum:
        raise ValueError(f"Property '{name}' = {value} must be >= {minimum}.")
    if maximum is not None and value > maximum:
        raise ValueError(f"Property '{name}' = {value} must be <= {maximum}.")
    return int(value) if integer else float(value)


#: the strings read_bool accepts (compared in lower case)
BOOL_STRINGS = {"true": True, "yes": True, "on": True, "1": True,
                "false": False, "no": False, "off": False, "0": False}


def read_bool(props, name: str, default: bool) -> bool:
    """A boolean property: Mitsuba's ``<boolean>``, or one of
    :data:`BOOL_STRINGS` (a ``<string>`` property, ``-p name=no``); anything
    else is a ``ValueError`` (``bool("false")`` would be True)."""
    value = props.get(name, default)
    if isinstance(value, str) and value.strip().lower() in BOOL_STRINGS:
        return BOOL_STRINGS[value.strip().lower()]
    if not isinstance(value, bool):
        raise ValueError(f"Property '{name}' = {value!r} must be a boolean "
                         f"(<boolean name=\"{name}\" value=\"true\"/>, or one of "
                         f"{sorted(BOOL_STRINGS)}).")
    return value


def check_unknown_properties(props, plugin: str, names=(), renamed=None) -> None:
    """A ``ValueError`` naming every property of ``props`` that the plugin
    never read (a misspelled ``slice_spacng`` would otherwise render the
    defaults silently) and, for each, the closest of ``names`` (what the
    plugin reads) and the properties it did read; a name in ``renamed``
    (old name -> new name) says what it is called now."""
    unknown = sorted(props.unqueried())
    if not unknown:
        return
    known = sorted(set(names) | {k for k in props.keys() if k not in unknown})
    parts = []
    renamed = renamed or {}
    for name in unknown:
        if name in renamed:
            parts.append(f"'{name}' (now called '{renamed[name]}')")
            continue
        close = difflib.get_close_matches(name, known + list(COMMON_PROPERTIES), n=1)
        parts.append(f"'{name}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
    raise ValueError(
        f"Unknown {plugin} propert{'ies' if len(unknown) > 1 else 'y'} {', '.join(parts)}: "
        f"remove it or correct its name (the {plugin} docstring lists its properties).")


#: properties every integrator reads (the template's)
COMMON_PROPERTIES = ("output", "samples_per_pixel", "jitter_pixels", "quality", "error_budget",
                     "report_launches")
