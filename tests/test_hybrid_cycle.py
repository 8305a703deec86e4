"""The stride map over a cycle of domains (analysis.stability.hybrid_cycle).

Walking is the cycle of one domain: its stride map must be the step map's S, value and
Jacobian, to round-off, for both controllers, and so have the restricted Poincaré map's
eigenvalues.  Stance -> flight -> stance of RABBIT under a PD law exercises resets that
change the state's dimension and a second guard: the Jacobian against central
differences, the centre of mass ballistic and the angular momentum about it constant in
flight.  Errors name the domain in one line.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from analysis import poincare_map
from analysis.design import ROBUST_GAIT
from analysis.stability import (Domain, HybridCycle, HybridCycleError,
                                finite_difference_jacobian, stance_flight_cycle, step_map,
                                vc_eigenvalue, walking_cycle)
from biped_casadi import SimulationOptions, TimeVaryingController, VirtualConstraintController
from biped_casadi.model import flight_model
from biped_casadi.simulation import directions
from gait_opt import GaitOptions, optimize_gait

#: the step map's own tests' design and options (tests/test_terrain.py)
M1, OPTIONS, GROUND = np.array([-10, 7.5, 10, -5.0]), \
    SimulationOptions(steps=1, rk4_steps=400, ground_tolerance=1e-4), 0.002
#: the robust design of the reproduction (README), as in tests/test_terrain.py
M1R, REJOIN = np.array([-8.2618, 2.5374, 0.0034, 8.5090]), 0.75


def _controller(gait, kind):
    return TimeVaryingController(gait, M1) if kind == "tv" else VirtualConstraintController(gait)


@pytest.fixture(scope="module")
def walking(gait):
    """The walking cycle and the step map of each controller, built once."""
    built = {}

    def get(kind):
        if kind not in built:
            c = _controller(gait, kind)
            built[kind] = walking_cycle(c, OPTIONS, ground=GROUND), step_map(c, OPTIONS)
        return built[kind]
    return get


# ------------------------------------------------------------------ walking
@pytest.mark.parametrize("kind", ["tv", pytest.param("vc", marks=pytest.mark.slow)])
def test_walking_is_the_one_domain_cycle(model, gait, walking, kind):
    """Same next state, step time and Jacobian A as StepMap (ground height and state off
    the flat orbit, as step_map's own test), with and without derivatives."""
    cycle, sm = walking(kind)
    assert len(cycle.domains) == 1 and cycle.n == 2 * model.nq
    s = np.r_[gait.q(0.0), gait.dq(0.0)] + 1e-4 * directions(1, model.nq, seed=3)[0]
    ref = sm.linearise(s, h=GROUND)
    lin = cycle.linearise(s)
    assert np.max(np.abs(lin.next_state - sm.step(s, GROUND).next_state)) < 1e-12
    assert abs(lin.durations[0] - ref.step_time) < 1e-12
    assert np.max(np.abs(lin.A - ref.A)) < 1e-12 * np.max(np.abs(ref.A))
    assert np.max(np.abs(lin.duration_gradients[0] - ref.C[0])) < 1e-12 * np.max(np.abs(ref.C))
    v = cycle.stride(s)
    assert np.max(np.abs(v.next_state - lin.next_state)) < 1e-12 and v.success
    # the domain's pieces: x- before the impact, the impact's output after it
    ps = lin.passes[0]
    qp, dqp = model.impact(ps.exit_state[:model.nq], ps.exit_state[model.nq:])
    assert np.array_equal(np.r_[np.array(qp).ravel(), np.array(dqp).ravel()], ps.next_state)
    assert abs(float(model.swing_foot(ps.exit_state[:model.nq])[1]) - GROUND) < 1e-14


def test_walking_fixed_point_is_the_step_maps(model, gait, walking):
    """Newton on the cycle from the perturbed start closes the orbit at the ground
    height 2 mm; the step map maps that state to itself as well."""
    cycle, sm = walking("tv")
    s = np.r_[gait.q(0.0), gait.dq(0.0)] + 1e-4 * directions(1, model.nq, seed=3)[0]
    fp = cycle.fixed_point(s)
    assert fp.residual < 1e-11 and fp.spectral_radius < 1
    assert np.max(np.abs(sm.step(fp.state, GROUND).next_state - fp.state)) < 1e-11


@pytest.mark.slow
def test_walking_cycle_eigenvalues_are_the_poincare_maps(model):
    """The eigenvalue comparison of step_map's own test (robust design, 2000 RK4 steps,
    ground 1e-7 off the orbit's last node, rtol 1e-4): the time-varying controller's two
    non-zero eigenvalues are A^z's; virtual constraints' one is vc_map's."""
    g = optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)
    o = SimulationOptions(rk4_steps=2000)
    s = np.r_[g.q(0.0), g.dq(0.0)]
    tv = TimeVaryingController(g, M1R, rejoin=REJOIN)
    lin = walking_cycle(tv, o, ground=1e-7).linearise(s)
    Az = poincare_map(g, rejoin=REJOIN).analyse(M1R)
    ev = np.sort(np.abs(lin.eigenvalues))[::-1]
    assert np.allclose(ev[:2], np.sort(np.abs(Az.eigenvalues))[::-1], rtol=1e-4)
    assert np.all(ev[2:] < 1e-6)
    vc = walking_cycle(VirtualConstraintController(g), o, ground=1e-7).linearise(s)
    ev = np.abs(vc.eigenvalues)
    assert np.isclose(vc.eigenvalues[0].real, vc_eigenvalue(g).eigenvalue, rtol=1e-4)
    assert np.all(ev[1:] < 1e-6)


