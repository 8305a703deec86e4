"""Unit tests of the validity conditions (one per condition, on synthetic nodes and
impacts) and of the one outcome type and its verdict."""
from __future__ import annotations

import math

import numpy as np
import pytest

from biped_casadi.simulation import SimulationOptions, WalkBatch, WalkOutcome, verdict
from biped_casadi.simulation.outcome import NOT_CONVERGED, OutcomeRecorder
from biped_casadi.simulation.validity import (NODE_CHECKS, Limits, first_violation,
                                              impact_message, impact_violation, node_message,
                                              node_violations,
                                              start_violation, strike_violation)

LIM = Limits(mu=0.6, min_normal_force=0.0, hip_floor=0.45, max_torso_angle=math.pi / 2,
             ground_tolerance=1e-9, singular_tolerance=0.01, torque_limit=150.0,
             min_liftoff_speed=0.0)


def _node(**over):
    """One valid node (standing, pressed on the ground, swing foot in the air)."""
    row = dict(finite=np.array([True]), den=np.array([5.0]), Fx=np.array([10.0]),
               Fz=np.array([300.0]), in_range=np.array([1.0]), xsw=np.array([0.2]),
               zsw=np.array([0.05]), hip=np.array([0.78]), torso=np.array([0.1]),
               u=np.array([[10.0], [-20.0], [5.0], [1.0]]))
    row.update({k: np.atleast_1d(np.asarray(v, float)) if k != "u" else np.asarray(v, float)
                for k, v in over.items()})
    return row


@pytest.mark.parametrize("change,status", [
    (dict(finite=[False]), "diverged"),
    (dict(in_range=[0.0]), "out_of_range"),
    (dict(den=[0.01]), "singular"),           # below 1 % of the scale 5.0
    (dict(den=[-1.0]), "singular"),           # the sign changed
    (dict(hip=[0.3]), "fell"),
    (dict(torso=[1.7]), "fell"),
    (dict(xsw=[-0.1], zsw=[-0.01]), "scuffed"),
    (dict(Fz=[-1.0]), "negative_normal_force"),
    (dict(Fx=[200.0]), "slipped"),             # |F_x| > 0.6 F_z
    (dict(u=[[151.0], [0.0], [0.0], [0.0]]), "torque_limit"),
])
def test_each_node_condition(change, status):
    rows = _node(**change)
    if status == "diverged":
        rows["finite"] = np.array([False])
    masks = node_violations(rows, LIM, 5.0, 1.0)
    assert list(masks) == [c for c in NODE_CHECKS if c in masks]
    _, which = first_violation({k: v[None, :] for k, v in masks.items()})
    assert which[0] == status
    # and the same node without the change is valid
    ok = node_violations(_node(), LIM, 5.0, 1.0)
    assert not any(m.any() for m in ok.values())
    if status != "diverged":
        node = {k: (v[..., 0] if k != "u" else v[:, 0]) for k, v in rows.items()}
        assert node_message(status, node, LIM, 5.0)


def test_a_huge_friction_ratio_is_printed_in_four_digits_not_three_hundred():
    """Near the law's pole |F_x| / F_z reaches 1e306: the message stays one short line
    (ordinary ratios keep their four decimals)."""
    node = {k: (v[..., 0] if k != "u" else v[:, 0]) for k, v in _node(Fx=[7e306]).items()}
    msg = node_message("slipped", node, LIM, 5.0)
    assert len(msg) < 80 and f"= {7e306 / float(node['Fz']):.4g} > mu" in msg, msg
    node = {k: (v[..., 0] if k != "u" else v[:, 0]) for k, v in _node(Fx=[200.0]).items()}
    assert f"= {200.0 / float(node['Fz']):.4f} > mu" in node_message("slipped", node, LIM, 5.0)
    assert "e+306 > mu" in impact_message("slipped", [7e306, 1.0], 0.1, LIM)


def test_swing_foot_under_the_ground_in_front_is_a_strike_not_a_scuff():
    rows = _node(zsw=[-0.01])                  # in front of the stance foot: a strike
    assert not node_violations(rows, LIM, 5.0, 1.0)["scuffed"].any()
    # but a foot already under the ground that goes further down scuffs
    assert node_violations(rows, LIM, 5.0, 1.0, z_prev=np.array([-0.005]))["scuffed"].all()
    # legs without knees may graze (the model's idealisation)
    graze = Limits(**{**LIM.__dict__, "scuffing_ignored": True})
    assert not node_violations(_node(xsw=[-0.1], zsw=[-0.01]), graze, 5.0, 1.0)["scuffed"].any()


