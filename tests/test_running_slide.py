"""The stance foot sliding near takeoff (analysis.stability.running_cycle with
``sliding``, biped_casadi.model.flight's ``sliding_dynamics``): the sliding dynamics
against the pinned foot's and the energy balance, a stride whose pinned foot would
leave the cone sliding instead, a slip that stops sticking again (or sliding the other
way), and a third slip stop under one law refused."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from biped_casadi.model import flight_model
from analysis.stability.hybrid_cycle import HybridCycle, HybridCycleError
from analysis.stability.running_cycle import (finite_difference_jacobian, running_cycle,
                                              running_stability, simulate_running)
from analysis.stability.running_domains import SLIP_STOP, SLIP_PART, FZ_PART


@pytest.fixture(scope="session")
def star(running_cycle15):
    return running_stability(running_cycle15)


def _states(model, k=4, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(k):
        yield (rng.normal(size=model.nq) * 0.3, rng.normal(size=model.nq),
               rng.normal(size=model.nu) * 20)


def test_sliding_at_the_pinned_foots_ratio_is_the_pinned_dynamics(model):
    """With the friction ratio the pinned foot needs (Fx / Fz of ``takeoff_guard``), the
    sliding foot does not accelerate along the ground and the joints move as pinned."""
    fl = flight_model(model)
    nq = model.nq
    for q, dq, u in _states(model):
        Fz, Fx = (float(v) for v in fl.takeoff_guard(q, dq, u))
        ddq = np.array(model.forward_dynamics(q, dq, u)).ravel()
        qe, dqe = fl.takeoff(q, dq)
        dde, Fs = fl.sliding_dynamics(qe, dqe, u, Fx / Fz)
        dde = np.array(dde).ravel()
        assert np.abs(dde[:nq] - ddq).max() < 1e-9 * max(1.0, np.abs(ddq).max())
        assert np.abs(dde[nq:]).max() < 1e-9
        assert abs(float(Fs) - Fz) < 1e-9 * max(1.0, abs(Fz))


def test_sliding_power_balance(model):
    """dE/dt along the sliding dynamics is the joints' power plus the friction force's
    (the normal force does no work: the foot stays on the ground), from the energy's
    own expression, for any slip velocity and friction ratio."""
    fl = flight_model(model)
    nq, ne = model.nq, fl.ne
    qe, dqe, u, mus = (ca.SX.sym("qe", ne), ca.SX.sym("dqe", ne), ca.SX.sym("u", model.nu),
                       ca.SX.sym("mu_s"))
    dde, Fz = fl.sliding_dynamics(qe, dqe, u, mus)
    E = fl.energy(qe, dqe)[2]
    dE = ca.jtimes(E, ca.vertcat(qe, dqe), ca.vertcat(dqe, dde))
    work = ca.dot(ca.mtimes(ca.DM(fl.Be), u), dqe) + mus * Fz * dqe[nq]
    f = ca.Function("balance", [qe, dqe, u, mus], [dE, work, Fz * mus * dqe[nq]])
    rng = np.random.default_rng(1)
    for q, dq, uu in _states(model):
        x = np.r_[q, rng.normal(), 0.0]
        v = np.r_[dq, rng.normal(), 0.0]
        a, b, friction = (float(w) for w in f(x, v, uu, rng.uniform(-0.8, 0.8)))
        assert abs(a - b) < 1e-9 * max(1.0, abs(a))
        assert abs(friction) > 1e-3                  # the friction's work is in the test


def test_a_stride_slides_where_the_pinned_foot_leaves_the_cone(running_cycle15, star, model):
    """x* + 0.01 rad/s on every velocity: pinned without a slack, the stance leaves the
    friction cone before takeoff (the old model stopped there, or carried a slack);
    with sliding the stride runs, the cone is never exceeded beyond round-off with the
    foot pinned, the sliding foot's force is on the cone's edge against its velocity,
    and the Jacobian through the slide is exact."""
    cyc, nq = running_cycle15, model.nq
    c, fl = cyc.controller, cyc.controller.fl
    x = star.fixed_point.copy()
    x[nq:] += 1e-2
    pinned = running_cycle(c, sliding=False, friction_slack=0.0)
    with pytest.raises(HybridCycleError, match=r"friction cone"):
        pinned.stride(x)
    sv = cyc.stride(x, record=True)
    st, sl, po, fli = sv.passes[0], sv.passes[1], sv.passes[4], sv.passes[-1]
    assert sv.durations[[2, 3, 5, 6]].tolist() == [0.0] * 4      # no slip stops
    assert sl.duration > 1e-5                                    # 1.26 ms measured
    N = st.times.size
    u = c.applied(c.stance_law.map(N)(st.nodes[:nq], st.nodes[nq:], st.times[None, :]))
    Fz, Fx = (np.array(v).ravel() for v in fl.takeoff_guard.map(N)(st.nodes[:nq],
                                                                   st.nodes[nq:], u))
    assert np.max(np.abs(Fx) - cyc.mu * Fz) < 1e-9
    assert abs(abs(Fx[-1]) - cyc.mu * Fz[-1]) < 1e-9 and Fz[-1] > 0    # slides on the edge
    sigma = sl.parameters[-2]
    assert sigma == np.sign(Fx[-1]) and po.parameters[-2] == sigma
    v = sl.nodes[fl.ne + nq]                                     # the slip velocity
    assert np.all(-sigma * v >= -1e-9) and -sigma * v[-1] > 0
    assert fli.entry[nq] == pytest.approx(sl.nodes[nq, -1] if po.duration == 0
                                          else po.exit_state[nq])
    J = finite_difference_jacobian(cyc, x, 1e-6)
    A = cyc.linearise(x).A
    assert np.abs(J - A).max() / np.abs(A).max() < 1e-6


def test_at_the_fixed_point_the_foot_slides_briefly(running_cycle15, star):
    """The closed loop's own orbit is not the collocated one: Fx is not 0 where Fz
    vanishes, so its takeoff slides (a few microseconds)."""
    assert star.status == "stable"
    d = running_cycle15.stride(star.fixed_point).durations
    assert 0 < d[1] < 1e-4


def test_a_takeoff_slide_too_short_to_gather_a_slip_is_a_takeoff(running_cycle15, star, model):
    """x* moved along the slide's duration gradient until it slides 5e-8 s: the slip at
    takeoff (7.5e-13 m/s) is below what a stop's threshold of 1e-12 m/s took for a stop
    before the guard's parts were told apart; now the slide ends on its normal-force
    part, the stick and the second slide are skipped, the foot leaves with its slip, and
    the Jacobian is the central differences'."""
    cyc, nq = running_cycle15, model.nq
    ne = cyc.controller.fl.ne
    lin = cyc.linearise(star.fixed_point)
    g = lin.duration_gradients[1]
    x = star.fixed_point + (5e-8 - lin.durations[1]) * g / (g @ g)
    lin = cyc.linearise(x, record=True)
    sl, fli = lin.passes[1], lin.passes[-1]
    v = sl.exit_state[ne + nq]
    assert 0 < sl.duration < 1e-7 and 0 < abs(v) < 1e-12
    assert fli.entry[ne + nq] == v                       # the foot leaves as it slid
    assert sl.part == FZ_PART and [ps.part for ps in lin.passes[2:4]] == [None, None]
    assert lin.durations[2:-1].tolist() == [0.0] * 5
    J = finite_difference_jacobian(cyc, x, 1e-6)
    assert np.abs(J - lin.A).max() / np.abs(lin.A).max() < 1e-6