# ------------------------------------------------------------ stance, flight
@pytest.fixture(scope="module")
def hop(model, gait):
    """RABBIT at 0.6 T of the default gait with the stance knee extending 4 rad/s
    faster: under a PD law holding the joints the normal force reaches zero, the robot
    flies with the stance knee bending 0.3 rad and the swing knee 0.5 rad straighter,
    and lands on the swing foot."""
    q, dq = gait.q(0.6 * gait.T).copy(), gait.dq(0.6 * gait.T).copy()
    dq[1] += 4.0
    cycle = stance_flight_cycle(model, q[1:], q[1:] + np.array([-0.3, 0.0, 0.0, -0.5]))
    x0 = np.r_[q, dq]
    return cycle, x0, cycle.linearise(x0, record=True)


def test_stance_flight_jacobian_against_central_differences(model, hop):
    cycle, x0, lin = hop
    assert [d.name for d in cycle.domains] == ["stance", "flight"]
    assert [ps.next_state.size for ps in lin.passes] == [2 * model.nq + 4, 2 * model.nq]
    assert np.all(lin.durations > 0)
    d = 1e-6
    cols = []
    for e in np.eye(x0.size):
        a, b = cycle.stride(x0 + d * e), cycle.stride(x0 - d * e)
        cols.append(np.r_[a.next_state - b.next_state, a.durations - b.durations] / (2 * d))
    fd = np.array(cols).T
    n = x0.size
    assert np.max(np.abs(fd[:n] - lin.A)) < 1e-6 * np.max(np.abs(lin.A))
    assert np.max(np.abs(fd[n:] - lin.duration_gradients)) < \
        1e-6 * np.max(np.abs(lin.duration_gradients))
    assert np.array_equal(cycle.stride(x0).next_state, lin.next_state)


