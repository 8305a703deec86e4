"""The walking simulator's stance force, friction cone and torques between its RK4 nodes
(:mod:`biped_casadi.simulation.margins`)."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from biped_casadi.simulation import SimulationOptions, Simulator, perturbed_initial_state
from biped_casadi.simulation.kernel import (SUB_STEPS, Diagnostics, minima_sampled,
                                           screen_steps)
from biped_casadi.simulation.margins import MarginCheck
from biped_casadi.simulation.validity import Limits


@pytest.fixture(scope="module")
def vc(gait):
    from biped_casadi.control import VirtualConstraintController
    return VirtualConstraintController(gait)


def _limits(**kw):
    base = dict(mu=0.6, min_normal_force=0.0, hip_floor=0.0, max_torso_angle=1.0,
                ground_tolerance=1e-9, singular_tolerance=1e-3, torque_limit=100.0,
                min_liftoff_speed=0.0)
    return Limits(**{**base, **kw})


@pytest.mark.parametrize("samples", [0, SUB_STEPS])
@pytest.mark.parametrize("output, status", [(0, "negative_normal_force"), (1, "slipped"),
                                            (2, "slipped"), (3, "torque_limit"),
                                            (4, "torque_limit")])
def test_a_margin_below_its_bound_between_two_nodes_is_found_where_the_nodes_pass(
        output, status, samples):
    """Margins c(t) = a (t - t*)^2 - d along twelve steps of 1 ms, lowest strictly inside
    the seventh (t* = 6.3 ms) and above 0 at every node: the screen flags the steps
    near the dip and not those far from it; the minimum is located at t* and named, by
    its rate (samples 0) or from the margins alone (a law without derivatives: where
    the margin is as low as at t*, to its round-off).  A dip that stays above 0 is
    nothing."""
    h, a, t_star = 1e-3, 2e6, 6.3e-3
    lim, schema = _limits(), Diagnostics(1)            # one torque: 5 margins
    check = MarginCheck(lim, schema)
    calls = []

    def margins(t, depth):
        c = np.full(5, 50.0)
        c[output] = a * (t - t_star) ** 2 - depth
        return c

    def between(X, tau, eta, p, depth=0.1):
        t = tau + eta
        calls.append(tau)
        dc, ddc = np.zeros(5), np.zeros(5)
        dc[output], ddc[output] = 2 * a * (t - t_star), 2 * a
        return margins(t, depth) if samples else (margins(t, depth), dc, ddc)

    ts = np.arange(13) * h
    W = np.array([margins(t, 0.1) for t in ts])
    assert W.min() > 0                                  # every node valid
    steps = [(None, t, h, None) for t in ts[:-1]]
    j, eta, got = check.first_dip(between, W, steps, samples)
    assert (j, got) == (6, status)
    if samples:         # from values: as low as the minimum, to the margin's last digit
        assert a * (ts[j] + eta - t_star) ** 2 <= np.spacing(0.1)
    else:
        assert ts[j] + eta == pytest.approx(t_star, rel=1e-12)
    assert set(np.round(np.array(calls) / h).astype(int)) <= {0, 5, 6, 7}   # screened
    W = np.array([margins(t, -0.5) for t in ts])
    assert check.first_dip(lambda *x: between(*x, depth=-0.5), W, steps, samples) is None


def test_sampled_minima_are_inside_the_step_not_at_its_nodes():
    """From values alone (minima_sampled, 16 parts of a 1 ms step): a margin falling
    through the step to below 0 at its last node has no minimum inside (it is that
    node's, as where the rate has no root); a dip below 0 inside the first part, every
    sample above 0, is found (the first part screened by the samples after it) at its
    lowest point; one far from its bound costs no search beyond the samples, nor one not
    flagged."""
    h, a = 1e-3, 2e8
    t1 = 0.3 * h / SUB_STEPS
    d = 0.5 * a * t1 ** 2                               # c(0) = a t1^2 - d > 0
    calls = []

    def between(eta):
        calls.append(eta)
        return np.array([0.5 - 1e3 * eta, a * (eta - t1) ** 2 - d, -1.0, 50.0 + 1e3 * eta])

    ends = between(0.0), between(h)
    assert min(between(e)[1] for e in np.linspace(0, h, SUB_STEPS + 1)) > 0   # samples pass
    counts = []
    for far in (False, True):
        calls.clear()
        found = minima_sampled([True, True, False, far], between, h, *ends)
        counts.append(len(calls))
        assert [i for _, i, _ in found] == [1]
        eta, _, v = found[0]
        assert v < 0 and a * (eta - t1) ** 2 <= np.spacing(d)
    assert counts[0] == counts[1] > SUB_STEPS - 1


def test_screen_steps_is_the_running_cycles_screen():
    """screen_steps on four nodes gives the last step's flags the running cycle's
    screen gave (centred second differences and their extrapolation, factor 2)."""
    W = np.array([[1.0, 5.0], [0.2, 4.0], [0.05, 3.5], [0.1, 3.4]])
    d1, d0 = W[3] - 2 * W[2] + W[1], W[2] - 2 * W[1] + W[0]
    curv = np.maximum(np.maximum(np.abs(d1), np.abs(d0)), np.abs(2 * d1 - d0))
    want = np.minimum(W[2], W[3]) - curv / 4 < 0
    assert list(screen_steps(W, np.zeros(2))[-1]) == list(want) == [True, False]
    assert screen_steps(W[:2], np.zeros(2)).all()       # the first step: always


def test_a_force_margin_dipping_between_two_nodes_stops_the_run(gait, vc, monkeypatch):
    """The real closed loop with one more margin, (F_z - F*)^2 - d, F* the stance force
    midway between two nodes of the nominal step's middle and d a quarter of the nodes'
    (F_z - F*)^2: above 0 at every node, below between those two (the RK4 step sampled
    at 64 lengths says where).  The run stops there, naming it, at that time, "between
    two RK4 nodes"; with the margins at the nodes only it walks."""
    q0, dq0 = perturbed_initial_state(gait, 0.0, 0.0)
    opts = SimulationOptions(steps=1)
    nominal = Simulator(vc, opts).run(q0, dq0)
    i = len(nominal.t) // 2
    F_star = 0.5 * (nominal.Fz[i] + nominal.Fz[i + 1])
    depth = 0.25 * (0.5 * (nominal.Fz[i + 1] - nominal.Fz[i])) ** 2
    base = MarginCheck.values

    def values(self, u, Fx, Fz, lib=np):
        extra = (Fz - F_star) ** 2 - depth
        return lib.vertcat(base(self, u, Fx, Fz, lib), extra) if lib is ca else \
            np.vstack([base(self, u, Fx, Fz), np.atleast_1d(extra)[None, :]])

    monkeypatch.setattr(MarginCheck, "values", values)
    sim = Simulator(vc, opts)
    sim.margin.status.append("negative_normal_force")        # the extra margin's name
    X = np.r_[nominal.q[i], nominal.dq[i]]
    p = vc.step_start(q0, dq0).p
    etas = np.linspace(0, sim.h, 65)
    Fz = np.array([float(sim.schema.row(sim.diagnostics(
        sim.event(X, nominal.tau[i], e, p)[2].ravel(), nominal.tau[i] + e, p)[0], "Fz")[0])
        for e in etas])
    assert ((Fz - F_star) ** 2 - depth).min() < 0 and Fz[0] != F_star != Fz[-1]
    res = sim.run(q0, dq0)
    assert res.status == "negative_normal_force" and "between two RK4 nodes" in res.message
    assert nominal.t[i] < res.failure_time < nominal.t[i + 1]
    assert abs(res.failure_time - nominal.t[i] - etas[np.argmin(np.abs(Fz - F_star))]) \
        <= 2 * etas[1]
    assert res.Fz[-1] == pytest.approx(F_star, abs=2 * np.sqrt(depth))
    monkeypatch.setattr(MarginCheck, "first_dip", lambda *args: None)   # nodes only
    assert sim.run(q0, dq0).status == "ok"
