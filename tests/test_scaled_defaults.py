"""The length-valued defaults (step-length bounds, the initial guess's step, swing
clearances, the co-design's clearance scale and margin, terrain sigma) scale with the
robot's leg length (the lower step-length bound and the guess also with the speed, at the
same Froude number); RABBIT's are today's constants bit for bit; explicit values win."""
from __future__ import annotations

import json

import pytest

from analysis.design import ROBUST_GAIT, RobustDesignSettings
from analysis.design.codesign import CodesignSettings
from analysis.terrain.spec import SIGMA, MonteCarloSettings
from biped_casadi import BipedModel, robot
import numpy as np

from gait_opt import (REFERENCE_LEG_LENGTH, REFERENCE_SPEED, GaitOptions, LegScaled,
                      default_step_length_bounds, gait_fields, guess_step_length, leg_scale,
                      optimize_gait, reference_speed)
from gait_opt.options import CLEARANCE, GUESS_STEP_LENGTH, STEP_LENGTH_BOUNDS
from gait_opt.transcription import guess_step


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
    # at the same Froude number (speed x sqrt(2)) the doubled robot's bounds are twice
    v2 = REFERENCE_SPEED * np.sqrt(2.0)
    base, o = GaitOptions().for_model(model), GaitOptions(speed=v2).for_model(doubled)
    assert o.step_length_bounds == pytest.approx(tuple(2 * v for v in base.step_length_bounds),
                                                 rel=1e-15)
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
    assert o.clearance == 0.02 and o.step_length_bounds == default_step_length_bounds(
        doubled, o.speed)
    # explicit bounds stay as given at any speed, the guess inside them
    slow = GaitOptions(speed=0.2, step_length_bounds=(0.3, 0.5))
    assert slow.for_model(doubled).step_length_bounds == (0.3, 0.5)
    assert 0.3 < guess_step(doubled, slow)[0] < 0.5
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
    assert gait3.options.step_length_bounds == default_step_length_bounds(
        model3, gait3.options.speed)
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


@pytest.mark.parametrize("speed", [REFERENCE_SPEED, 0.9, 1.2, 2.0])
def test_rabbit_bounds_and_guess_are_the_constants_from_its_default_speed(model, speed):
    assert reference_speed(model) == REFERENCE_SPEED == 0.75
    assert GaitOptions(speed=speed).for_model(model).step_length_bounds == (0.2, 0.8)
    # the guess's formula before the scaling, bit for bit
    assert guess_step_length(model, speed) == 0.45 * np.sqrt(speed / 0.75)
    assert GUESS_STEP_LENGTH == 0.45


def test_lower_bound_follows_the_speed_below_the_reference(model, model3, doubled):
    for m in (model, model3, doubled):
        lo_ref, hi_ref = LegScaled(step_length_bounds=STEP_LENGTH_BOUNDS).for_model(m)[
            "step_length_bounds"]
        for v in (0.1, 0.3, 0.5):
            lo, hi = GaitOptions(speed=v).for_model(m).step_length_bounds
            assert hi == hi_ref
            assert lo == pytest.approx(lo_ref * min(1.0, v / reference_speed(m)), rel=1e-15)
            assert lo <= lo_ref
    # the same Froude number, the same bounds and guess relative to the leg
    f = reference_speed(doubled) / reference_speed(model)
    assert f == pytest.approx(np.sqrt(2.0), rel=1e-15)
    for v in (0.3, 0.5, 1.0):
        a = np.array(GaitOptions(speed=v).for_model(model).step_length_bounds)
        b = np.array(GaitOptions(speed=v * f).for_model(doubled).step_length_bounds)
        np.testing.assert_allclose(b, 2 * a, rtol=1e-14)
        assert guess_step_length(doubled, v * f) == pytest.approx(
            2 * guess_step_length(model, v), rel=1e-14)


def test_slow_three_link_gait_is_not_held_by_the_leg_bound(model3):
    """At 0.3 m/s the three-link biped's optimal step is shorter than 0.25 leg: the
    default bound no longer holds it there (the fixed 0.25 leg bound did, at a higher
    cost); the built-in guess it started from is recorded."""
    leg = model3.description.leg_length
    g = optimize_gait(model3, GaitOptions(speed=0.3))
    lo, hi = g.options.step_length_bounds
    assert lo < g.step_length < 0.25 * leg
    assert g.step_length - lo > 0.01 * leg            # inside, not on the bound
    held = optimize_gait(model3, GaitOptions(speed=0.3, step_length_bounds=(0.25 * leg, leg)))
    assert held.step_length == pytest.approx(0.25 * leg, abs=1e-6)
    assert g.cost < held.cost
    L0, T0 = guess_step(model3, g.options)
    assert g.solver_stats["initial_guess"] == dict(step_length=L0, T=T0)
    assert L0 == pytest.approx(guess_step_length(model3, 0.3), rel=1e-15)