def test_flight_is_ballistic_and_the_edges_are_the_flight_models(model, hop):
    """Along flight the centre of mass falls at g from its takeoff state and the angular
    momentum about it stays at its takeoff value; the flight starts at ``takeoff`` of the
    stance's end (where Fz = 0) and the stride ends at ``landing_swing`` of the flight's
    end (where the swing foot is on the ground)."""
    fl = flight_model(model)
    cycle, _, lin = hop
    st, fp = lin.passes
    ne = fl.ne
    q, dq = st.exit_state[:model.nq], st.exit_state[model.nq:]
    Fz = float(cycle.domains[0].guard(st.exit_state, st.duration, []))   # takeoff_guard's
    assert abs(Fz) < 1e-9 * model.description.total_mass * model.description.gravity
    qe, dqe = fl.takeoff(q, dq)
    assert np.array_equal(np.r_[np.array(qe).ravel(), np.array(dqe).ravel()], fp.entry)
    t, N = fp.times, fp.nodes
    assert t[-1] == fp.duration and N.shape == (2 * ne, t.size)
    com = np.array([np.array(fl.com(N[:ne, j])).ravel() for j in range(t.size)]).T
    v0 = np.array(fl.com_velocity(N[:ne, 0], N[ne:, 0])).ravel()
    g = model.description.gravity
    ballistic = com[:, :1] + v0[:, None] * t + np.array([[0.0], [-0.5 * g]]) * t ** 2
    assert np.max(np.abs(com - ballistic)) < 1e-9
    L = np.array([float(fl.angular_momentum(N[:ne, j], N[ne:, j], com[:, j]))
                  for j in range(t.size)])
    assert np.max(np.abs(L - L[0])) < 1e-9 * abs(L[0])
    feet = np.array(fl.feet(N[:ne, -1]))
    assert abs(feet[1, 1]) < 1e-12 and np.all(np.array(
        [float(fl.feet(N[:ne, j])[1, 0]) for j in range(1, t.size)]) > 0)
    qp, dqp = fl.landing_swing(N[:ne, -1], N[ne:, -1])[:2]
    assert np.array_equal(np.r_[np.array(qp).ravel(), np.array(dqp).ravel()], lin.next_state)


# ------------------------------------------------------------------ errors
def _ball(name="ball", reset_size=2, t_max=1.0, ceiling=None):
    """A ball falling on the ground: x = (z, v), guard z, reset (z, -v / 2)."""
    X, t, p = ca.SX.sym("X", 2), ca.SX.sym("t"), ca.SX.sym("p", 0)
    f = ca.Function("f", [X, t, p], [ca.vertcat(X[1], -9.81)])
    g = ca.Function("g", [X, t, p], [X[0]])
    x = ca.SX.sym("x", 2)
    r = ca.Function("r", [x], [ca.vertcat(x[0], -0.5 * x[1], ca.SX.zeros(reset_size - 2))])
    c = None if ceiling is None else ca.Function("c", [X, t, p], [ceiling - X[0]])
    return Domain(name, 2, f, g, r, 1e-3, t_max, constraints=c,
                  constraint_names=("below the ceiling",) if c is not None else ())


def test_errors_name_the_domain_in_one_line(model, hop):
    ball = HybridCycle([_ball()])
    v = ball.linearise([1.0, 0.0])
    assert abs(v.durations[0] - np.sqrt(2 / 9.81)) < 1e-12     # RK4 is exact on a parabola
    with pytest.raises(HybridCycleError, match=r"^domain 'ball': guard not crossed going down "
                                               r"within the time limit 0.1 s \(100 RK4 steps"):
        HybridCycle([_ball(t_max=0.1)]).stride([1.0, 0.0])
    with pytest.raises(HybridCycleError, match=r"^domain 'ball': its reset gives 3 numbers, "
                                               r"domain 'ball' takes 2$") as e:
        HybridCycle([_ball(reset_size=3)])
    assert e.value.domain == "ball" and e.value.kind == "dimension"
    with pytest.raises(HybridCycleError, match=r"^domain 'high': below the ceiling violated "
                                               r"at t = 0.\d+ s"):
        HybridCycle([_ball("high", ceiling=1.2)]).stride([1.0, 2.0])
    cycle, x0, _ = hop
    with pytest.raises(HybridCycleError, match=rf"^domain 'stance': its reset gives "
                                               rf"{2 * model.nq + 4} numbers, domain 'stance' "
                                               rf"takes {2 * model.nq}$"):
        HybridCycle(cycle.domains[:1])
    for i, d, msg in ((2, -0.5, r"^domain 'stance': swing foot height violated at t = "),
                      (1, 0.5, r"^domain 'flight': landing normal impulse violated at t = ")):
        with pytest.raises(HybridCycleError, match=msg) as e:
            cycle.stride(x0 + d * np.eye(x0.size)[i])
        assert "\n" not in str(e.value) and e.value.kind == "constraint"
    with pytest.raises(ValueError, match=f"has {2 * model.nq} numbers, got 3"):
        cycle.stride(np.zeros(3))


