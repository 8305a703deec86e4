"""The batched walkers check their limits between their RK4 nodes too
(:mod:`biped_casadi.simulation.margins`, shared with the walking simulator)."""
from __future__ import annotations

import re

import casadi as ca
import numpy as np
import pytest

from biped_casadi.simulation import SimulationOptions, perturbed_initial_state
from biped_casadi.simulation.kernel import screen_steps
from biped_casadi.simulation.margins import MarginCheck
from biped_casadi.simulation.tv_walker import ZeroDynamicsWalker
from biped_casadi.simulation.vc_walker import VirtualConstraintWalker

M1 = np.array([-10.0, 7.5, 10.0, -5.0])


def _walkers(gait):
    opts = SimulationOptions(steps=1)
    return (ZeroDynamicsWalker(gait.model, gait, opts, rk4_steps=400),
            VirtualConstraintWalker(gait.model, gait, opts, nodes=200))


def _walk(walker, q0, dq0):
    if isinstance(walker, ZeroDynamicsWalker):
        return walker.walk(q0[None], dq0[None], M1[None], 0.5, steps=1)
    return walker.walk_from_states(q0[None], dq0[None], steps=1)


@pytest.mark.parametrize("kind", ["tv", "vc"])
def test_a_scuff_between_two_nodes_ends_the_walkers_run(gait, kind, monkeypatch):
    """The step's start (the swing foot on the ground behind the stance foot) with the
    swing knee turned so that the foot moves down at 2 mm/s: the law lifts it again
    within the first RK4 step, below the ground in between (sampled at 65 lengths of
    the time-varying walker's step) and above it at the next node.  Both walkers end the
    run there, scuffed, naming the foot's lowest point "between two RK4 nodes"; checked
    at the nodes only they walk the step."""
    model = gait.model
    q0, dq0 = perturbed_initial_state(gait, 0.0, 0.0)

    def foot_speed(dq):
        return float(model.swing_foot_velocity(q0, dq)[1])

    knee = np.eye(model.nq)[-1]                     # z_sw's rate is linear in dq
    dq = dq0 + (-2e-3 - foot_speed(dq0)) / (foot_speed(dq0 + knee) - foot_speed(dq0)) * knee
    tv, vc = _walkers(gait)
    x0, P = tv.scenarios(q0[None], dq[None], M1[None], 0.5)
    z_r = np.r_[x0[0], gait.states(np.array([0.0]))[:, 0]]
    z = np.array([float(np.array(tv.event(z_r, 0.0, eta, P[0], tv._theta)[0])[0, 0])
                  for eta in np.linspace(0, tv.h, 65)])
    tol = tv.limits.ground_tolerance
    assert z[0] >= -tol and z[-1] > 0 and z.min() < -10 * tol
    walker = tv if kind == "tv" else vc
    b = _walk(walker, q0, dq)
    assert b.status[0] == "scuffed" and b.fail_step[0] == 0
    assert b.message[0].startswith("step 1: swing foot below the ground") and \
        b.message[0].endswith("between two RK4 nodes")
    z_dip = float(re.search(r"z_sw = (\S+) m", b.message[0]).group(1))
    assert z_dip < -tol and (kind == "vc" or z_dip == pytest.approx(z.min(), rel=0.05))
    monkeypatch.setattr("biped_casadi.simulation.margins.swing_foot_dip",
                        lambda *args: None)             # the nodes only
    assert _walk(walker, q0, dq).status[0] == "ok"


def _nodes_Fz(walker, gait, q0, dq0):
    """The stance force at the nodes of the walker's first step (its first quarter T
    for the time-varying walker) from the reference's start."""
    if isinstance(walker, ZeroDynamicsWalker):
        x0, P = walker.scenarios(q0[None], dq0[None], M1[None], 0.5)
        D0, k1 = walker._batch("diag", x0.T, np.zeros((1, 1)), walker._R_start[0.0], P.T)
        Dg = walker._chunk(x0, np.zeros(1), k1.T, P, walker._rtab[0])[3]
        return np.r_[walker.schema.row(D0, "Fz")[0], walker.schema.row(Dg, "Fz")[0]]
    th, w, p = walker._batch("start", q0[:, None], dq0[:, None])
    st = walker._integrate_step(th.ravel(), w.ravel(), p.T, np.zeros(1))
    return walker.schema.row(st["Dg"], "Fz")[0]


@pytest.mark.parametrize("kind", ["tv", "vc"])
def test_a_force_margin_dipping_between_two_nodes_ends_the_walkers_run(gait, kind,
                                                                       monkeypatch):
    """The real closed loop with one more margin, (F_z - F*)^2 - d, F* the stance force
    midway between the 51st and 52nd nodes (F_z rises over those nodes: it crosses F*
    first there) and d a quarter of the nodes' (F_z - F*)^2: above 0 at every node,
    -d between those two.  The run ends there, naming the stance force (F* to within
    2 sqrt(d)) "between two RK4 nodes"; with the margins at the nodes only it walks."""
    q0, dq0 = perturbed_initial_state(gait, 0.0, 0.0)
    walker = _walkers(gait)[kind == "vc"]
    Fz = _nodes_Fz(walker, gait, q0, dq0)
    i = 51
    assert np.all(np.diff(Fz[:i + 2]) > 0)
    F_star = 0.5 * (Fz[i] + Fz[i + 1])
    depth = 0.25 * (0.5 * (Fz[i + 1] - Fz[i])) ** 2
    base = MarginCheck.values

    def values(self, u, Fx, Fz, lib=np):
        extra = (Fz - F_star) ** 2 - depth
        return lib.vertcat(base(self, u, Fx, Fz, lib), extra) if lib is ca else \
            np.concatenate([base(self, u, Fx, Fz), np.asarray(extra, float)[None]])

    monkeypatch.setattr(MarginCheck, "values", values)
    monkeypatch.setattr(MarginCheck, "near",     # it bounds the margins values() has
                        lambda self, R: np.ones(R.shape[1], bool))
    walker = _walkers(gait)[kind == "vc"]
    walker.margin.status.append("negative_normal_force")     # the extra margin's name
    assert ((Fz - F_star) ** 2 - depth).min() > 0
    b = _walk(walker, q0, dq0)
    assert b.status[0] == "negative_normal_force" and b.fail_step[0] == 0
    msg = b.message[0]
    assert msg.startswith("step 1: stance normal force F_z = ") and \
        msg.endswith("N, between two RK4 nodes")
    assert float(re.search(r"F_z = (\S+) N", msg).group(1)) == \
        pytest.approx(F_star, abs=2 * np.sqrt(depth))
    monkeypatch.setattr(MarginCheck, "first_dips", lambda *args: {})     # nodes only
    assert _walk(walker, q0, dq0).status[0] == "ok"


def test_the_screen_estimates_a_first_step_from_the_nodes_after_it():
    """The first step of a batch (or the first after NaN rows) has no node before it:
    the second differences centred on its last node and the next, and their
    extrapolation back, stand in (a margin far from its bound is not flagged there, a
    near one is); with fewer than three nodes every step is flagged."""
    t = np.arange(8.0)
    far, near = 5 + 0.1 * t, 0.2 * (t - 0.5) ** 2 + 0.01
    W = np.stack([far, near], axis=1)
    assert list(screen_steps(W, np.zeros(2))[0]) == [False, True]
    padded = np.concatenate([np.full((2, 2), np.nan), W])
    assert (screen_steps(padded, np.zeros(2))[2:] == screen_steps(W, np.zeros(2))).all()
    assert screen_steps(W[:2], np.zeros(2)).all() and screen_steps(padded[:4], 0).all()
