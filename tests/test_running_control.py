"""The tracking controller of a running gait (biped_casadi.control.running) and the exact
stability of its closed loop (analysis.stability.running_cycle, biped running
--stability).

RABBIT's 1.5 m/s gait is solved once per session on the default grid (about 10 s) and
its stride map built once (about 5 s); the gains change without a rebuild
(RunningCycle.retuned).  Every figure is compared with another computation: the
reference with the gait's own interpolant and the dynamics at the points, the AD
Jacobian with central differences, the perturbed run's contraction with the spectral
radius, the command line's numbers with the library's.
"""
from __future__ import annotations

import copy
import dataclasses
import json
import math
import re

import casadi as ca
import numpy as np
import pytest

from biped_casadi.control.running import RunningController, phase_derivatives
from biped_casadi.numerics import rk4_step
from gait_opt.running import hermite_simpson
from analysis.stability.hybrid_cycle import HybridCycle, HybridCycleError
from analysis.stability.running_cycle import (finite_difference_jacobian, running_cycle,
                                              running_stability, simulate_running)

STABLE_M1 = (0.0, 0.95, 0.95, 0.0)     # the design of docs/howto/running.md
KP, KD = 400.0, 30.0


@pytest.fixture(scope="session")
def run_gait(running_gait):
    return running_gait


@pytest.fixture(scope="session")
def cycle(running_cycle15):
    c = running_cycle15.controller
    assert np.all(c.Kp == KP) and np.all(c.Kd == KD)
    np.testing.assert_array_equal(c.M1, STABLE_M1)
    return running_cycle15


@pytest.fixture(scope="session")
def stable(cycle):
    return running_stability(cycle)


@pytest.fixture(scope="session")
def pinned(cycle):
    """The model before sliding: the stance foot pinned to its takeoff, the cone with
    its slack (``sliding=False``)."""
    return running_cycle(cycle.controller, sliding=False)


@pytest.fixture(scope="session")
def pinned_stable(pinned):
    return running_stability(pinned)


@pytest.fixture(scope="session")
def gait_file(run_gait, tmp_path_factory):
    return str(run_gait.save(tmp_path_factory.mktemp("run") / "run15.json"))


# ------------------------------------------------------------------ the reference
@pytest.mark.parametrize("phase", ["stance", "flight"])
def test_reference_reproduces_the_collocation(model, cycle, run_gait, phase):
    c = cycle.controller
    ref = getattr(c, phase)
    X, U = getattr(run_gait, f"x_{phase}"), getattr(run_gait, f"u_{phase}")
    F = phase_derivatives(model, phase, X, U)
    ne, nq = X.shape[0] // 2, model.nq
    q, dq, ddq, u = ref.sample(ref.t_nodes)
    # every point, ends and midpoints: states, accelerations f(x, u) and torques
    assert np.abs(q - X[:nq]).max() < 1e-9
    assert np.abs(dq - X[ne:ne + nq]).max() < 1e-9
    assert np.abs(ddq - F[ne:ne + nq]).max() < 1e-8
    assert np.abs(u - U).max() < 1e-9
    # between the points: the gait's own Hermite-Simpson interpolant (another code)
    t = np.linspace(0, ref.duration, 20 * ref.n_intervals + 1)
    x_hs, u_hs = hermite_simpson(ref.t_nodes, X, F, U, t)
    q, dq, _, u = ref.sample(t)
    assert np.abs(q - x_hs[:nq]).max() < 1e-10
    assert np.abs(dq - x_hs[ne:ne + nq]).max() < 1e-10
    assert np.abs(u - u_hs).max() < 1e-9
    # past the end: the last interval's polynomials go on, continuously
    q_end = np.array(ref.function(ref.duration)[0]).ravel()
    q_past = np.array(ref.function(ref.duration + 1e-7)[0]).ravel()
    assert 0 < np.abs(q_past - q_end).max() < 1e-5


@pytest.mark.parametrize("law", ["pd", "computed_torque"])
def test_on_the_reference_the_law_gives_the_gaits_torques(model, cycle, run_gait, law):
    c = cycle.controller
    if law != c.law:
        c = RunningController(model, run_gait, 900.0, 60.0, M1=STABLE_M1, law=law)
    for phase in ("stance", "flight"):
        X, U = getattr(run_gait, f"x_{phase}"), getattr(run_gait, f"u_{phase}")
        ref, f = getattr(c, phase), getattr(c, f"{phase}_law")
        n = X.shape[0] // 2
        u = np.array(f.map(X.shape[1])(X[:n], X[n:], ref.t_nodes[None, :]))
        # the reference meets the points to the NLP's tolerance (its Hermite-Simpson
        # defects, 1e-10 rad/s here): the gains (and the computed torque's inverse
        # dynamics, entries of a few kg m^2) carry that into the torque
        q, dq, _, _ = ref.sample(ref.t_nodes)
        off = (np.abs(c.Kp).max() * np.abs(q - X[:model.nq]).max()
               + np.abs(c.Kd).max() * np.abs(dq - X[n:n + model.nq]).max())
        assert np.abs(u - U).max() < 1e-8 + 10 * off, (law, phase)
        # and off it, the law corrects: a joint behind its reference gets more torque
        x = X[:, 3].copy()
        x[2] -= 0.01
        du = np.array(f(x[:n], x[n:], ref.t_nodes[3])).ravel() - U[:, 3]
        assert du[1] > 0


def test_gains_are_checked(model, run_gait):
    for kw, word in ((dict(Kp=-1.0), "Kp"), (dict(Kd=np.nan), "Kd"), (dict(M1=[1, 2]), "M1"),
                     (dict(law="lqr"), "law"), (dict(Kp=[1, 2, 3]), "Kp")):
        with pytest.raises(ValueError, match=word):
            RunningController(model, run_gait, **kw)
    with pytest.raises(TypeError, match="running gait"):
        RunningController(model, object())


def _edited(gait, **fields):
    return dataclasses.replace(gait, **fields)