@pytest.mark.slow
def test_the_how_to_example_runs(model):
    """The stride-map example of docs/howto/running.md, as written there."""
    page = Path(__file__).resolve().parents[1] / "docs" / "howto" / "running.md"
    block = page.read_text().split("## The stride map over a cycle of domains", 1)[1] \
        .split("```python\n", 1)[1].split("```", 1)[0]
    ns = {}
    exec(compile(block, str(page), "exec"), ns)
    n = 2 * model.nq
    assert ns["lin"].A.shape == (n, n) and ns["r"].A.shape == (n, n)
    assert [ps.next_state.size for ps in ns["r"].passes] == [n + 4, n]


# ------------------------------------------------------------------ a clock through the stride
def _clocked_cycle():
    """Two domains of a scalar state.  The first moves at rate 1 from x0 to 1 (it lasts
    1 - x0), the reset takes 1 off; the second moves at the rate given by its parameter
    p = 1 + s, s the time the stride ran before it (a law whose clock runs on through the
    stride), for 0.555 s, and the reset takes 2 off: P(x0) = 0.555 (2 - x0) - 2, with
    dP/dx0 = -0.555 entirely through s (the second domain starts at 0 whatever x0)."""
    X, t, p = ca.SX.sym("X"), ca.SX.sym("t"), ca.SX.sym("p")
    x, s = ca.SX.sym("x"), ca.SX.sym("s")
    e = ca.SX(0, 1)
    first = Domain("first", 1, ca.Function("f0", [X, t, e], [ca.SX(1)]),
                   ca.Function("g0", [X, t, e], [1 - X]),
                   ca.Function("r0", [x], [x - 1]), 0.01, 5.0)
    second = Domain("second", 1, ca.Function("f1", [X, t, p], [p]),
                    ca.Function("g1", [X, t, p], [0.555 - t]),
                    ca.Function("r1", [x], [x - 2]), 0.01, 5.0,
                    start=ca.Function("s1", [x, s], [x, 1 + s]))
    return HybridCycle([first, second])


def test_a_domain_entry_sees_the_time_the_stride_ran():
    """``start(x, s)`` gets the previous domains' durations; the Jacobian carries s."""
    cyc = _clocked_cycle()
    x0 = 0.3
    lin = cyc.linearise([x0])
    first, second = lin.passes
    assert first.duration == pytest.approx(1 - x0, abs=1e-12)
    assert second.parameters[0] == pytest.approx(1 + first.duration, abs=1e-12)
    assert second.duration == pytest.approx(0.555, abs=1e-12)
    assert lin.next_state[0] == pytest.approx(0.555 * (2 - x0) - 2, abs=1e-12)
    assert lin.A[0, 0] == pytest.approx(-0.555, rel=1e-10)
    assert lin.duration_gradients[0, 0] == pytest.approx(-1.0, rel=1e-12)
    assert abs(lin.duration_gradients[1, 0]) < 1e-12
    assert cyc.stride([x0]).next_state[0] == lin.next_state[0]


