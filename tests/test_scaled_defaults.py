"""The length-valued defaults (step-length bounds, swing clearances, terrain sigma) scale
with the robot's leg length; RABBIT's are today's constants bit for bit; explicit values
win."""
from __future__ import annotations

import json

import pytest

from analysis.design import ROBUST_GAIT, RobustDesignSettings
from analysis.design.codesign import CodesignSettings
from analysis.terrain.spec import SIGMA, MonteCarloSettings
from biped_casadi import BipedModel, robot
from gait_opt import REFERENCE_LEG_LENGTH, GaitOptions, LegScaled, gait_fields, leg_scale
from gait_opt.options import CLEARANCE, STEP_LENGTH_BOUNDS


@pytest.fixture(scope="module")
def doubled(model):
    """RABBIT with every length twice as long (masses and inertias unchanged)."""
    return BipedModel(model.description.scaled(length=2))


def test_rabbit_defaults_are_the_constants_exactly(model):
    assert model.description.leg_length == REFERENCE_LEG_LENGTH
    assert leg_scale(model) == 1.0
    o = GaitOptions().for_model(model)
    assert o.step_length_bounds == STEP_LENGTH_BOUNDS == (0.2, 0.8)
    assert o.clearance == CLEARANCE == 0.03
    assert gait_fields(CodesignSettings().gait, model) == ROBUST_GAIT
    assert gait_fields(RobustDesignSettings().gait, model) == ROBUST_GAIT
    assert MonteCarloSettings().for_model(model).sigma == SIGMA == 0.005


def test_rabbit_gait_records_the_constants(gait):
    d = gait.options.to_dict()
    assert d["step_length_bounds"] == list(STEP_LENGTH_BOUNDS)
    assert d["clearance"] == CLEARANCE


def test_settings_records_unchanged(model):
    """The co-design settings still record ROBUST_GAIT's numbers (same JSON, same keys)."""
    for st in (CodesignSettings(), RobustDesignSettings()):
        assert json.dumps(st.to_dict()["gait"]) == json.dumps(ROBUST_GAIT)


def test_doubled_robot_gets_doubled_lengths(model, doubled):
    assert doubled.description.leg_length == 2 * model.description.leg_length
    assert leg_scale(doubled) == 2.0
    base, o = GaitOptions().for_model(model), GaitOptions().for_model(doubled)
    assert o.step_length_bounds == tuple(2 * v for v in base.step_length_bounds)
    assert o.clearance == 2 * base.clearance
    assert gait_fields(CodesignSettings().gait, doubled)["clearance"] == \
        2 * ROBUST_GAIT["clearance"]
    other = {k: v for k, v in ROBUST_GAIT.items() if k != "clearance"}
    assert {k: v for k, v in gait_fields(CodesignSettings().gait, doubled).items()
            if k != "clearance"} == other
    assert MonteCarloSettings().for_model(doubled).sigma == \
        2 * MonteCarloSettings().for_model(model).sigma


def test_explicit_values_win(doubled):
    o = GaitOptions(step_length_bounds=(0.3, 0.5), clearance=0.02).for_model(doubled)
    assert (o.step_length_bounds, o.clearance) == ((0.3, 0.5), 0.02)
    # one given, the other scaled
    o = GaitOptions(clearance=0.02).for_model(doubled)
    assert o.clearance == 0.02 and o.step_length_bounds == tuple(
        leg_scale(doubled) * v for v in STEP_LENGTH_BOUNDS)
    # a plain dict of gait fields is taken as given, even with ROBUST_GAIT's numbers
    assert gait_fields(dict(ROBUST_GAIT), doubled) == ROBUST_GAIT
    assert gait_fields(CodesignSettings(gait=dict(ROBUST_GAIT)).gait, doubled) == ROBUST_GAIT
    assert MonteCarloSettings(sigma=0.004).for_model(doubled).sigma == 0.004
    assert MonteCarloSettings(sigma=0.0).for_model(doubled).sigma == 0.0
    # a terrain profile is the terrain: no random heights on top
    assert MonteCarloSettings(profile=(0.01, 0.0)).for_model(doubled).sigma == 0.0


def test_leg_scaled_fields_scale_bounds_too(model, doubled):
    f = LegScaled(step_length_bounds=(0.2, 0.8), speed=0.5).for_model(doubled)
    assert f == dict(step_length_bounds=(0.4, 1.6), speed=0.5)
    assert type(f) is dict
    assert LegScaled(ROBUST_GAIT).for_model(model) == ROBUST_GAIT


def test_three_link_gait_records_its_bounds(model3, gait3):
    """A gait solved with the defaults records the bounds it was solved with."""
    k = leg_scale(model3)
    assert k == model3.description.leg_length / REFERENCE_LEG_LENGTH
    assert gait3.options.step_length_bounds == tuple(k * v for v in STEP_LENGTH_BOUNDS)
    assert gait3.options.clearance == k * CLEARANCE
    lo, hi = gait3.options.step_length_bounds
    assert lo <= gait3.step_length <= hi


def test_unfilled_options_refuse_nothing_and_keep_defaults_open():
    o = GaitOptions()
    assert o.step_length_bounds is None and o.clearance is None
    assert "step_length_bounds" in o.to_dict()
    assert GaitOptions.from_dict(o.to_dict()) == o
    with pytest.raises(ValueError, match="'clearance' must be a non-negative number"):
        GaitOptions(clearance=-0.01)
    with pytest.raises(ValueError, match="sigma must be a finite number"):
        MonteCarloSettings(sigma=-1.0)


def test_three_link_is_not_rabbit_sized(model3):
    """The measurement robots differ from RABBIT (else the tests above say nothing)."""
    assert robot("three_link").description.leg_length != REFERENCE_LEG_LENGTH