@pytest.mark.parametrize("edit, error, words", [
    (lambda g: _edited(g, x_stance=np.where(np.eye(*g.x_stance.shape) > 0, np.nan,
                                            g.x_stance)), ValueError, "gait.x_stance has non-finite"),
    (lambda g: _edited(g, u_flight=g.u_flight[:2]), ValueError, "gait.u_flight has shape"),
    (lambda g: _edited(g, x_flight=g.x_flight[:, :4]), ValueError, "gait.x_flight must be a table"),
    (lambda g: _edited(g, T_stance="0.3"), ValueError, "gait.T_stance must be a positive"),
    (lambda g: _edited(g, T_flight=float("inf")), ValueError, "gait.T_flight"),
])
def test_controller_refuses_a_gait_no_solve_writes(model, run_gait, edit, error, words):
    """NaN states built a controller (its runs said 'state not finite'); rows of another
    robot failed inside CasADi; a duration given as text was converted."""
    with pytest.raises(error, match=words):
        RunningController(model, edit(run_gait))


@pytest.mark.parametrize("kw, error, words", [
    (dict(Kp="high"), ValueError, "Kp must be numbers"), (dict(M1="abc"), ValueError, "M1"),
    (dict(M1=[0, 0, 1e300, 0]), ValueError, "M1: components must lie within"),
    (dict(torque_limit="a"), ValueError, "torque_limit")])
def test_controller_arguments_are_named(model, run_gait, kw, error, words):
    with pytest.raises(error, match=words):
        RunningController(model, run_gait, **kw)


def test_controller_of_another_robot_is_refused(model3, run_gait):
    with pytest.raises(ValueError, match=r"x_stance has shape .* for three_link"):
        RunningController(model3, run_gait)
    with pytest.raises(TypeError, match="model must be a robot model"):
        RunningController(None, run_gait)


def test_cycle_arguments_are_named(cycle):
    """Each of these ran (a negative slack or time limit, a NaN tolerance, a start of
    the wrong size broadcast by numpy, a NaN fixed point gave NaN deviations, -1
    strides an empty 'ok' run) or failed without naming the argument."""
    c, n = cycle.controller, cycle.n
    x = np.asarray(cycle.controller.gait.x_stance)[:, 0]
    for call, error, words in (
            (lambda: running_cycle(cycle.controller.gait), TypeError, "controller must be"),
            (lambda: running_cycle(c, mu="a"), ValueError, "mu must be"),
            (lambda: running_cycle(c, friction_slack=-5.0), ValueError, "friction_slack"),
            (lambda: running_cycle(c, time_limits=-1.0), ValueError, "time_limits"),
            (lambda: running_cycle(c, tolerance=float("nan")), ValueError, "tolerance"),
            (lambda: running_cycle(c, flight_clock="landing"), ValueError, "flight_clock"),
            (lambda: running_stability(None), TypeError, "cycle must be a running cycle"),
            (lambda: running_stability(cycle, x0=np.full(n, np.nan)), ValueError, "x0"),
            (lambda: running_stability(cycle, tol=-1.0), ValueError, "tol"),
            (lambda: running_stability(cycle, max_iter=2.5), ValueError, "max_iter"),
            (lambda: simulate_running(cycle, x, x[:3], 2), ValueError, "start must be"),
            (lambda: simulate_running(cycle, np.full(n, np.nan), x, 2), ValueError, "x_star"),
            (lambda: simulate_running(cycle, x, x, -1), ValueError, "strides"),
            (lambda: simulate_running(cycle, x, x, 2.5), ValueError, "strides")):
        with pytest.raises(error, match=words):
            call()


# ------------------------------------------------------------------ the stride map
def test_fixed_point_near_the_collocation(stable, run_gait):
    assert stable.status == "stable", stable.message
    assert stable.residual < 1e-10
    # the closed loop's orbit (RK4 of the exact dynamics) is not the collocated one, but
    # close: the transcription's and the integration's errors
    assert 0 < stable.distance < 1e-3
    assert np.allclose(stable.durations, [run_gait.T_stance, run_gait.T_flight], atol=1e-3)
    assert stable.spectral_radius == pytest.approx(np.abs(np.linalg.eigvals(stable.A)).max())
    assert stable.spectral_radius < 1 and stable.stable


def test_exact_jacobian_matches_central_differences(cycle, stable):
    J = finite_difference_jacobian(cycle, stable.fixed_point, 1e-6)
    rel = np.abs(J - stable.A).max() / np.abs(stable.A).max()
    assert rel < 1e-6
    assert np.abs(stable.A).max() > 1e-2          # not a trivial comparison


def test_retuned_cycle_is_the_cycle_built_at_those_gains(model, run_gait, cycle, stable):
    x = stable.fixed_point
    fresh = running_cycle(RunningController(model, run_gait, 700.0, 45.0, M1=(0, 1, 0.5, 0)))
    re = cycle.retuned(700.0, 45.0, (0, 1, 0.5, 0))
    a, b = fresh.linearise(x), re.linearise(x)
    assert np.array_equal(a.next_state, b.next_state) and np.array_equal(a.A, b.A)
    assert not np.array_equal(a.A, stable.A)
    assert np.array_equal(cycle.controller.M1, STABLE_M1)       # the original is unchanged


@pytest.mark.parametrize("gains", [dict(Kp=1e300), dict(Kd=1e5)])
def test_retuned_refuses_the_gains_running_cycle_refuses(model, run_gait, cycle, gains):
    """A retuned cycle is checked at the cycle's RK4 steps as a built one: the same
    refusal, and the largest gain it names is accepted."""
    with pytest.raises(ValueError, match="RK4 step") as built:
        running_cycle(cycle.controller.with_gains(**gains))
    with pytest.raises(ValueError) as retuned:
        cycle.retuned(**gains)
    assert str(retuned.value) == str(built.value)
    (name, top), = re.findall(r"(Kp|Kd) at most ([0-9.e+]+) ", str(built.value))
    cycle.retuned(**{name: 0.99 * float(top)})