def _optional_cycle(clock_from=1):
    """First: dX/dt = 1 for 1 s.  Middle (may be empty): dX/dt = -1 down to X = 1.5, so
    empty for x0 <= 0.5 and x0 - 0.5 s long above.  Last: dX/dt = p for 0.2 s, p = s the
    time since the middle's entry (``clock_from=1``), then 1 off:
    P(x0) = x0 (empty middle) or 0.5 + 0.2 (x0 - 0.5)."""
    X, t, p = ca.SX.sym("X"), ca.SX.sym("t"), ca.SX.sym("p")
    x, s = ca.SX.sym("x"), ca.SX.sym("s")
    e = ca.SX(0, 1)
    ident = ca.Function("r", [x], [x])
    first = Domain("first", 1, ca.Function("f0", [X, t, e], [ca.SX(1)]),
                   ca.Function("g0", [X, t, e], [1 - t]), ident, 0.01, 5.0)
    middle = Domain("middle", 1, ca.Function("f1", [X, t, e], [ca.SX(-1)]),
                    ca.Function("g1", [X, t, e], [X - 1.5]), ident, 0.01, 5.0,
                    may_be_empty=True)
    last = Domain("last", 1, ca.Function("f2", [X, t, p], [p]),
                  ca.Function("g2", [X, t, p], [0.2 - t]),
                  ca.Function("r2", [x], [x - 1]), 0.01, 5.0,
                  start=ca.Function("s2", [x, s], [x, s]), clock_from=clock_from)
    return HybridCycle([first, middle, last])


def test_an_empty_domain_and_a_clock_from_a_later_entry():
    """A domain whose guard is <= 0 at entry ends there (duration 0, its reset at the
    entry state); ``clock_from`` counts s from that domain's entry."""
    cyc = _optional_cycle()
    lin = cyc.linearise([0.3], record=True)
    assert lin.durations[1] == 0.0 and lin.passes[1].times.tolist() == [0.0]
    assert lin.passes[2].parameters[0] == 0.0
    assert lin.next_state[0] == pytest.approx(0.3, abs=1e-12)
    assert lin.A[0, 0] == pytest.approx(1.0, rel=1e-12)
    lin = cyc.linearise([0.8])
    assert lin.durations[1] == pytest.approx(0.3, abs=1e-12)
    assert lin.passes[2].parameters[0] == pytest.approx(0.3, abs=1e-12)
    assert lin.next_state[0] == pytest.approx(0.56, abs=1e-12)
    assert lin.A[0, 0] == pytest.approx(0.2, rel=1e-9)
    # counted from the stride's start instead, the last domain sees 1.3 s
    assert _optional_cycle(0).stride([0.8]).passes[2].parameters[0] == pytest.approx(1.3)
    with pytest.raises(HybridCycleError, match="domain 'last': clock_from must be a "
                                               "domain's index from 0 to 2, got 3"):
        _optional_cycle(3)


def test_a_start_of_two_inputs_takes_one_number_of_time():
    x, s = ca.SX.sym("x"), ca.SX.sym("s", 2)
    X, t = ca.SX.sym("X"), ca.SX.sym("t")
    with pytest.raises(HybridCycleError, match="domain 'd': start takes x, or x and"):
        Domain("d", 1, ca.Function("f", [X, t, ca.SX(0, 1)], [ca.SX(1)]),
               ca.Function("g", [X, t, ca.SX(0, 1)], [1 - X]), ca.Function("r", [x], [x]),
               0.01, 1.0, start=ca.Function("s", [x, s], [x, ca.SX(0, 1)]))


# ------------------------------------------------------------------ between the nodes
def _cubic(dense=True, on_guard=False):
    """A height on the cubic z0 + v0 t + a0 t^2 / 2 + j t^3 / 6 (x = (z, v, a, j), RK4
    steps of 0.02 s, exact on it): a constraint of a domain that ends at t = 0.09 s, or
    the domain's guard."""
    X, t, p = ca.SX.sym("X", 4), ca.SX.sym("t"), ca.SX.sym("p", 0)
    f = ca.Function("f", [X, t, p], [ca.vertcat(X[1], X[2], X[3], 0.0)])
    z = ca.Function("z", [X, t, p], [X[0]])
    x = ca.SX.sym("x", 4)
    r = ca.Function("r", [x], [x])
    if on_guard:
        return HybridCycle([Domain("dip", 4, f, z, r, 0.02, 0.2, guard_name="height",
                                   dense_guard=dense)])
    clock = ca.Function("clock", [X, t, p], [0.09 - t])
    return HybridCycle([Domain("dip", 4, f, clock, r, 0.02, 0.2, constraints=z,
                               constraint_names=("height",), tolerance=1e-12,
                               dense_constraints=("height",) if dense else ())])