def test_codesign_lengths_scale_and_rabbit_keeps_the_constants(model, model3, doubled):
    """The co-design's clearance margin of a moved gait and its mid-step clearance row's
    unit: RABBIT's constants exactly, other robots' scaled with the leg, given values
    kept; the settings record the margin used."""
    from analysis.design.codesign.functions import CLEARANCE_SCALE, TranscriptionSettings
    from analysis.design.codesign.settings import CLEARANCE_MARGIN, MoveSettings
    assert (CLEARANCE_MARGIN, CLEARANCE_SCALE) == (0.002, 0.05)
    assert MoveSettings().clearance_margin is None
    assert MoveSettings().for_model(model).clearance_margin == 0.002
    assert TranscriptionSettings().for_model(model).clearance_scale == 0.05
    for m in (model3, doubled):
        k = leg_scale(m)
        assert MoveSettings().for_model(m).clearance_margin == CLEARANCE_MARGIN * k
        assert TranscriptionSettings().for_model(m).clearance_scale == CLEARANCE_SCALE * k
        assert MoveSettings(clearance_margin=0.001).for_model(m).clearance_margin == 0.001
        assert TranscriptionSettings(clearance_scale=0.04).for_model(m).clearance_scale == 0.04
    # recorded: the filled settings write the number used (RABBIT: the old 0.002)
    assert CodesignSettings().for_model(model).to_dict()["move"]["clearance_margin"] == 0.002
    assert CodesignSettings().for_model(doubled).to_dict()["move"]["clearance_margin"] == \
        2 * CLEARANCE_MARGIN
    given = CodesignSettings(move=MoveSettings(clearance_margin=0.003))
    assert given.for_model(doubled).move.clearance_margin == 0.003


def test_codesign_margins_follow_the_robot(model, model3, doubled):
    """The co-design's strike-front margin, mid-step clearance and lift-off row scale:
    RABBIT's old constants exactly, twice on RABBIT with every length doubled, the leg
    scale on the three-link biped; the torque limit the robot's own; given values kept."""
    import dataclasses
    from analysis.design.codesign.functions import (CLEARANCE_MID, LIFT_SCALE,
                                                    STRIKE_FRONT_MIN, TranscriptionSettings)
    lengths = ("strike_front_min", "clearance_mid", "lift_scale", "clearance_scale")
    blank = TranscriptionSettings()
    assert all(getattr(blank, n) is None for n in lengths + ("torque_limit",))
    r = blank.for_model(model)
    assert (r.strike_front_min, r.clearance_mid, r.lift_scale, r.torque_limit) == \
        (STRIKE_FRONT_MIN, CLEARANCE_MID, LIFT_SCALE, model.description.torque_limit)
    assert (STRIKE_FRONT_MIN, CLEARANCE_MID, LIFT_SCALE) == (0.02, 0.001, 0.3)
    assert model.description.torque_limit == 150.0
    d = blank.for_model(doubled)
    for n in lengths:
        assert getattr(d, n) == 2 * getattr(r, n), n
    k = leg_scale(model3)
    t = blank.for_model(model3)
    for n in lengths:
        assert getattr(t, n) == pytest.approx(k * getattr(r, n), rel=1e-15), n
    # the fields that are neither lengths nor other physical margins stay as they are
    # (the speeds, impulse and torque margin: tests/test_codesign_scales.py)
    physical = ("liftoff_min", "strike_speed_min", "impulse_min", "torque_margin")
    others = [f.name for f in dataclasses.fields(TranscriptionSettings)
              if f.name not in lengths + physical + ("torque_limit",)]
    assert all(getattr(d, n) == getattr(r, n) for n in others)
    # the robot's own torque limit, unless one is given
    weak = BipedModel(dataclasses.replace(model.description, torque_limit=40.0))
    assert blank.for_model(weak).torque_limit == 40.0
    assert TranscriptionSettings(torque_limit=90.0).for_model(weak).torque_limit == 90.0
    given = TranscriptionSettings(strike_front_min=0.01, clearance_mid=0.0, lift_scale=0.5)
    g = given.for_model(doubled)
    assert (g.strike_front_min, g.clearance_mid, g.lift_scale) == (0.01, 0.0, 0.5)
    assert g.clearance_scale == d.clearance_scale
    # filled settings are filled: a second call changes nothing
    assert d.for_model(model) == d


def test_codesign_records_the_clearance_it_used(model, doubled):
    """The co-design's settings, filled for the robot, record the robust gait's clearance
    as used (doubled robot: twice ROBUST_GAIT's), RABBIT's exactly ROBUST_GAIT; a plain
    dict stays as given."""
    assert json.dumps(CodesignSettings().for_model(model).to_dict()["gait"]) == \
        json.dumps(ROBUST_GAIT)
    rec = CodesignSettings().for_model(doubled).to_dict()["gait"]
    assert rec == gait_fields(CodesignSettings().gait, doubled)
    assert rec["clearance"] == 2 * ROBUST_GAIT["clearance"]
    plain = CodesignSettings(gait=dict(ROBUST_GAIT)).for_model(doubled)
    assert plain.to_dict()["gait"] == ROBUST_GAIT
    # filling twice is filling once
    once = CodesignSettings().for_model(doubled)
    assert once.for_model(doubled).to_dict() == once.to_dict()