def test_priority_and_first_node():
    """At one node the order of NODE_CHECKS decides; along the nodes the first counts."""
    rows = _node(Fz=[-1.0], u=[[151.0], [0.0], [0.0], [0.0]])
    _, which = first_violation({k: v[None, :] for k, v in
                                node_violations(rows, LIM, 5.0, 1.0).items()})
    assert which[0] == "negative_normal_force"
    masks = {"slipped": np.array([[False, False, True]]),
             "torque_limit": np.array([[False, True, True]])}
    first, which = first_violation(masks)
    assert first[0] == 1 and which[0] == "torque_limit"
    first, which = first_violation(masks, stop=np.array([1]))
    assert first[0] == 3 and which[0] == ""


def test_start_strike_and_impact_conditions():
    assert start_violation([-1e-3, 0.0], LIM).tolist() == ["scuffed", ""]
    assert strike_violation([-0.3, 0.0, 0.1]).tolist() == ["", "scuffed", "scuffed"]
    F = np.array([[1.0, 10.0], [1.0, -1.0], [7.0, 10.0], [1.0, 10.0], [1.0, 10.0]])
    v_lift = np.array([0.5, 0.5, 0.5, -0.1, 0.5])
    finite = np.array([True, True, True, True, False])
    assert impact_violation(F, v_lift, finite, LIM).tolist() == [
        "", "negative_normal_force", "slipped", "scuffed", "diverged"]


def test_limits_of_options(model):
    lim = Limits.of(SimulationOptions(mu=0.5, torque_limit=None), model)
    assert lim.torque_limit == model.params.torque_limit and lim.mu == 0.5
    assert lim.hip_floor == pytest.approx(0.5625 * model.description.leg_length)


def test_a_robot_without_a_torque_limit_is_held_to_its_gaits():
    """A URDF without effort limits: the runs are held to the limit its gait was made
    for (a gait for 60 N m motors walked at 139 N m with status ok), unless the options
    give one; without a gait's limit there is none."""
    from pathlib import Path
    from types import SimpleNamespace

    from biped_casadi import robot
    walker = robot(Path(__file__).resolve().parents[1] / "docs/howto/walker/walker.urdf")
    assert not math.isfinite(walker.params.torque_limit)
    gait = SimpleNamespace(options=SimpleNamespace(torque_limit=60.0))
    assert Limits.of(SimulationOptions(), walker, gait).torque_limit == 60.0
    assert Limits.of(SimulationOptions(torque_limit=80.0), walker, gait).torque_limit == 80.0
    assert Limits.of(SimulationOptions(saturate=True), walker, gait).saturate
    assert not math.isfinite(Limits.of(SimulationOptions(), walker).torque_limit)


# ------------------------------------------------------------------ outcomes
def _recorded():
    rec = OutcomeRecorder(3, 4)
    rec.track([0, 1, 2], np.ones((4, 3, 2)) * np.array([10.0, 20.0, 30.0])[None, :, None],
              np.zeros((3, 2)), np.full((3, 2), 100.0))
    for k in range(4):
        err = np.array([1e-2, 5e-4, 3e-2]) * 0.1 ** k
        rec.impact([0, 1, 2], k, err, -err, np.full(3, 0.7), np.tile([1.0, 10.0], (3, 1)))
    rec.fail([2], ["slipped"], 3, ["step 3: slipped"])
    return rec.batch()


def test_batch_is_an_array_of_outcomes():
    B = _recorded()
    assert isinstance(B[0], WalkOutcome) and len(B) == 3
    for i in range(3):
        o = B[i]
        assert o.status == B.status[i] and o.fail_step == B.fail_step[i]
        assert o.final_error == B.final_error[i] or (math.isinf(o.final_error)
                                                     and math.isinf(B.final_error[i]))
        np.testing.assert_array_equal(o.qu_error, B.qu_error[i])
        assert type(o.peak_torque) is float and type(o.fail_step) is int
        assert o.success                        # the run was simulated
    assert B.ok.tolist() == [True, True, False]
    assert B.peak_torque.tolist() == [10.0, 20.0, 30.0]
    again = WalkBatch.concat([B[0], B[1], B[2]])
    np.testing.assert_array_equal(again.qu_error, B.qu_error)
    assert again.status.tolist() == B.status.tolist()