def test_a_constraint_below_zero_between_two_nodes_stops_the_domain():
    """z = 1e-4 - 0.1 t + 5 t^2 is 4e-4 below zero at t = 0.01 s and above it at every
    node (0, 0.02, ...): checked at the nodes only the domain passes; checked between
    them it stops there.  From rest (z = 0, v = 0: the rate vanishes at the node, as a
    foot's at takeoff) z = -5 t^2 + 2000 t^3 / 6 dips to -1/6000 at t = 0.01 s and is
    back above 0 at the next node."""
    x = [1e-4, -0.1, 10.0, 0.0]
    plain = _cubic(dense=False).stride(x, record=True).passes[0]
    assert np.all(plain.nodes[0] > 0) and plain.dips == []
    with pytest.raises(HybridCycleError, match=r"^domain 'dip': height violated at t = 0.01 s "
                                               r"\(-0.0004 < 0, between two RK4 nodes\)$") as e:
        _cubic().stride(x)
    assert e.value.kind == "constraint"
    with pytest.raises(HybridCycleError, match=r"^domain 'dip': height violated at t = 0.01 s "
                                               r"\(-0.000167 < 0, between two RK4 nodes\)$"):
        _cubic().stride([0.0, 0.0, -10.0, 2000.0])


def test_a_minimum_above_zero_is_recorded():
    """z = 1e-3 - 0.1 t + 5 t^2: its minimum 5e-4 at t = 0.01 s, between two nodes."""
    ps = _cubic().linearise([1e-3, -0.1, 10.0, 0.0], record=True).passes[0]
    (t, name, v), = ps.dips
    assert name == "height" and t == pytest.approx(0.01, abs=1e-12)
    assert v == pytest.approx(5e-4, abs=1e-15)
    assert np.min(ps.nodes[0]) > v + 1e-4             # the nodes are well above it


def test_a_dip_after_the_first_step_is_screened_in_and_one_far_above_out():
    """z = zmin + 5 (t - 0.05)^2, its minimum in the third RK4 step (0.04 to 0.06 s), the
    nodes there 5e-4 above it.  With zmin = -1e-4 the nodes are all above zero and
    the domain stops at t = 0.05 s; with zmin = 1e-2 the nodes' second differences
    (c'' h^2 = 4e-3) bound the dip well above zero and no minimum is searched."""
    def start(zmin):
        return [zmin + 5 * 0.05 ** 2, -0.5, 10.0, 0.0]

    plain = _cubic(dense=False).stride(start(-1e-4), record=True).passes[0]
    assert np.all(plain.nodes[0] > 0) and plain.dips == []
    with pytest.raises(HybridCycleError, match=r"^domain 'dip': height violated at t = 0.05 s "
                                               r"\(-0.0001 < 0, between two RK4 nodes\)$"):
        _cubic().stride(start(-1e-4))
    assert _cubic().stride(start(1e-2), record=True).passes[0].dips == []


def test_a_guard_that_dips_and_rises_within_a_step_is_crossed():
    """The guard z = 1e-4 - 0.1 t + 5 t^2 is below zero from t = 0.00106 s to 0.0189 s,
    inside the first RK4 step: the nodes never see the crossing; between them it is the
    first root, and the duration's gradient is the implicit function's,
    dt/d(z0, v0) = -(1, t) / (v0 + a t)."""
    x = [1e-4, -0.1, 10.0, 0.0]
    with pytest.raises(HybridCycleError, match="not crossed going down") as e:
        _cubic(dense=False, on_guard=True).stride(x)
    assert e.value.kind == "no_crossing"
    lin = _cubic(on_guard=True).linearise(x)
    root = (0.1 - np.sqrt(0.1 ** 2 - 2 * 10.0 * 1e-4)) / 10.0
    assert lin.durations[0] == pytest.approx(root, abs=1e-15)
    slope = -0.1 + 10.0 * root
    assert np.allclose(lin.duration_gradients[0, :2], [-1 / slope, -root / slope], rtol=1e-9)
    assert abs(lin.next_state[0]) < 1e-15


