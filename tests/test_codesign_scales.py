"""The co-design's RABBIT-sized margins that are not lengths follow the robot: the
lift-off and strike speeds with sqrt(g leg), the strike's normal impulse with mass x
sqrt(g leg), the torque margins with the robot's torque limit.  RABBIT's filled settings
are its documented constants bit for bit; other robots' are computed here from their
descriptions; given values are kept; bad values are refused naming the field.  The
sampling search records (and keys) the clearance it used."""
from __future__ import annotations

import dataclasses
import json
import math

import pytest

from analysis.design import ROBUST_GAIT, RobustDesignSettings
from analysis.design.codesign import CodesignSettings
from analysis.design.codesign.functions import (IMPULSE_MIN, LIFTOFF_MIN, STRIKE_SPEED_MIN,
                                                TORQUE_MARGIN, TranscriptionSettings)
from analysis.design.codesign.scales import physical_scales
from analysis.design.codesign.settings import MOVE_TORQUE_MARGIN, MoveSettings
from biped_casadi import BipedModel, find_description
from biped_casadi.caching import argument_key
from gait_opt import leg_scale

PHYSICAL = ("liftoff_min", "strike_speed_min", "impulse_min", "torque_margin")


def _model(description=None, **changes):
    d = description if description is not None else find_description("rabbit")
    return BipedModel(dataclasses.replace(d, **changes) if changes else d)


def _expected(model) -> dict:
    """The filled margins computed here from the robot's and RABBIT's descriptions."""
    d, r = model.description, find_description("rabbit")
    speed = math.sqrt(d.gravity * d.leg_length) / math.sqrt(r.gravity * r.leg_length)
    impulse = d.total_mass * speed / r.total_mass
    limit = d.torque_limit if math.isfinite(d.torque_limit) else r.torque_limit * (
        d.total_mass * d.gravity * d.leg_length) / (r.total_mass * r.gravity * r.leg_length)
    return dict(liftoff_min=LIFTOFF_MIN * speed, strike_speed_min=STRIKE_SPEED_MIN * speed,
                impulse_min=IMPULSE_MIN * impulse, torque_margin=TORQUE_MARGIN * limit /
                r.torque_limit, move_torque_margin=MOVE_TORQUE_MARGIN * limit / r.torque_limit)


def test_rabbit_keeps_its_constants_bit_for_bit(model):
    assert (LIFTOFF_MIN, STRIKE_SPEED_MIN, IMPULSE_MIN, TORQUE_MARGIN, MOVE_TORQUE_MARGIN) == \
        (0.02, 0.02, 0.5, 3.0, 0.5)
    assert model.description.torque_limit == 150.0 and model.description.total_mass == 32.0
    assert physical_scales(model) == dict(length=1.0, speed=1.0, impulse=1.0, torque=1.0)
    blank = TranscriptionSettings()
    assert all(getattr(blank, n) is None for n in PHYSICAL)
    t = blank.for_model(model)
    assert (t.liftoff_min, t.strike_speed_min, t.impulse_min, t.torque_margin) == \
        (0.02, 0.02, 0.5, 3.0)
    # the torque margins as fractions of RABBIT's limit: 3/150 and 0.5/150
    assert t.torque_margin / model.description.torque_limit == 3.0 / 150.0
    assert MoveSettings().torque_margin is None
    assert MoveSettings().for_model(model).torque_margin == 0.5
    # the co-design records the move's margin it used: RABBIT's 0.5, as before
    assert CodesignSettings().for_model(model).to_dict()["move"]["torque_margin"] == 0.5


@pytest.mark.parametrize("make", [
    lambda: _model(find_description("three_link")),
    lambda: _model(find_description("rabbit").scaled(length=2)),
    lambda: _model(find_description("rabbit").scaled(mass=3)),
    lambda: _model(torque_limit=40.0),
    lambda: _model(gravity=3.71),
    lambda: _model(find_description("rabbit").scaled(mass=0.5, length=0.7),
                   torque_limit=math.inf),
], ids=["three_link", "legs x2", "mass x3", "limit 40", "gravity 3.71", "no limit"])
def test_other_robots_margins_follow_their_size(make):
    m = make()
    e = _expected(m)
    t = TranscriptionSettings().for_model(m)
    for n in PHYSICAL:
        assert getattr(t, n) == pytest.approx(e[n], rel=1e-14), n
        assert math.isfinite(getattr(t, n)) and getattr(t, n) > 0, n
    assert MoveSettings().for_model(m).torque_margin == pytest.approx(
        e["move_torque_margin"], rel=1e-14)
    assert physical_scales(m)["length"] == leg_scale(m)
    # filled settings are filled: a second call changes nothing
    assert t.for_model(_model()) == t