def test_perturbed_run_converges_at_the_spectral_radius(cycle, stable, model):
    x = stable.fixed_point.copy()
    x[model.nq:] += 1e-2
    run = simulate_running(cycle, stable.fixed_point, x, 20)
    assert run.status == "ok", run.message
    d = run.deviations
    assert d.size == 21 and d[-1] < 1e-4 * d[0]
    # the first stride moves the perturbation onto the map's modes; after it, the
    # geometric mean of the per-stride contraction is the spectral radius's
    rate = (d[-1] / d[1]) ** (1 / 19)
    assert abs(np.log(rate / stable.spectral_radius)) < np.log(1.3)
    c = cycle.controller
    for s in run.strides:
        assert s.fz_min >= -1e-9
        assert s.friction_excess_max <= cycle.friction_slack + 1e-9   # 0: it slides
        assert s.torque_max <= c.torque_limit
        assert s.landing_impulse_ratio <= cycle.mu
        assert s.swing_min >= 0 and s.other_foot_min >= -1e-9


def test_the_pushing_foot_is_checked_between_the_nodes(pinned, pinned_stable, model):
    """0.02 rad/s less on dq1 at the fixed point: after the takeoff the foot that pushed
    off goes below the ground and is back above it at the first flight node (1.29 ms).
    The same cycle checked at its nodes only runs the stride; the RK4 step from the
    takeoff state, sampled at 400 lengths, has the foot below the ground where and as
    deep as the cycle says."""
    cycle, stable = pinned, pinned_stable
    x = stable.fixed_point.copy()
    x[model.nq] -= 0.02
    with pytest.raises(HybridCycleError, match=r"^domain 'flight': other foot height "
                                               r"violated at t = \S+ s \(\S+ < 0, between "
                                               r"two RK4 nodes\)$") as e:
        cycle.stride(x)
    t_dip, z_dip = (float(v) for v in re.search(r"t = (\S+) s \((\S+) <", str(e.value)).groups())
    _, _, fl = _at_nodes(cycle).stride(x, record=True).passes
    c, d = cycle.controller, cycle.domains[2]
    ne = c.fl.ne
    z_nodes = np.array(c.fl.feet.map(fl.times.size)(fl.nodes[:ne]))[1, 0::2]
    assert np.all(z_nodes >= -d.tolerance) and 0 < t_dip < fl.times[1]
    etas = np.linspace(0, fl.times[1], 401)
    z = [float(c.fl.feet(np.array(rk4_step(
        lambda X, stage: d.vector_field(X, stage * eta, fl.parameters), fl.entry, eta))
        .ravel()[:ne])[1, 0]) for eta in etas]
    assert min(z) < -d.tolerance
    assert min(z) == pytest.approx(z_dip, rel=1e-2)
    assert abs(etas[int(np.argmin(z))] - t_dip) <= etas[1]


def _at_nodes(cycle):
    """The cycle checked at its RK4 nodes only."""
    at_nodes = copy.copy(cycle)
    at_nodes.domains = [dataclasses.replace(d, dense_constraints=(), dense_guard=False)
                        for d in cycle.domains]
    return at_nodes