# ------------------------------------------------------------------ a guard of parts
def _parted_cycle(skip=(1, 0), wall_reset=None):
    """First: dX/dt = 1, a guard of two parts, 'wall' 2 - X - t (reset x -> -x, the next
    domain skipped) and 'clock' 1.5 - t (reset the identity), empty where a part is <= 0
    at entry.  Middle: dX/dt = 2 for 0.25 s.  Last: 0.1 s at rest, then x - 1.  The wall
    fires first for x0 > -1, at t = 1 - x0 / 2, x = 1 + x0 / 2: P = -2 - x0 / 2; the
    clock for x0 < -1: P = x0 + 1; the wall at entry for x0 >= 2: P = -x0 - 1."""
    X, t, e = ca.SX.sym("X"), ca.SX.sym("t"), ca.SX(0, 1)
    x = ca.SX.sym("x")
    ident = ca.Function("r", [x], [x])
    flip = ca.Function("flip", [x], [-x]) if wall_reset is None else wall_reset
    first = Domain("first", 1, ca.Function("f0", [X, t, e], [ca.SX(1)]),
                   ca.Function("g0", [X, t, e], [ca.vertcat(2 - X - t, 1.5 - t)]),
                   (flip, ident), 0.01, 5.0, guard_parts=("wall", "clock"), skip=skip,
                   may_be_empty=True)
    middle = Domain("middle", 1, ca.Function("f1", [X, t, e], [ca.SX(2)]),
                    ca.Function("g1", [X, t, e], [0.25 - t]), ident, 0.01, 5.0)
    last = Domain("last", 1, ca.Function("f2", [X, t, e], [ca.SX(0)]),
                  ca.Function("g2", [X, t, e], [0.1 - t]), ca.Function("r2", [x], [x - 1]),
                  0.01, 5.0)
    return HybridCycle([first, middle, last])


def test_the_part_of_the_guard_that_fires_chooses_the_reset_and_the_skipped_domains():
    """The part that reaches 0 first ends the domain, is named in its pass, and chooses
    the reset and whether the middle domain runs; the Jacobian is that part's (its
    saltation term), also where a part ends the domain at its entry."""
    cyc = _parted_cycle()
    lin = cyc.linearise([0.4], record=True)
    assert [ps.part for ps in lin.passes] == ["wall", None, "guard"]
    assert lin.durations[0] == pytest.approx(0.8, abs=1e-14)
    assert lin.durations[1] == 0.0 and lin.passes[1].times.tolist() == [0.0]
    assert lin.next_state[0] == pytest.approx(-2.2, abs=1e-13)
    assert lin.A[0, 0] == pytest.approx(-0.5, abs=1e-12)
    assert lin.duration_gradients[0, 0] == pytest.approx(-0.5, abs=1e-12)
    lin = cyc.linearise([-1.6])
    assert [ps.part for ps in lin.passes[:2]] == ["clock", "guard"]
    assert lin.durations.tolist() == pytest.approx([1.5, 0.25, 0.1], abs=1e-13)
    assert lin.next_state[0] == pytest.approx(-0.6, abs=1e-13)
    assert lin.A[0, 0] == pytest.approx(1.0, abs=1e-12)
    lin = cyc.linearise([2.5])
    assert [ps.part for ps in lin.passes[:2]] == ["wall", None] and lin.durations[0] == 0.0
    assert lin.next_state[0] == pytest.approx(-3.5, abs=1e-13)
    assert lin.A[0, 0] == pytest.approx(-1.0, abs=1e-12)
    for x0 in (0.4, -1.6):                         # central differences, either part
        d = 1e-6
        fd = (cyc.stride([x0 + d]).next_state[0] - cyc.stride([x0 - d]).next_state[0]) / (2 * d)
        assert fd == pytest.approx(cyc.linearise([x0]).A[0, 0], abs=1e-8)


