"""The fall and the controller's singularity are checked at the RK4 nodes only: the
arguments of :mod:`biped_casadi.simulation.validity` ("At the nodes only"), pinned.

The denominator of the time-varying law going through zero mid-step stops the walking
simulator and the time-varying walker on the torques (or the stance reaction) while it is
still over ten of its largest between-node dips away from zero (and with the torque
limit and the friction lifted, no run passes that zero); on virtual
constraints the denominator, the hip height and the torso angle between two nodes are
those of the constraint curve at the phase between them; the hip and the torso of the
time-varying walker at its coarsest step in use (T/128) go beyond its nodes' by less
than the screen's estimate, micrometres.
"""
from __future__ import annotations

import numpy as np
import pytest

from biped_casadi.control import Design
from biped_casadi.control.output_law import decoupling_denominator
from biped_casadi.control.zero_dynamics import denominator_samples
from biped_casadi.simulation import SimulationOptions, Simulator, perturbed_initial_state
from biped_casadi.simulation.kernel import SCREEN_SAFETY
from biped_casadi.simulation.tv_walker import ZeroDynamicsWalker
from biped_casadi.simulation.vc_walker import VirtualConstraintWalker

M1 = np.array([-10.0, 7.5, 10.0, -5.0])
#: the starts (q_u, dq_u offsets, rad and rad/s): a small one and the README's
STARTS = [(1e-5, 1e-4), (2e-4, 2e-3)]
#: where the run stops before the denominator: the torque limit, or the stance reaction
#: (its horizontal component grows like the torques)
FORCE_STOPS = ("torque_limit", "slipped", "negative_normal_force")


def _singular_mid_step(gait) -> np.ndarray:
    """M1 with its first entry set so that D11 - D12 M1 (eq. 24) is 0 on the reference at
    T/2 (it changes sign there; the other entries those of M1)."""
    D11, D12 = denominator_samples(gait, 3)                 # tau = 0, T/2, T
    out = M1.copy()
    out[0] += float(decoupling_denominator(D11, D12, M1)[1]) / D12[0, 1]
    return out


def _largest_dip(values) -> float:
    """The most a smooth sequence of node values can dip between two of its nodes by the
    screen's estimate: SCREEN_SAFETY / 8 times its largest second difference."""
    return SCREEN_SAFETY / 8 * float(np.max(np.abs(np.diff(values, 2))))


@pytest.mark.parametrize("rk4_steps", [2000, 200])
@pytest.mark.parametrize("start", STARTS)
def test_the_simulator_stops_on_the_torques_before_the_denominator_nears_zero(
        gait, start, rk4_steps):
    """The reference's denominator goes through 0 at T/2; with no tolerance band (only
    its sign stops a run as singular) the run from a perturbed start stops on its
    torques (or the reaction) before T/2, the denominator there still more than 10 of
    its largest dips between two nodes (over the run, by the screen's estimate) away
    from 0 (measured: 70 at T/200 from the smaller start, 7500 at T/2000): it cannot
    have changed sign and back in a step."""
    M = _singular_mid_step(gait)
    sim = Simulator(Design.tv(gait, M, rejoin=0.5).controller_for(),
                    SimulationOptions(steps=1, singular_tolerance=0.0, rk4_steps=rk4_steps))
    r = sim.run(*perturbed_initial_state(gait, *start))
    assert r.status in FORCE_STOPS and r.failure_time < 0.5 * gait.T
    den = r.denominator / sim._den_scale
    assert np.all(den * den[0] > 0)                          # no sign change at a node
    assert abs(den[-1]) > 10 * _largest_dip(den)
    assert abs(den[-1]) < 0.2                                # ... and the pole near


def _recorded_nodes(monkeypatch, module):
    """The rows and masks of every call of ``module``'s node_violations (a walk's
    nodes, in order), recorded."""
    calls = []
    base = module.node_violations

    def record(rows, *args, **kw):
        masks = base(rows, *args, **kw)
        calls.append((rows, masks))
        return masks

    monkeypatch.setattr(module, "node_violations", record)
    return calls


@pytest.mark.parametrize("start", STARTS)
def test_the_time_varying_walker_stops_on_the_torques_before_the_denominator(
        gait, start, monkeypatch):
    """As the simulator, in the time-varying walker at its coarsest step in use (T/128,
    basins and terrain): the run stops on a force condition, at a node whose
    denominator is more than 10 of the run's largest dips between two nodes from 0
    (measured: 32 from the smaller start)."""
    from biped_casadi.simulation import tv_walker
    calls = _recorded_nodes(monkeypatch, tv_walker)
    walker = ZeroDynamicsWalker(gait.model, gait, SimulationOptions(singular_tolerance=0.0),
                                rk4_steps=128)
    q0, dq0 = perturbed_initial_state(gait, *start)
    b = walker.walk(q0[None], dq0[None], _singular_mid_step(gait)[None], 0.5, steps=1)
    assert b.status[0] in FORCE_STOPS and b.fail_step[0] == 0
    den, stop = [], None
    for rows, masks in calls:
        bad = np.any([np.atleast_2d(m)[0] for m in masks.values()], axis=0)
        d = np.atleast_2d(rows["den"])[0]
        if bad.any():
            stop = len(den) + int(np.argmax(bad))
            den.extend(d[:int(np.argmax(bad)) + 1])
            break
        den.extend(d)
    assert stop is not None
    den = np.array(den) / walker.den_scale(_singular_mid_step(gait))[0]
    assert np.all(den * den[0] > 0)
    assert abs(den[stop]) > 10 * _largest_dip(den)