def test_the_friction_cone_is_checked_between_the_nodes(pinned, run_gait):
    """0.05 rad/s more on dq1 at the collocated landing state: the stance's largest
    (Fx - slack) / Fz, sampled at 16 lengths of the RK4 steps around its largest node,
    is between two nodes.  With mu halfway between that and the nodes' largest, the
    cycle checked at its nodes passes the stance (and stops at the landing, whose impulse
    is outside that narrower cone); checked between them it stops in that step of the
    stance at the cone.  mu only enters the constraints: the motion is the same."""
    cycle = pinned
    x = np.asarray(run_gait.x_stance, float)[:, 0].copy()
    x[cycle.n // 2] += 0.05
    st = cycle.stride(x, record=True).passes[0]
    d, mu = cycle.domains[0], cycle.mu
    assert d.constraint_names[:2] == ("stance normal force", "friction cone (Fx <= mu Fz)")

    def ratio(X, t):
        Fz, cone = np.array(d.constraints(X, t, st.parameters)).ravel()[:2]
        return (mu * Fz - cone) / Fz                   # (Fx - slack) / Fz

    at_nodes = [ratio(st.nodes[:, k], t) for k, t in enumerate(st.times[:-1])]
    k = int(np.argmax(at_nodes))
    samples = []
    for i in (k - 1, k):
        X, t = st.nodes[:, i], st.times[i]
        for eta in np.linspace(0, d.h, 17)[1:-1]:
            Xe = np.array(rk4_step(lambda Y, stage: d.vector_field(Y, t + stage * eta,
                                                                    st.parameters),
                                   X, eta)).ravel()
            samples.append((ratio(Xe, t + eta), t + eta))
    r_between, t_between = max(samples)
    assert r_between > at_nodes[k]
    tight = running_cycle(cycle.controller, mu=(at_nodes[k] + r_between) / 2,
                          sliding=False)
    with pytest.raises(HybridCycleError) as at_nodes_only:      # the stance passes
        _at_nodes(tight).stride(x)
    assert at_nodes_only.value.domain == "flight" and "landing impulse" in str(
        at_nodes_only.value)                           # (its cone is now narrower too)
    with pytest.raises(HybridCycleError, match=r"^domain 'stance': friction cone \(Fx <= mu "
                                               r"Fz\) violated at t = \S+ s \(\S+ < 0, "
                                               r"between two RK4 nodes\)$") as e:
        tight.stride(x)
    t_dip = float(re.search(r"t = (\S+) s", str(e.value)).group(1))
    assert abs(t_dip - t_between) < d.h and t_dip not in st.times


def test_the_ground_pushes_the_foot_until_the_flight_law_lets_it_go(pinned, pinned_stable,
                                                                     model):
    """0.01 rad/s less on dq1 at the fixed point: the stance law's normal force reaches 0
    late (0.31 ms after T_stance), the restarted flight law's first torques differ from
    the stance law's last, and under them the ground would still push the foot.  It stays
    on the ground (the push-off) until that force reaches 0; freed at the law's switch
    instead, it would start down and go below the ground between two nodes.  At the
    fixed point the push-off is empty: the foot leaves at the switch."""
    cycle, stable = pinned, pinned_stable
    c, nq = cycle.controller, model.nq
    at_star = cycle.stride(stable.fixed_point, record=True)
    assert at_star.durations[1] == 0.0 and at_star.passes[1].times.tolist() == [0.0]
    x = stable.fixed_point.copy()
    x[nq] -= 0.01
    st, po, fl = cycle.stride(x, record=True).passes
    q, dq = st.exit_state[:nq], st.exit_state[nq:]
    qe, dqe = c.fl.takeoff(q, dq)
    assert po.parameters[-1] == 0.0 and fl.parameters[-1] == pytest.approx(po.duration, abs=1e-15)
    Fz_stance = float(c.fl.takeoff_guard(q, dq, c.stance_law(q, dq, st.duration))[0])
    Fz_switch = float(c.fl.takeoff_guard(q, dq, c.flight_law(qe, dqe, 0.0))[0])
    assert abs(Fz_stance) < 1e-9 and Fz_switch > 0.1             # 2.2 N measured
    assert 0 < po.duration < 1e-3                                 # 0.125 ms measured
    q, dq = po.exit_state[:nq], po.exit_state[nq:]
    qe, dqe = c.fl.takeoff(q, dq)
    assert abs(float(c.fl.takeoff_guard(q, dq, c.flight_law(qe, dqe, po.duration))[0])) < 1e-9
    run = simulate_running(cycle, stable.fixed_point, x, 20)
    assert run.status == "ok", run.message
    assert run.strides[0].pushoff == po.duration
    assert run.strides[0].durations[0] == pytest.approx(st.duration + po.duration, abs=1e-15)
    # the foot freed at the switch: the push-off's guard below 0 at its entry
    d = cycle.domains[1]
    X, t, p = ca.SX.sym("X", d.nX), ca.SX.sym("t"), ca.SX.sym("p", d.n_par)
    freed = HybridCycle([cycle.domains[0],
                         dataclasses.replace(d, guard=ca.Function("g", [X, t, p], [-1 + 0 * t])),
                         cycle.domains[2]])
    with pytest.raises(HybridCycleError, match=r"^domain 'flight': other foot height "
                                               r"violated at t = \S+ s \(\S+ < 0, between "
                                               r"two RK4 nodes\)$"):
        freed.stride(x)


def test_plain_tracking_is_unstable_and_its_run_diverges(cycle, model):
    plain = cycle.retuned(M1=np.zeros(model.nu))
    r = running_stability(plain)
    assert r.status == "unstable" and r.spectral_radius > 1
    x = r.fixed_point.copy()
    x[model.nq:] += 1e-2
    run = simulate_running(plain, r.fixed_point, x, 20)
    d = run.deviations
    assert d.max() > 10 * d[0]
    # it stops at the first stride the robot cannot run, and says where and why
    if run.status != "ok":
        assert run.message.startswith(f"stride {d.size}: domain '")
        assert "violated" in run.message or "not crossed" in run.message


def _takeoff_jump(cyc, x):
    """The law's torque at its switch: stance law's last, flight law's first (N m)."""
    c = cyc.controller
    st, po, _ = cyc.stride(x, record=True).passes
    nq = c.model.nq
    q, dq = st.exit_state[:nq], st.exit_state[nq:]
    u_st = np.array(c.stance_law(q, dq, st.duration)).ravel()
    qe, dqe = (np.array(v).ravel() for v in c.fl.takeoff(q, dq))
    u_fl = np.array(c.flight_law(qe, dqe, po.parameters[-1])).ravel()
    return np.abs(u_fl - u_st).max(), st, po


@pytest.fixture(scope="session")
def stride_clock(cycle):
    return running_cycle(cycle.controller, flight_clock="stride", sliding=False)


def test_the_stride_clock_continues_the_stance_reference_through_takeoff(
        model, run_gait, pinned, pinned_stable, stride_clock):
    """With ``flight_clock='stride'`` the flight law starts at the stance's clock less
    T_stance, so a takeoff off the reference's time leaves the torque continuous where
    the restarted clock jumps; the exact Jacobian carries the takeoff time into flight.
    (The pinned foot's model: the takeoff is where the law switches.)"""
    cycle, stable = pinned, pinned_stable
    x = stable.fixed_point.copy()
    x[model.nq:] += 1e-2
    jump0, st0, fl0 = _takeoff_jump(cycle, x)
    jump1, st1, fl1 = _takeoff_jump(stride_clock, x)
    assert fl0.parameters[-1] == 0.0
    assert fl1.parameters[-1] == pytest.approx(st1.duration - run_gait.T_stance, abs=1e-15)
    assert abs(st1.duration - run_gait.T_stance) > 1e-4          # off the reference's time
    assert st1.duration == st0.duration                          # stance is the same
    assert jump1 < 0.3 * jump0                                   # 2.48 -> 0.65 N m measured
    r = running_stability(stride_clock)
    assert r.status in ("stable", "unstable") and r.residual < 1e-10
    J = finite_difference_jacobian(stride_clock, r.fixed_point, 1e-5)
    assert np.max(np.abs(J - r.A)) < 1e-6 * np.max(np.abs(r.A))
    # retuning keeps the clock
    re = stride_clock.retuned(M1=STABLE_M1)
    assert re.flight_clock == "stride"
    assert np.array_equal(re.stride(x).next_state, stride_clock.stride(x).next_state)


# ------------------------------------------------------------------ command line
def test_command_line_stability(gait_file, stable, capsys):
    from analysis.cli import main
    assert main(["running", "--gait", gait_file, "--steps", "4", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)["stability"]
    assert s["spectral_radius"] == pytest.approx(stable.spectral_radius, rel=1e-9)
    assert s["fixed_point_distance"] == pytest.approx(stable.distance, rel=1e-6)
    assert np.allclose(s["eigenvalue_moduli"], np.abs(stable.eigenvalues), rtol=1e-9)
    sim = s["simulation"]
    assert sim["status"] == "ok" and len(sim["contraction"]) == 4
    d = np.array(sim["deviations"])
    assert np.allclose(sim["contraction"], d[1:] / d[:-1])
    # the human report prints the same figures (no second build of the cycle)
    from analysis.cli.running import _print_stability
    _print_stability(s)
    out = capsys.readouterr().out
    assert f"spectral radius      {stable.spectral_radius:.4f}" in out
    assert "per-stride contraction " + " ".join(f"{v:.3g}" for v in sim["contraction"]) in out
    assert s["sliding"] and sim["sliding"] and "slack" not in out
    assert (f"sliding near takeoff up to {1e3 * sim['margins']['slip_max']:.3g} ms"
            in out) and sim["margins"]["slip_max"] > 0


def test_command_line_says_a_failed_loop_and_exits_1(gait_file, capsys):
    """Plain tracking's perturbed run stops (its third stance leaves the friction cone):
    the report is printed, then one line on stderr, exit code 1 (as ``biped
    mujoco-running``'s run that stops); the flight clock is reported."""
    from analysis.cli import main
    assert main(["running", "--gait", gait_file, "--m1", "0", "0", "0", "0", "--json"]) == 1
    o = capsys.readouterr()
    s = json.loads(o.out)["stability"]
    assert s["status"] == "unstable" and s["simulation"]["status"] == "stopped"
    assert s["flight_clock"] == "takeoff"
    assert o.err.strip() == ("biped running: the closed loop failed: the perturbed run "
                             f"stopped at {s['simulation']['message']}")


def test_a_foot_back_below_the_ground_names_the_tangential_force(capsys):
    """A pushing foot below the ground in flight: the message says what was measured to
    cause it (with either clock, the law's switch being taken up by the push-off); a
    loop that completes is exit 0, silent."""
    from analysis.cli.running import loop_exit_code
    msg = "domain 'flight': other foot height violated at t = 0.000580279 s (-6.09e-09 < 0)"
    for clock in ("takeoff", "stride"):
        assert loop_exit_code(dict(status="failed", message=msg, flight_clock=clock,
                                   sliding=False)) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"biped running: the closed loop failed: {msg}")
        assert "tangential ground force" in err and "--flight-clock" not in err
    # a sliding foot leaves without a tangential force: no such cause is named
    assert loop_exit_code(dict(status="failed", message=msg, sliding=True)) == 1
    assert "tangential" not in capsys.readouterr().err
    other = "domain 'stance': torque u1 <= 150 N m violated at t = 0.00923782 s (-0.511 < 0)"
    assert loop_exit_code(dict(status="failed", message=other, flight_clock="takeoff")) == 1
    assert "tangential" not in capsys.readouterr().err
    assert loop_exit_code(dict(status="unstable", simulation=dict(status="ok"))) == 0
    assert loop_exit_code(None) == 0 and capsys.readouterr().err == ""


@pytest.mark.parametrize("args, words", [
    (["--kp", "-5"], "--kp"), (["--kd", "nan"], "--kd"), (["--m1", "1", "2"], "--m1"),
    (["--steps", "-1"], "--steps"), (["--perturb", "inf"], "--perturb"),
    (["--m1", "0", "inf", "0", "0"], "--m1"), (["--speed", "2"], "--speed"),
    (["--plot", "figs"], "--plot"), (["--torque-limit", "100"], "add --saturate"),
    (["--saturate", "--torque-limit", "0"], "--torque-limit must be a positive number"),
    # RK4 diverged: 'state not finite at t = 0.0028 s', exit 1
    (["--kp", "1e300"], "the step supports Kp at most"),
    (["--kd", "1e300"], "the step supports Kd at most")])
def test_command_line_refuses_bad_gains(gait_file, capsys, args, words):
    from analysis.cli import main
    assert main(["running", "--gait", gait_file, *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "Traceback" not in err


def test_a_closed_loop_option_implies_the_closed_loop(run_gait, tmp_path, capsys,
                                                      monkeypatch):
    """``biped running --kp 1e300`` optimised the step, ignored the gain (no --stability)
    and exited 0: now any closed-loop option analyses the loop, which refuses the gain
    (too stiff for its RK4 step); without one the command stays the optimisation alone.
    (1e300 is now refused before the optimisation; 1e7 only at the step's nodes.)"""
    import analysis.cli.running as cli
    monkeypatch.setattr(cli, "optimize_running", lambda *a, **k: run_gait)
    out = str(tmp_path / "r.json")
    with pytest.raises(ValueError, match="Kp 1e[+]07.*the step supports Kp at most"):
        cli.cmd_running(cli_args("--kp", "1e7", "--steps", "0", "--out", out))
    capsys.readouterr()
    assert cli.cmd_running(cli_args("--out", out, "--json")) == 0
    d = json.loads(capsys.readouterr().out)
    assert "stability" not in d


def cli_args(*argv):
    """The namespace ``biped running`` parses from ``argv``."""
    from analysis.cli import build_parser
    return build_parser().parse_args(["running", *argv])


def test_command_line_names_a_bad_gait_file(tmp_path, capsys):
    from analysis.cli import main
    p = tmp_path / "walk.json"
    p.write_text('{"kind": "gait"}')
    assert main(["running", "--gait", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(p) in err


@pytest.mark.parametrize("command", ["running", "mujoco-running"])
def test_a_step_of_a_robot_that_is_not_built_in_asks_for_its_description(
        gait_file, tmp_path, capsys, command):
    """A saved step names its robot; one that is not built in (an imported robot's) needs
    ``--robot FILE``: both commands say so in one line (exit 2) instead of 'not a built-in
    robot' alone, and a ``--robot`` of another robot is named."""
    import json
    from analysis.cli import main
    d = json.loads(open(gait_file).read())
    d["robot"] = "my_walker"
    p = tmp_path / "mine.json"
    p.write_text(json.dumps(d))
    assert main([command, "--gait", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--robot FILE" in err and "my_walker" in err, err
    assert main([command, "--gait", str(p), "--robot", "three_link"]) == 2
    err = capsys.readouterr().err.strip()
    assert "is a step of my_walker, not of" in err, err


def test_stability_figure_is_labelled():
    from analysis.reporting.plots import running_stability_plot
    c = np.linspace(0.5, 1.5, 5)
    r = np.array([3.0, 1.2, 0.4, 0.9, np.nan])
    fig = running_stability_plot("RABBIT", 1.5, {"PD, Kp 400": (c, r)},
                                 {"M1[2]": (c, 2 * r)}, "PD")
    assert "RABBIT" in fig._suptitle.get_text() and "1.5 m/s" in fig._suptitle.get_text()
    for ax in fig.axes:
        assert "[" in ax.get_xlabel() and "spectral radius" in ax.get_ylabel()
        assert ax.get_yscale() == "log"
        assert any(t.get_text() == "spectral radius 1" for t in ax.get_legend().get_texts())
    assert len(fig.axes[0].get_lines()) == 2      # the family and the line at 1


def test_saturation_clips_at_the_limit(model, run_gait, cycle):
    import casadi as ca
    c = RunningController(model, run_gait, KP, KD, M1=STABLE_M1, saturate=True,
                          torque_limit=50.0)
    u = np.array([-80.0, -20.0, 49.0, 120.0])
    assert np.array_equal(np.array(c.applied(ca.DM(u))).ravel(), [-50.0, -20.0, 49.0, 50.0])
    # without saturation the torques pass, and the limit is the model's
    assert cycle.controller.torque_limit == model.description.torque_limit
    assert np.array_equal(np.array(cycle.controller.applied(ca.DM(u))).ravel(), u)
    with pytest.raises(ValueError, match="torque_limit"):
        RunningController(model, run_gait, torque_limit=-1.0)


@pytest.mark.slow
def test_the_how_to_example_runs(tmp_path, monkeypatch):
    """The closed-loop example of docs/howto/running.md as written there (its asserts
    included), after the page's first example, which saves the step it loads."""
    from pathlib import Path
    page = Path(__file__).resolve().parents[1] / "docs" / "howto" / "running.md"
    blocks = [b.split("```", 1)[0] for b in page.read_text().split("```python\n")[1:]]
    (first,) = [b for b in blocks if "optimize_running(" in b]
    (block,) = [b for b in blocks if "running_cycle(" in b]
    monkeypatch.chdir(tmp_path)
    exec(compile(first, str(page), "exec"), {})
    space = {}
    exec(compile(block, str(page), "exec"), space)
    assert space["r"].stable and np.allclose(space["J"], space["r"].A, rtol=0, atol=1e-5)


@pytest.mark.slow
def test_the_margin_lets_a_perturbed_run_land_at_2_m_s(model):
    """At 2 m/s, with the default friction margin, the perturbed run (0.002 rad/s on every
    velocity, the how-to's design) lands in every stride with its impulse inside the
    ground's cone (mu, not mu - mu_margin) and converges.  (Without the margin the
    impulse sits on the cone's edge: ``test_running.py``'s margin test; the run then
    stops at its first landing: the how-to's measurement.)  With 0.01 rad/s the first
    landing is inside the cone too, but the second flight stops: the foot that pushed
    off goes below the ground between the takeoff and the first RK4 node."""
    from gait_opt.running import RunningOptions, optimize_running
    o = RunningOptions(speed=2.0)
    g = optimize_running(model, o, cache=True)
    assert g.success
    cyc = running_cycle(RunningController(model, g, KP, KD, M1=STABLE_M1), sliding=False)
    r = running_stability(cyc)
    assert r.status == "stable"
    x = r.fixed_point.copy()
    x[model.nq:] += 2e-3
    on = simulate_running(cyc, r.fixed_point, x, 8)
    assert on.status == "ok" and len(on.strides) == 8, on.message
    assert max(s.landing_impulse_ratio for s in on.strides) < o.mu
    assert on.deviations[-1] < on.deviations[1]
    x[model.nq:] += 8e-3
    off = simulate_running(cyc, r.fixed_point, x, 8)
    assert off.strides and max(s.landing_impulse_ratio for s in off.strides) < o.mu
    assert re.match(rf"stride {len(off.strides) + 1}: domain 'flight': other foot height "
                    r"violated at t = \S+ s \(\S+ < 0, between two RK4 nodes\)$", off.message)


# ------------------------------------------------------------------ saturation
SAT_LIMIT = 100.0      # below the 1.5 m/s orbit's peak (106 N m): its torques saturate


@pytest.fixture(scope="module")
def saturated(model, run_gait):
    """The how-to's design with the torques clipped at SAT_LIMIT (one build, about 6 s)."""
    c = RunningController(model, run_gait, KP, KD, M1=STABLE_M1, saturate=True,
                          torque_limit=SAT_LIMIT)
    cyc = running_cycle(c)
    return cyc, running_stability(cyc)


def test_time_above_interpolates_the_crossings():
    from analysis.stability.running_cycle import _time_above
    t = np.array([0.0, 1.0, 2.0, 4.0])
    assert _time_above(t, [-1.0, 1.0, 3.0, -1.0]) == pytest.approx(0.5 + 1.0 + 1.5)
    assert _time_above(t, [-1.0, -2.0, 0.0, -1.0]) == 0.0
    assert _time_above(t[:2], [2.0, 2.0]) == 1.0


def test_a_saturated_run_goes_on_at_the_limit_and_says_how_long(model, saturated, cycle,
                                                                 stable):
    cyc, r = saturated
    assert r.status == "stable"
    x = r.fixed_point.copy()
    x[model.nq:] += 1e-2
    run = simulate_running(cyc, r.fixed_point, x, 4)
    assert run.status == "ok", run.message
    c = cyc.controller
    for s in run.strides:
        assert s.torque_max > SAT_LIMIT and s.saturated_time > 0
    # the time lies between the node intervals saturated at both ends and at either end
    low = high = 0.0
    passes = cyc.stride(r.fixed_point, record=True).passes
    nq, ne = model.nq, c.fl.ne
    for p, phase in zip(passes, cyc.laws):
        N = p.times.size
        if p.nodes.shape[0] == 2 * nq:
            q, dq = c.fl.takeoff.map(N)(p.nodes[:nq], p.nodes[nq:])
        else:
            q, dq = p.nodes[:ne], p.nodes[ne:]
        clock = p.parameters[-1] if p is not passes[0] else 0.0
        u = np.array(c.stance_law.map(N)(q[:nq, :], dq[:nq, :], p.times[None, :] + clock)
                     if phase == "stance" else
                     c.flight_law.map(N)(q, dq, p.times[None, :] + clock))
        over = np.abs(u).max(axis=0) > SAT_LIMIT
        dt = np.diff(p.times)
        low += dt[over[:-1] & over[1:]].sum()
        high += dt[over[:-1] | over[1:]].sum()
    sat = simulate_running(cyc, r.fixed_point, r.fixed_point, 1).strides[0].saturated_time
    assert 0 < low <= sat <= high
    # at the robot's limit the 1.5 m/s run never asks for more: no time saturated
    x = stable.fixed_point.copy()
    x[model.nq:] += 1e-2
    assert all(s.saturated_time == 0 for s in simulate_running(cycle, stable.fixed_point, x,
                                                                2).strides)


def test_command_line_saturates(gait_file, saturated, cycle, monkeypatch, capsys):
    """``--saturate`` builds the cycle of a saturating controller and reports each
    stride's time saturated (the build is replaced by the fixture's: its limit is lower
    than the robot's, so that the 1.5 m/s orbit saturates)."""
    import analysis.cli.running as cli
    from analysis.cli import main
    asked = []

    def build(c, **options):
        asked.append((c.saturate, c.torque_limit))
        return saturated[0] if c.saturate else cycle
    monkeypatch.setattr(cli, "running_cycle", build)
    assert main(["running", "--gait", gait_file, "--steps", "3", "--saturate",
                 "--torque-limit", str(SAT_LIMIT), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)["stability"]
    sim = s["simulation"]
    assert s["clipped_at"] == SAT_LIMIT
    cyc, r = saturated
    x = r.fixed_point.copy()
    x[cyc.controller.model.nq:] += 1e-2
    lib = simulate_running(cyc, r.fixed_point, x, 3)
    assert sim["saturate"] and sim["torque_limit"] == SAT_LIMIT and sim["status"] == "ok"
    assert sim["saturated_time"] == [s.saturated_time for s in lib.strides]
    assert min(sim["saturated_time"]) > 0
    assert sim["margins"]["saturated_time"] == pytest.approx(sum(sim["saturated_time"]))
    cli._print_stability({"law": "pd", "Kp": KP, "Kd": KD, "M1": list(STABLE_M1),
                          "clipped_at": s["clipped_at"],
                          "status": "stable", "stable": True, "fixed_point_residual": 0.0,
                          "fixed_point_distance": 0.0, "spectral_radius": 0.5,
                          "eigenvalue_moduli": [0.5], "simulation": sim})
    out = capsys.readouterr().out
    assert "clipped at 100 N m in 3 of 3 strides" in out and "|u| asked <=" in out
    assert "M1 0 0.95 0.95 0, torques clipped at 100 N m): stable" in out
    assert main(["running", "--gait", gait_file, "--steps", "1", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)["stability"]
    sim = s["simulation"]
    robot = float(cycle.controller.torque_limit)
    assert asked == [(True, SAT_LIMIT), (False, robot)] and s["clipped_at"] is None
    assert not sim["saturate"] and sim["saturated_time"] == [0.0]


def test_saturate_closes_the_loop_of_an_optimised_step(run_gait, tmp_path, monkeypatch,
                                                       capsys):
    """``biped running --saturate`` without ``--stability`` still runs the closed loop
    (as ``--choose-m1`` and ``--gait``): the solve and the loop are replaced here by the
    session's step and a record of the call."""
    import analysis.cli.running as cli
    from analysis.cli import main
    calls = []
    monkeypatch.setattr(cli, "optimize_running", lambda *a, **k: run_gait)
    monkeypatch.setattr(cli, "closed_loop", lambda model, gait, args: calls.append(
        args.saturate) or {"law": "pd", "Kp": KP, "Kd": KD, "M1": list(STABLE_M1),
                           "status": "failed", "message": "recorded"})
    out = str(tmp_path / "run.json")
    assert main(["running", "--saturate", "--out", out, "--json"]) == 1     # a failed loop
    o = capsys.readouterr()
    assert calls == [True] and json.loads(o.out)["stability"]["message"] == "recorded"
    assert o.err.strip() == "biped running: the closed loop failed: recorded"


def test_a_robot_without_a_torque_limit_runs_the_closed_loop(model, run_gait, cycle, stable):
    """No limit (a URDF without <limit effort>): no torque constraint, nothing saturated,
    the same stride map; a clip then needs a limit of its own."""
    import warnings
    free = RunningController(model, run_gait, KP, KD, M1=STABLE_M1, torque_limit=math.inf)
    c = running_cycle(free)
    x = stable.fixed_point
    np.testing.assert_allclose(c.linearise(x).A, cycle.linearise(x).A, rtol=0, atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                  # (inf - inf made a NaN warning)
        run = simulate_running(c, x, x, 2)
    assert run.status == "ok" and all(s.saturated_time == 0.0 for s in run.strides)
    with pytest.raises(ValueError, match="torque_limit must be a positive number, got inf"):
        RunningController(model, run_gait, KP, KD, saturate=True, torque_limit=math.inf)


def test_an_optimised_steps_torque_limit_is_its_closed_loops(run_gait, tmp_path,
                                                              monkeypatch, capsys):
    """``biped running --torque-limit U --saturate`` (no --gait): U bounds the optimised
    step and is the limit its closed loop clips at (without --saturate, the limit its
    runs stop beyond); the solve and the loop are replaced by the session's step and a
    record of the controller built."""
    import analysis.cli.running as cli
    from analysis.cli import main
    bounds, limits = [], []

    def solve(model, opts, **kw):
        bounds.append(opts.torque_limit)
        return run_gait

    def loop(model, gait, args):
        c = cli.running_controller(args, gait, model)
        limits.append((c.saturate, c.torque_limit))
        return {"law": "pd", "Kp": KP, "Kd": KD, "M1": list(STABLE_M1), "status": "failed",
                "message": "recorded"}
    monkeypatch.setattr(cli, "optimize_running", solve)
    monkeypatch.setattr(cli, "closed_loop", loop)
    out = str(tmp_path / "run.json")
    for extra in (["--saturate"], ["--stability"]):
        assert main(["running", "--torque-limit", "120", *extra, "--out", out, "--json"]) == 1
        capsys.readouterr()
    assert bounds == [120.0, 120.0] and limits == [(True, 120.0), (False, 120.0)]


def test_a_robot_without_a_limit_needs_one_to_clip_at(model, run_gait):
    """The closed loop of a robot without a torque limit (a URDF without effort limits):
    --saturate asks for --torque-limit in the words of 'biped export --saturate'; without
    --saturate the loop has no limit, but MuJoCo's motors need one; one line each."""
    import argparse
    from analysis.cli.common import UserError
    from analysis.cli.running import running_controller
    from biped_casadi import robot
    free = robot(dataclasses.replace(model.description, torque_limit=float("inf")))
    assert free is not model and model.description.torque_limit == 150.0

    def built(saturate, limit, engine=""):
        return running_controller(argparse.Namespace(m1=None, kp=KP, kd=KD, law="pd",
                                                     saturate=saturate, torque_limit=limit),
                                  run_gait, free, engine)
    with pytest.raises(UserError, match="^--saturate: the robot RABBIT has no torque limit "
                                        "to clip at: give --torque-limit U$"):
        built(True, None)
    assert built(False, None).torque_limit == math.inf
    with pytest.raises(UserError, match="no torque limit, which MuJoCo's motors need: "
                                        "give --saturate --torque-limit U$"):
        built(False, None, "MuJoCo")
    c = built(True, 90.0)
    assert c.saturate and c.torque_limit == 90.0


@pytest.mark.parametrize("gain, h2_bound", [("Kp", 8.0), ("Kd", None)])
def test_the_rk4_bound_on_the_gains_is_rk4s(model, run_gait, gain, h2_bound):
    """The bound :func:`check_rk4_steps` puts on the gains is RK4's stability region: for
    the computed torque each output is dd e = -Kp e - Kd de, so Kp alone is stable while
    h^2 Kp <= 8 (the imaginary axis, |h lambda| <= 2 sqrt 2) and Kd alone while h Kd is
    at most the root of 1 - x + x^2/2 - x^3/6 + x^4/24 = 1 (the negative real axis)."""
    from biped_casadi.control.running_step import check_rk4_steps
    h = 1e-3
    x = [r.real for r in np.roots([1 / 24, -1 / 6, 1 / 2, -1]) if abs(r.imag) < 1e-12][0]
    limit = h2_bound / h**2 if gain == "Kp" else x / h
    for scale, refused in ((0.999, False), (1.001, True)):
        gains = {"Kp": 0.0, "Kd": 0.0}
        gains[gain] = limit * scale
        c = RunningController(model, run_gait, law="computed_torque", **gains)
        if not refused:
            check_rk4_steps(c, dict(stance=h, flight=h))
            continue
        with pytest.raises(ValueError, match=f"{gain} at most ([0-9.e+]+) ") as e:
            check_rk4_steps(c, dict(stance=h, flight=h))
        top = float(re.search(f"{gain} at most ([0-9.e+]+) ", str(e.value)).group(1))
        assert top == pytest.approx(limit, rel=2e-3)


def test_a_mode_the_flow_grows_is_not_refused_as_rk4s(model, run_gait, cycle):
    """M1 = (0, 1.1, 1.1, 0) makes the flight's A = M De^-1 Be indefinite: the frozen
    output error has a real mode that grows in the flow itself, e^z a step, and RK4
    follows it (|P(z)| = e^z to round-off).  That is the law's, not the step's: the gains
    are not refused, and the cycle has a fixed point there (inside the stable band)."""
    from biped_casadi.control.running_step import _output_matrices, rk4_growth
    M1 = (0.0, 1.1, 1.1, 0.0)
    c = RunningController(model, run_gait, KP, KD, M1=M1)
    A = _output_matrices(c, "flight")
    assert min(np.linalg.eigvals(a).real.min() for a in A) < 0      # the flow's growth
    h = cycle.rk4_steps["flight"]
    assert rk4_growth(A, h, c.Kp, c.Kd) <= 1 + 1e-9
    r = running_stability(cycle.retuned(M1=M1))
    assert r.status != "failed" and r.spectral_radius < 1, r.message


def test_rk4_reach_bounds_rk4s_stability_region():
    """Every z with ``|P(z)|`` <= 1 lies within RK4_REACH of 0, which the region nearly
    reaches (a polar grid of the plane)."""
    from biped_casadi.control.running_step import RK4_REACH
    th, r = np.meshgrid(np.linspace(0, np.pi, 2001), np.linspace(0, 4, 4001))
    z = r * np.exp(1j * th)
    inside = np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24) <= 1
    assert RK4_REACH - 2e-3 < np.abs(z[inside]).max() <= RK4_REACH


@pytest.mark.parametrize("phase", ["stance", "flight"])
def test_the_gains_bounds_before_a_step_hold_at_its_nodes(model, run_gait, phase):
    """The bounds known before a step is optimised (rk4_gain_bounds) are beyond the
    exact ones at the step's nodes at the same RK4 step, and gains beyond them are
    refused at that step and at longer ones."""
    from biped_casadi.control.running_step import check_rk4_steps, rk4_gain_bounds
    n = (16 if phase == "stance" else 10) * 8
    h = float(getattr(run_gait, f"T_{phase}")) / n
    kp_top, kd_top = rk4_gain_bounds(model, phase, h, "pd", STABLE_M1)
    exact = {}
    for gain, kept in (("Kp", dict(Kd=KD)), ("Kd", dict(Kp=KP))):
        c = RunningController(model, run_gait, M1=STABLE_M1, **kept, **{gain: 1e12})
        with pytest.raises(ValueError) as e:
            check_rk4_steps(c, {phase: h})
        exact[gain] = float(re.search(f"{gain} at most ([0-9.e+]+) ", str(e.value)).group(1))
    assert exact["Kp"] < kp_top and exact["Kd"] < kd_top, (exact, kp_top, kd_top)
    for gains in (dict(Kp=1.01 * kp_top, Kd=0.0), dict(Kp=0.0, Kd=1.01 * kd_top)):
        c = RunningController(model, run_gait, M1=STABLE_M1, **gains)
        for scale in (1, 2, 10):
            with pytest.raises(ValueError, match="RK4 step"):
                check_rk4_steps(c, {phase: scale * h})