def test_the_scales_are_the_physical_ones():
    """Doubled legs: speeds and impulse x sqrt(2), the torque margin as RABBIT's (same
    limit); three times the mass: the impulse x 3 alone; a 40 N m limit: 40/150."""
    base = TranscriptionSettings().for_model(_model())
    legs = TranscriptionSettings().for_model(_model(find_description("rabbit").scaled(length=2)))
    assert legs.liftoff_min / base.liftoff_min == pytest.approx(math.sqrt(2), rel=1e-14)
    assert legs.impulse_min / base.impulse_min == pytest.approx(math.sqrt(2), rel=1e-14)
    assert legs.torque_margin == base.torque_margin
    heavy = TranscriptionSettings().for_model(_model(find_description("rabbit").scaled(mass=3)))
    assert heavy.impulse_min / base.impulse_min == pytest.approx(3.0, rel=1e-14)
    assert (heavy.liftoff_min, heavy.strike_speed_min) == (base.liftoff_min,
                                                           base.strike_speed_min)
    weak = _model(torque_limit=40.0)
    assert TranscriptionSettings().for_model(weak).torque_margin == pytest.approx(
        base.torque_margin * 40.0 / 150.0, rel=1e-15)


def test_given_values_win_and_zero_is_allowed():
    m = _model(find_description("rabbit").scaled(length=2, mass=2))
    given = TranscriptionSettings(liftoff_min=0.01, strike_speed_min=0.0, impulse_min=0.2,
                                  torque_margin=1)
    g = given.for_model(m)
    assert (g.liftoff_min, g.strike_speed_min, g.impulse_min, g.torque_margin) == \
        (0.01, 0.0, 0.2, 1.0)
    assert type(g.torque_margin) is float
    assert MoveSettings(torque_margin=0.25).for_model(m).torque_margin == 0.25
    st = CodesignSettings(transcription={"impulse_min": 0.2})
    assert st.transcription == {"impulse_min": 0.2}


@pytest.mark.parametrize("make, message", [
    (lambda: TranscriptionSettings(impulse_min=-0.1), r"^impulse_min must be non-negative"),
    (lambda: TranscriptionSettings(liftoff_min="fast"), r"^liftoff_min must be a number"),
    (lambda: TranscriptionSettings(strike_speed_min=math.nan),
     r"^strike_speed_min must be finite"),
    (lambda: TranscriptionSettings(torque_margin=-3), r"^torque_margin must be non-negative"),
    (lambda: TranscriptionSettings(clearance_scale=0.0), r"^clearance_scale must be positive"),
    (lambda: MoveSettings(torque_margin=-0.5), r"^torque_margin must be non-negative"),
    (lambda: MoveSettings(clearance_margin=math.inf), r"^clearance_margin must be finite"),
    (lambda: CodesignSettings(transcription={"impulse_min": -1.0}),
     r"^transcription: impulse_min must be non-negative"),
])
def test_bad_values_are_refused_naming_the_field(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_sampling_search_records_the_clearance_it_used(model):
    """Filled for the robot, the sampling search's settings hold the gait's clearance as
    used (the doubled robot: twice ROBUST_GAIT's); RABBIT's are ROBUST_GAIT's, with the
    same JSON and the same argument key as the unfilled settings."""
    st = RobustDesignSettings()
    rab = st.for_model(model)
    assert json.dumps(rab.to_dict()["gait"]) == json.dumps(ROBUST_GAIT)
    assert argument_key((model, rab)) == argument_key((model, st))
    doubled = _model(model.description.scaled(length=2))
    big = st.for_model(doubled)
    assert big.to_dict()["gait"]["clearance"] == 2 * ROBUST_GAIT["clearance"]
    assert argument_key((doubled, big)) != argument_key((doubled, st))
    assert big.for_model(doubled) == big
    plain = RobustDesignSettings(gait=dict(ROBUST_GAIT))
    assert plain.for_model(doubled) is plain