def _landing_slip(cyc, star, nq, v=0.01):
    """The landing state in flight coordinates with the foot slipping at ``v``."""
    qe, dqe = (np.array(w).ravel() for w in cyc.controller.fl.takeoff(star.fixed_point[:nq],
                                                                    star.fixed_point[nq:]))
    dqe[nq] = v
    return np.r_[qe, dqe]


def test_a_slip_that_stops_sticks_again(running_cycle15, star, model):
    """The slide under the stance law entered mid-stance (the landing state, Fz ~ the
    weight) with the foot moving at 1 cm/s: friction stops it long before Fz reaches 0;
    the foot sticks there (pinned, the cone met at every node) until the cone's edge near
    takeoff, and slides again to Fz = 0; the exact Jacobian of that map, through the
    slip's stop and the stick, is the central differences'."""
    cyc, nq = running_cycle15, model.nq
    c, fl = cyc.controller, cyc.controller.fl
    ne = fl.ne
    y = _landing_slip(cyc, star, nq)
    sv = HybridCycle(cyc.domains[1:4]).stride(y, record=True)
    sl, st, again = sv.passes
    assert 0 < sl.duration < st.duration and again.duration > 0
    assert sl.part == SLIP_PART and st.entry[ne + nq] == 0.0                   # stopped
    assert st.part == "friction margin mu Fz - |Fx|" and again.part == FZ_PART
    X, t = st.nodes, st.times + st.parameters[-1]
    N = t.size
    u = c.applied(c.stance_law.map(N)(X[:nq], X[ne:ne + nq], t[None, :]))
    Fz, Fx = (np.array(w).ravel() for w in fl.takeoff_guard.map(N)(X[:nq], X[ne:ne + nq], u))
    assert np.all(np.abs(Fx) <= cyc.mu * Fz + 1e-9) and Fz.min() > 0          # stuck
    assert abs(abs(Fx[-1]) - cyc.mu * Fz[-1]) < 1e-9                           # to the edge
    assert np.all(X[nq] == sl.exit_state[nq])                                  # in place
    assert again.parameters[-3] == 1 and again.parameters[-2] == np.sign(Fx[-1])
    sub = HybridCycle(cyc.domains[1:4])
    J = finite_difference_jacobian(sub, y, 1e-6)
    A = sub.linearise(y).A
    assert np.abs(J - A).max() / np.abs(A).max() < 1e-6