def test_convergence_and_verdict():
    B = _recorded()
    # run 0: errors 1e-2, 1e-3, 1e-4, 1e-5 -> below 1e-3 from step 3 (1e-3 is not below)
    assert B.steps_to_converge(1e-3).tolist()[:2] == [3.0, 1.0]
    assert math.isnan(B.steps_to_converge(1e-3)[2])          # failed
    assert B.verdict(1e-3).tolist() == ["ok", "ok", "slipped"]
    assert B.verdict(1e-7).tolist() == [NOT_CONVERGED, NOT_CONVERGED, "slipped"]
    assert verdict("ok", 2e-3, 1e-3) == NOT_CONVERGED and verdict("fell", np.inf, 1) == "fell"
    assert B[0].completed_steps == 4 and B[0].unactuated_errors().shape == (4,)
    d = B.to_dict()
    assert d["status"] == ["ok", "ok", "slipped"] and len(d["qu_error"][0]) == 4


def test_friction_ratio_where_the_normal_force_is_not_positive():
    """A node with F_z <= 0 makes the single-support ratio infinite, as an impulse with
    F_z <= 0 makes the impact ratio (it was |F_x| / 1e-300, ~1e303); runs with F_z > 0
    keep their ratio."""
    rec = OutcomeRecorder(3, 1)
    Fx = np.array([[30.0, 10.0], [5.0, 20.0], [1.0, 2.0]])
    Fz = np.array([[100.0, -50.0], [100.0, 0.0], [100.0, 100.0]])
    rec.track([0, 1, 2], np.zeros((4, 3, 2)), Fx, Fz)
    B = rec.batch()
    assert B.max_friction_ratio.tolist() == [math.inf, math.inf, 0.02]
    assert B.min_normal_force.tolist() == [-50.0, 0.0, 100.0]
    rec = OutcomeRecorder(2, 1)                  # a node that is not finite: NaN, as before
    rec.track([0, 1], np.zeros((4, 2, 1)), np.array([[np.nan], [1.0]]),
              np.array([[np.nan], [np.nan]]))
    assert np.isnan(rec.batch().max_friction_ratio).all()
    rec = OutcomeRecorder(1, 1)                  # a masked node does not count
    rec.track([0], np.zeros((4, 1, 2)), Fx[:1], Fz[:1], mask=np.array([[True, False]]))
    assert rec.batch().max_friction_ratio.tolist() == [0.3]


def test_simulate_prints_no_giant_ratio(capsys):
    """A start far off the orbit (F_z <= 0 at once): the text says inf, not a
    300-digit number, and --json gives null for it."""
    import json

    from analysis.cli import main
    assert main(["simulate", "--controller", "vc", "--perturb", "1", "0"]) == 1   # stopped
    out = capsys.readouterr().out
    assert "max |F_x|/F_z inf" in out and max(len(w) for w in out.split()) < 40, out
    assert main(["simulate", "--controller", "vc", "--perturb", "1", "0", "--json"]) == 1
    assert json.loads(capsys.readouterr().out)["max_friction_ratio"] is None


def test_a_gait_at_its_friction_bound_walks_its_own_orbit(model):
    """RABBIT's gait at 1.1 m/s has its impact impulse on the cone (|F_x| / F_z =
    0.6 + 1.6e-10, within the optimiser's tolerance; `biped gait`'s dense-grid check:
    all constraints hold); simulating its own orbit said 'slipped: 0.6000 > mu = 0.6'.
    The friction checks take the gait's tolerance (1e-7 on the ratio)."""
    from biped_casadi import Design, simulate
    from gait_opt import optimize_gait
    g = optimize_gait(model, speed=1.1, cache=True)
    assert g.violations() == []
    run = simulate(Design.vc(g).controller_for(), *g.evaluate(0.0)[:2])
    assert run.ok, run.message
    assert 0.6 < run.max_impulse_ratio < 0.6 + 1e-7


def test_limits_friction_is_the_gaits_unless_given(model):
    """Without ``mu`` in the options a run is held to the friction coefficient its gait
    was optimised for (``biped gait --mu``), else 0.6; a given ``mu`` wins."""
    from types import SimpleNamespace

    gait = SimpleNamespace(options=SimpleNamespace(mu=0.9))
    assert SimulationOptions().mu is None
    assert Limits.of(SimulationOptions(), model, gait).mu == 0.9
    assert Limits.of(SimulationOptions(mu=0.5), model, gait).mu == 0.5
    assert Limits.of(SimulationOptions(), model).mu == 0.6
    assert Limits.of(SimulationOptions(), model, SimpleNamespace()).mu == 0.6
    with pytest.raises(ValueError, match="mu"):
        SimulationOptions(mu=0.0)