@pytest.mark.parametrize("nodes", [100, 200])
def test_on_virtual_constraints_the_stops_between_nodes_are_the_curves(gait, nodes):
    """The virtual-constraint walker's configuration is the constraint curve's at the
    phase, and the phase between two nodes is exact: its denominator, hip height and
    torso angle there are the curve's (sampled at 16 phases per step), beyond the
    nodes' by less than the screen's estimate from them: under 1e-4 of the
    denominator's scale (the singular tolerance is 1e-2) and 1e-5 m or rad."""
    model = gait.model
    walker = VirtualConstraintWalker(model, gait, nodes=nodes)
    vm = walker.vmap
    th = np.linspace(vm.theta_plus, vm.theta_minus, 16 * nodes + 1)
    Q, _, den = (np.array(v) for v in vm.curve.map(th.size)(th[None, :]))
    hip = np.array([float(np.array(model.points(Q[:, i]))[1, model.hip_index])
                    for i in range(th.size)])
    torso = np.array([float(model.torso_angle(Q[:, i])) for i in range(th.size)])
    for values, size in ((den.ravel() / walker.den_scale, 1e-4), (hip, 1e-5),
                         (torso, 1e-5)):
        at_nodes = values[::16]
        parts = values[:-1].reshape(nodes, 16)
        lo = np.minimum(at_nodes[:-1], at_nodes[1:])
        hi = np.maximum(at_nodes[:-1], at_nodes[1:])
        beyond = max(np.max(lo - parts.min(axis=1)), np.max(parts.max(axis=1) - hi))
        assert beyond <= max(_largest_dip(at_nodes), 1e-12) and beyond < size


def test_the_time_varying_walkers_hip_and_torso_between_nodes(gait):
    """At the time-varying walker's coarsest step in use (T/128), from the README's
    perturbation: the hip height and the torso angle at 17 lengths of each RK4 step of
    the first quarter T go beyond the nodes' by less than the screen's estimate from
    the nodes, under 1e-5 m and rad: a fall's bound, a judgment, is met at the nodes
    to that."""
    walker = ZeroDynamicsWalker(gait.model, gait, SimulationOptions(), rk4_steps=128)
    q0, dq0 = perturbed_initial_state(gait, 2e-4, 2e-3)
    x0, P = walker.scenarios(q0[None], dq0[None], M1[None], 0.5)
    S = walker.schema
    D0, k1 = walker._batch("diag", x0.T, np.zeros((1, 1)), walker._R_start[0.0], P.T)
    Xs, Ts, _, Dg = walker._chunk(x0, np.zeros(1), k1.T, P, walker._rtab[0])
    X = np.c_[x0.T, Xs[:, 0]]
    t = np.r_[0.0, Ts[0]]
    p = np.r_[P[0], walker._theta]
    rows = {r: np.r_[S.row(D0, r)[0], S.row(Dg, r)[0]] for r in ("hip", "torso")}
    for j in range(walker.K):
        z = np.r_[X[:, j], gait.states(np.array([t[j]]))[:, 0]]
        dense = np.array([walker._state_at(z, t[j], p, e)[:, 0]
                          for e in np.linspace(0, walker.h, 17)[1:-1]])
        for r, values in rows.items():
            v = S.row(dense.T, r).ravel()
            lo, hi = sorted(values[j:j + 2])
            beyond = max(lo - v.min(), v.max() - hi)
            assert beyond <= _largest_dip(values) and beyond < 1e-5, (r, j)


def test_with_the_limits_lifted_no_run_passes_the_denominators_zero(gait):
    """Torque limit and friction lifted (1e9), no tolerance band: the runs still stop at
    the zero of the denominator, none passes it: the simulator on the reaction at its
    pole, found between two RK4 nodes by the screen (at T/200 from the smaller start),
    or on the normal force; the time-varying walker on its sign at a node, on the
    reaction between two nodes or on the normal force.  The simulator's denominator
    keeps its sign at every state it logged."""
    M = _singular_mid_step(gait)
    opts = SimulationOptions(steps=1, singular_tolerance=0.0, torque_limit=1e9, mu=1e9)
    stops = ("singular",) + FORCE_STOPS
    for start, rk4_steps in ((STARTS[0], 200), (STARTS[1], 2000)):
        sim = Simulator(Design.tv(gait, M, rejoin=0.5).controller_for(),
                        SimulationOptions(**{**opts.to_dict(), "rk4_steps": rk4_steps}))
        r = sim.run(*perturbed_initial_state(gait, *start))
        assert r.status in stops and r.failure_time < gait.T
        assert np.all(r.denominator * r.denominator[0] > 0)
        if rk4_steps == 200:
            assert r.status == "slipped" and r.message.endswith("between two RK4 nodes")
    for rk4_steps in (128, 400):
        walker = ZeroDynamicsWalker(gait.model, gait, opts, rk4_steps=rk4_steps)
        for start in STARTS:
            q0, dq0 = perturbed_initial_state(gait, *start)
            b = walker.walk(q0[None], dq0[None], M[None], 0.5, steps=1)
            assert b.status[0] in stops and b.fail_step[0] == 0