def test_a_third_slip_stop_is_refused(running_cycle15, star, model):
    """The last slide under a law (after a stick) entered in the same way: its slip must
    not stop, and the stride is refused with the named reason."""
    cyc = running_cycle15
    with pytest.raises(HybridCycleError, match=r"^domain 'slide again': slip velocity \(the "
                       r"sliding foot stops again before takeoff: stick-slip beyond slide -> "
                       r"stick -> slide under one law not modelled\) violated at t = "):
        HybridCycle([cyc.domains[3]]).stride(_landing_slip(cyc, star, model.nq))
    assert SLIP_STOP.startswith("slip velocity")


def test_a_push_off_that_stops_slides_the_other_way(running_cycle15, star, model):
    """x* less 0.01 rad/s on dq1, its second stride: the sliding push-off's foot stops
    before takeoff (the model without re-sticking refused this stride), where the pinned
    foot would need more than mu Fz the other way: the stick is empty, the foot slides
    back to the takeoff, the cone is met, the run goes on, and the exact Jacobian through
    the slip's stop is the central differences'."""
    cyc, nq = running_cycle15, model.nq
    x = star.fixed_point.copy()
    x[nq] -= 0.01
    x2 = cyc.stride(x).next_state
    sv = cyc.stride(x2, record=True)
    po, stick, back = sv.passes[4:7]
    assert po.duration > 0 and stick.duration == 0.0 and back.duration > 0
    assert po.part == SLIP_PART and stick.part == "friction margin mu Fz - |Fx|"   # at entry
    assert po.exit_state[cyc.controller.fl.ne + nq] != 0 and back.entry[-2] == 0.0
    assert back.parameters[-2] == -po.parameters[-2]
    run = simulate_running(cyc, star.fixed_point, x, 4)
    assert run.status == "ok", run.message
    assert max(s.friction_excess_max for s in run.strides) < 1e-9
    J = finite_difference_jacobian(cyc, x2, 1e-6)
    A = cyc.linearise(x2).A
    assert np.abs(J - A).max() / np.abs(A).max() < 1e-6


def test_the_slack_is_the_pinned_models(running_cycle15):
    c = running_cycle15.controller
    assert running_cycle15.sliding and running_cycle15.friction_slack == 0.0
    with pytest.raises(ValueError, match="friction_slack must be 0 with sliding"):
        running_cycle(c, friction_slack=3.0)
    with pytest.raises(ValueError, match="sliding must be"):
        running_cycle(c, sliding="yes")