def test_a_guard_of_parts_is_checked_when_built():
    x = ca.SX.sym("x")
    with pytest.raises(HybridCycleError, match=r"^domain 'first': its part 'wall' skips 3 "
                                               r"domains, past the cycle's end$"):
        _parted_cycle(skip=(3, 0))
    with pytest.raises(HybridCycleError, match=r"^domain 'first': skip must be 2 whole "):
        _parted_cycle(skip=(1,))
    with pytest.raises(HybridCycleError, match=r"^domain 'first': the parts' resets give "):
        _parted_cycle(wall_reset=ca.Function("two", [x], [ca.vertcat(x, x)]))
    d = _parted_cycle().domains
    before = Domain("before", 1, d[1].vector_field, d[1].guard, d[1].reset, 0.01, 5.0,
                    skip=(1,))
    with pytest.raises(HybridCycleError, match=r"^domain 'before': its part 'guard' skips "
                                               r"domain 'first', whose reset depends on its "
                                               r"part$"):
        HybridCycle([before, d[0], d[2]])
    with pytest.raises(HybridCycleError, match=r"^domain 'd': reset must be a "
                                               r"casadi.Function or one per part"):
        Domain("d", 1, d[0].vector_field, d[0].guard, (d[1].reset,), 0.01, 5.0)


def _signed_cycle(**kw):
    """One domain of a scalar state: its direction p = sign(x) chosen at entry, dx/dt =
    p x for 0.555 s, P(x) = x exp(0.555 p): continuous at 0, its slope exp(0.555) on one
    side and exp(-0.555) on the other."""
    X, t, p, x = ca.SX.sym("X"), ca.SX.sym("t"), ca.SX.sym("p"), ca.SX.sym("x")
    return HybridCycle([Domain("move", 1, ca.Function("f", [X, t, p], [p * X]),
                               ca.Function("g", [X, t, p], [0.555 - t]),
                               ca.Function("r", [x], [x]), 0.01, 5.0,
                               start=ca.Function("s", [x], [x, ca.sign(x)]), **kw)])


def test_central_differences_keep_to_a_domains_discrete_choice():
    """2e-6 from where the direction changes, a step of 1e-5 mixes the two slopes; with
    the direction a discrete parameter it shrinks to 1e-6 and gives x's slope, and a
    point on the change itself is refused naming the choice."""
    x = np.array([2e-6])
    plain = _signed_cycle()
    J, steps = finite_difference_jacobian(plain, x, 1e-5, return_steps=True)
    assert steps[0] == 1e-5 and abs(J[0, 0] - np.exp(0.555)) > 0.1       # the two mixed
    cyc = _signed_cycle(discrete_parameters=(0,))
    A = cyc.linearise(x).A
    assert A[0, 0] == pytest.approx(np.exp(0.555), rel=1e-9)
    J, steps = finite_difference_jacobian(cyc, x, 1e-5, return_steps=True)
    assert steps[0] == pytest.approx(1e-6, rel=1e-12)
    assert J[0, 0] == pytest.approx(A[0, 0], rel=1e-8)
    with pytest.raises(HybridCycleError, match=r"^domain 'move': x is on its edge: column 0"
                                               r".*\(lasting, guard, discrete parameters "
                                               r"\(-1\.0,\)\)$"):
        finite_difference_jacobian(cyc, np.array([1e-12]), 1e-5, shrink=1)
    for bad in ((1,), (True,), (0.0,)):
        with pytest.raises(HybridCycleError, match=r"^domain 'move': discrete_parameters "
                                                   r"must be places in the domain's 1 "):
            _signed_cycle(discrete_parameters=bad)
