"""The retime stage's parameters (issue 23): each default in one place — ``RetimeParams`` and its
groups ``ContactParams`` (MPS06 §3.2), ``PolygonParams`` (§3.3-3.4) and ``SplineParams`` (§3.5-3.6)
— which the lower-level functions take as required arguments; a config's old flat keys land in
the groups, unknown keys still fail naming the field."""

from __future__ import annotations

import dataclasses
import inspect

import pytest
from motionweb.tasks.params.retime import FLAT_KEYS, ContactParams, PolygonParams, RetimeParams, SplineParams
from pydantic import ValidationError

GROUPS = {"contacts": ContactParams, "polygons": PolygonParams, "spline": SplineParams}


def required(fn, *names: str) -> dict[str, object]:
    """``fn``'s parameters ``names``, asserting that none has a default; their annotations."""
    sig = inspect.signature(fn, eval_str=True)
    for name in names:
        assert sig.parameters[name].default is inspect.Parameter.empty, f"{fn.__qualname__}({name}=...) has a default"
    return {name: sig.parameters[name].annotation for name in names}


def test_the_lower_level_functions_take_the_groups_with_no_defaults_of_their_own() -> None:
    """Contacts and polygons take the group models themselves (no twin types with defaults); the
    spline and the path timing take the group's values as required arguments."""
    from motionweb.tasks.retime import contacts, objective, path_timing, polygons, spline

    assert not hasattr(contacts, "ContactRule") and not hasattr(polygons, "PolygonOptions")
    assert required(contacts.contacts_for, "rule", "clip")["rule"] is ContactParams
    assert required(contacts.detect_contacts, "rule", "floor")["rule"] is ContactParams
    assert required(contacts.missed_stances, "rule")["rule"] is ContactParams
    for fn in (polygons.original_forces, polygons.feasible_polygons, polygons.sweep_polygon, polygons.FrameLP):
        assert required(fn, "opts")["opts"] is PolygonParams, fn
    required(objective.bake, "alpha", "beta")
    required(spline.optimize_timing, "samples_per_frame", "knots_per_second", "speed_max")
    required(spline.TimingSpline.make, "knots_per_second")
    required(spline.check_keytimes, "speed_max")
    required(path_timing.path_timing, "samples_per_frame")
    box = {f.name: f for f in dataclasses.fields(polygons.FeasiblePolygons)}["box"]
    assert box.default is dataclasses.MISSING and box.default_factory is dataclasses.MISSING


def test_each_default_is_defined_once() -> None:
    """A field lives either at the top of RetimeParams or in one group, and the groups' defaults are
    the group models' own (``default_factory``, no copy of their values)."""
    top = set(RetimeParams.model_fields) - set(GROUPS)
    names = [set(model.model_fields) for model in GROUPS.values()]
    for i, a in enumerate(names):
        assert not a & top
        for b in names[i + 1:]:
            assert not a & b
    for group, model in GROUPS.items():
        assert RetimeParams.model_fields[group].default_factory is model
        assert getattr(RetimeParams(), group) == model()


def test_old_flat_keys_map_into_the_groups() -> None:
    """Every flat key of a config written before the groups names a field of its group (none is
    lost or shadows a top-level field), and a flat config means the nested one."""
    for old, (group, name) in FLAT_KEYS.items():
        assert name in GROUPS[group].model_fields, old
        assert old not in RetimeParams.model_fields, old
    flat = RetimeParams.model_validate({
        "contact_height_on": 0.05, "contact_min_s": 0.06, "contact_gap_s": 0.04, "friction": 0.8,
        "floor_height": 0.0, "floor_heights": {"jump_00": 0.1}, "contact_intervals": {"jump_00": {"l_ankle": [[0, 1]]}},
        "knots_per_second": 10, "objective": "minimize", "lp_solver": "highs", "root_tolerance": 0.05,
        "smoothing_s": 0.1})
    nested = RetimeParams(
        smoothing_s=0.1,
        contacts=ContactParams(height_on=0.05, min_s=0.06, gap_s=0.04, friction=0.8, floor_height=0.0,
                               floor_heights={"jump_00": 0.1}, intervals={"jump_00": {"l_ankle": [(0.0, 1.0)]}}),
        polygons=PolygonParams(lp_solver="highs", root_tolerance=0.05),
        spline=SplineParams(knots_per_second=10.0, objective="minimize"))
    assert flat == nested
    # flat keys join the group's nested keys (a model or a mapping)
    assert RetimeParams(contacts=ContactParams(height_on=0.05), friction=0.8).contacts == ContactParams(
        height_on=0.05, friction=0.8)
    assert RetimeParams.model_validate({"spline": {"beta": 0.2}, "alpha": 2}).spline == SplineParams(alpha=2, beta=0.2)


def test_unknown_and_doubled_keys_fail_naming_the_field() -> None:
    with pytest.raises(ValidationError) as info:
        RetimeParams.model_validate({"contact_heigth_on": 0.05})
    assert [e["loc"] for e in info.value.errors()] == [("contact_heigth_on",)]
    with pytest.raises(ValidationError) as info:
        RetimeParams.model_validate({"contacts": {"heigth_on": 0.05}, "knots_per_second": 10})
    assert [e["loc"] for e in info.value.errors()] == [("contacts", "heigth_on")]
    with pytest.raises(ValidationError, match=r"contact_height_on and contacts\.height_on both given"):
        RetimeParams.model_validate({"contact_height_on": 0.05, "contacts": {"height_on": 0.06}})
    with pytest.raises(ValidationError) as info:
        RetimeParams.model_validate({"contacts": "high", "friction": 0.8})
    assert [e["loc"][0] for e in info.value.errors()] == ["contacts"]


def test_the_flat_default_section_of_before_the_groups_means_the_defaults() -> None:
    """configs/default.yaml's ``retime`` section as it was written before the groups (every flat
    key with its value then) loads as ``RetimeParams()``: no old key is lost or moved wrongly."""
    old = {"body_model": "table", "total_mass": 70.0, "friction": 0.5, "contact_height_on": 0.04,
           "contact_height_off": 0.07, "contact_speed_on": 0.6, "contact_speed_off": 1.2, "contact_min_s": 0.05,
           "contact_gap_s": 0.05, "contact_height_ground": 0.01, "floor_height": None, "floor_heights": {},
           "torque_limits_from": "table", "torque_limits": {}, "torque_margin": 1.5, "repair_glitches": True,
           "smoothing_s": 0.08, "samples_per_frame": 4, "alpha": 1.0, "beta": 0.1, "objective": "match",
           "contact_intervals": {}, "allow_flight_only": False, "speed_max": 6.0, "pdd_max": 40.0,
           "root_tolerance": 0.03, "directions": 8, "max_lps": 16, "lp_solver": "simplex", "knots_per_second": 8.0,
           "timing": "auto"}
    assert RetimeParams.model_validate(old) == RetimeParams()
    assert set(old) == (set(RetimeParams.model_fields) - set(GROUPS)) | set(FLAT_KEYS)