def test_the_stride_clock_slides_too(running_cycle15, model):
    """With the stance's clock continued through the flight, the sliding push-off and the
    flight take the law's time from the landing: the fixed point closes and its exact
    Jacobian, through the slide, is the central differences'."""
    cyc = running_cycle(running_cycle15.controller, flight_clock="stride")
    assert all(d.clock_from == 0 for d in cyc.domains)
    r = running_stability(cyc)
    assert r.status in ("stable", "unstable") and r.residual < 1e-10
    sv = cyc.stride(r.fixed_point, record=True)
    assert sv.durations[1] > 0                                 # it slides
    g = cyc.controller.gait
    assert sv.passes[-1].parameters[-1] == pytest.approx(
        sum(sv.durations[:-1]) - g.T_stance, abs=1e-15)
    J = finite_difference_jacobian(cyc, r.fixed_point, 1e-5)
    assert np.abs(J - r.A).max() < 1e-6 * np.abs(r.A).max()


def test_central_differences_keep_to_the_strides_sequence_of_domains(running_cycle15, star,
                                                                      model):
    """A state 2 um (along dq1) inside the states whose push-off lasts: P has a kink
    where the push-off becomes empty, and a step of 1e-5 on dq1 crosses it.  The central
    differences shrink that column's step until both sides run x's domains, and agree
    with the exact Jacobian (a column whose step stays inside keeps it); a point on the
    edge itself is refused."""
    cyc, nq = running_cycle15, model.nq
    po = cyc.kinds.index("slide", 4)                     # the push-off: the flight law's slide

    def lasts(s):
        x = star.fixed_point.copy()
        x[nq] -= s
        return cyc.stride(x).durations[po] > 0

    lo, hi = 0.0, 0.01                                   # empty at x*, lasting at -0.01 rad/s
    assert not lasts(lo) and lasts(hi)
    for _ in range(30):
        lo, hi = (lo, (lo + hi) / 2) if lasts((lo + hi) / 2) else ((lo + hi) / 2, hi)
    x = star.fixed_point.copy()
    x[nq] -= hi + 2e-6
    A = cyc.linearise(x).A
    J = finite_difference_jacobian(cyc, x, 1e-5)
    assert np.abs(J - A).max() < 1e-6 * np.abs(A).max()
    J, steps = finite_difference_jacobian(cyc, x, 1e-5, return_steps=True)
    assert steps[nq] == pytest.approx(1e-6, rel=1e-12) and steps.max() == 1e-5
    x[nq] = star.fixed_point[nq] - hi                    # on the edge: within 1e-9 of it
    with pytest.raises(HybridCycleError, match="domain 'push-off': x is on its edge"):
        finite_difference_jacobian(cyc, x, 1e-5, shrink=1)


def test_central_differences_keep_to_the_slides_direction(running_cycle15, star, model):
    """A state 2 um (along q1) inside the states whose slide runs x*'s way: past them the
    foot slides the other way (the stance's cone is met on its other side), the same
    sequence of domains and parts, but another piece of P (its curvature jumps there).
    A step of 1e-5 on q1 crosses it and its difference is off by the jump; the column's
    step shrinks until both sides slide x's way, and agrees with the exact Jacobian."""
    cyc = running_cycle15
    sl = cyc.kinds.index("slide")

    def direction(s):
        x = star.fixed_point.copy()
        x[0] -= s
        return cyc.stride(x).passes[sl].parameters[-2]

    lo, hi = 1e-5, 1e-4                          # x*'s way at -1e-5 on q1, the other at -1e-4
    way = direction(0.0)
    assert direction(lo) == way and direction(hi) == -way
    for _ in range(30):
        lo, hi = (lo, (lo + hi) / 2) if direction((lo + hi) / 2) != way else ((lo + hi) / 2, hi)
    x = star.fixed_point.copy()
    x[0] -= hi - 2e-6
    A = cyc.linearise(x).A
    J, steps = finite_difference_jacobian(cyc, x, 1e-5, return_steps=True)
    assert steps[0] == pytest.approx(1e-6, rel=1e-12)
    for s in (1, -1):
        y = x.copy()
        y[0] += s * steps[0]
        assert cyc.stride(y).passes[sl].parameters[-2] == way
    assert np.abs(J[:, 0] - A[:, 0]).max() < 3e-8 * np.abs(A).max()
