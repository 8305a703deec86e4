"""A periodic running gait of RABBIT (gait_opt.running) and its measured checks
(gait_opt.running_checks).

The gait is solved once per session on a small grid (fast) and read on the default
grid (the session's shared step, cached on disk); every check is computed outside the NLP: the ground force from the exact
dynamics on a dense grid of the Hermite-Simpson interpolant, the phases integrated by
scipy under the gait's torques, the step map through the exact takeoff and landing
Functions, the centre of mass and the angular momentum in flight.  A constraint
dropped from the NLP shows in one of them; checks of a gait that violates them on
purpose (the hand-made guess, a takeoff torque changed) show that the checks see it.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from biped_casadi import rabbit
from biped_casadi.model import flight_model
from gait_opt.running import (MU_MARGIN, RunningGait, RunningOptions, hermite_simpson,
                              optimize_running, running_guess)
from gait_opt.running_checks import check_running, dense, phase_rhs

SPEED = 1.5


@pytest.fixture(scope="session")
def model():
    return rabbit()


@pytest.fixture(scope="session")
def small(model):
    """A small grid (6 stance, 4 flight intervals): a few seconds."""
    g = optimize_running(model, RunningOptions(speed=SPEED, n_stance=6, n_flight=4))
    return g, check_running(model, g)


@pytest.fixture(scope="session")
def default(model, running_gait):
    """The default grid (16 + 10 intervals): the session's shared 1.5 m/s step."""
    o, d = running_gait.options, RunningOptions(speed=SPEED)
    assert (o.speed, o.n_stance, o.n_flight) == (d.speed, d.n_stance, d.n_flight)
    return running_gait, check_running(model, running_gait)


def _physical(model, g, r, integration_tol):
    """Every measured figure of a solved running gait within its tolerance."""
    o = g.options
    weight = model.description.total_mass * model.description.gravity
    assert g.success, g.solver_stats
    assert g.speed == pytest.approx(o.speed, rel=1e-8)
    assert g.step_length > 0.3
    # stance: the foot pressed and not slipping, the force at zero at takeoff
    assert abs(r.fz_takeoff) <= 1e-6 * weight
    assert r.fz_min_nodes >= -1e-6 * weight
    assert r.fz_min_dense >= -1e-6 * weight
    # inside the friction cone at the points and between them (near takeoff, where both
    # forces vanish, by the cone on their rates)
    assert r.friction_excess_nodes <= 1e-6 * weight
    assert r.friction_excess_dense <= 1e-6 * weight
    assert r.swing_min_stance >= -1e-7
    # torques within the limit between the points too (where the quadratic through the
    # points overshoots it, the bound is lowered and the step solved again)
    assert "torque limit" not in dict(r.violations(o.limit(model)))
    # flight: a real one, both feet above the ground, the touchdown valid
    assert r.flight_duration >= o.flight_time_bounds[0] - 1e-9
    assert r.takeoff_torque_jump <= 1e-8
    assert abs(r.takeoff_foot_acceleration) <= 1e-5
    assert r.feet_min_flight >= -1e-7
    assert r.strike_velocity <= -o.min_strike_speed + 1e-8
    assert r.other_foot_velocity >= o.min_liftoff_speed - 1e-8
    assert r.impulse_ratio <= o.mu + 1e-6
    # the two edges close the orbit; the transcription agrees with an ODE integrator
    assert r.periodicity_collocated <= 1e-8
    assert r.stance_end_error <= integration_tol
    assert r.flight_end_error <= integration_tol
    assert r.step_map_residual <= 5 * integration_tol
    assert abs(r.touchdown_time_error) <= integration_tol
    # flight physics: exact along the integration, to the transcription's error along
    # the collocated trajectory
    assert r.com_ballistic_integrated <= 1e-9
    assert r.momentum_drift_integrated <= 1e-8 * max(1.0, r.momentum_scale)
    assert r.com_ballistic_collocated <= integration_tol
    assert r.momentum_drift_collocated <= integration_tol * max(1.0, r.momentum_scale)


def test_small_grid_gait_is_physical(model, small):
    g, r = small
    _physical(model, g, r, integration_tol=1e-2)


@pytest.mark.slow
def test_default_gait_is_physical(model, default):
    g, r = default
    _physical(model, g, r, integration_tol=1e-3)


@pytest.mark.slow
def test_grids_agree(small, default):
    """The small and the default grid find the same gait (cost and durations)."""
    (gs, _), (gd, _) = small, default
    assert gs.cost == pytest.approx(gd.cost, rel=0.01)
    assert gs.T_stance == pytest.approx(gd.T_stance, rel=0.02)
    assert gs.T_flight == pytest.approx(gd.T_flight, rel=0.05)


def test_warm_start_from_a_gait(model, small):
    """A solved gait as the guess of the same problem: fewer IPOPT iterations (no
    multipliers are kept: the barrier starts afresh), the same gait."""
    g, _ = small
    again = optimize_running(model, g.options, guess=g)
    assert again.success
    assert again.solver_stats["iterations"] < g.solver_stats["iterations"]
    assert again.cost == pytest.approx(g.cost, rel=1e-6)


def test_takeoff_and_landing_states(model, small):
    """Recomputed from the stored states: the flight starts at the takeoff embedding,
    the base at rest at the origin; the landing foot is where the step ends."""
    g, _ = small
    fl = flight_model(model)
    n, ne = model.nq, fl.ne
    assert np.allclose(g.x_flight[:n, 0], g.x_stance[:n, -1], atol=1e-9)
    assert np.allclose(g.x_flight[[n, n + 1, ne + n, ne + n + 1], 0], 0, atol=1e-9)
    feet = np.array(fl.feet(g.x_flight[:ne, -1]))
    assert feet[1, 1] == pytest.approx(0, abs=1e-8)
    assert feet[0, 1] == pytest.approx(g.step_length, abs=1e-8)
    assert feet[1, 0] >= g.options.trailing_clearance - 1e-8
    q_plus, dq_plus, *_ = fl.landing_swing(g.x_flight[:ne, -1], g.x_flight[ne:, -1])
    assert np.allclose(np.r_[np.array(q_plus).ravel(), np.array(dq_plus).ravel()],
                       g.x_stance[:, 0], atol=1e-8)


def test_posture_bounds(model, small):
    g, _ = small
    o = g.options
    for x in (g.x_stance, g.x_flight):
        q = x[:model.nq]
        assert np.all(q[1] <= o.stance_knee_max + 1e-8) and np.all(q[1] >= -o.knee_flexion_max - 1e-8)
        assert np.all(q[4] >= o.swing_knee_min - 1e-8) and np.all(q[4] <= o.knee_flexion_max + 1e-8)
        lean = np.array(model.torso_angle.map(q.shape[1])(q)).ravel()
        assert np.all(np.abs(lean) <= o.torso_lean_max + 1e-8)


def test_save_and_load(tmp_path, small):
    g, _ = small
    back = RunningGait.load(g.save(tmp_path / "run.json"))
    assert back.options == g.options
    for f in dataclasses.fields(RunningGait):
        a, b = getattr(g, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b), f.name
        elif f.name != "solver_stats":
            assert a == b, f.name
    (tmp_path / "other.json").write_text('{"kind": "gait"}')
    with pytest.raises(ValueError, match="not a running gait"):
        RunningGait.load(tmp_path / "other.json")


def test_checks_see_a_gait_that_is_not_one(model):
    """The hand-made guess is no orbit: the checks say so (the edges do not close, the
    phases do not follow the dynamics, the takeoff force is not zero)."""
    o = RunningOptions(speed=SPEED, n_stance=6, n_flight=4)
    guess = running_guess(model, o)
    g = RunningGait(robot="RABBIT", options=o, step_length=1.0, cost=0.0, **guess)
    r = check_running(model, g)
    assert r.periodicity_collocated > 1e-2
    assert r.stance_end_error > 1e-2
    assert abs(r.fz_takeoff) > 10.0


def test_checks_see_a_changed_takeoff_torque(model, small):
    g, r = small
    bad = dataclasses.replace(g, u_stance=g.u_stance.copy())
    bad.u_stance[0, -1] += 20.0                 # the stance knee at takeoff
    r_bad = check_running(model, bad)
    assert abs(r.fz_takeoff) < 1e-3 < abs(r_bad.fz_takeoff)
    assert r_bad.stance_end_error > r.stance_end_error


def test_dense_grid_violations_are_named(model, default):
    """The default step holds its constraints between the points; a limit below its
    dense peak, or a foot below the ground, is named with its amount, worst first, and
    the command line's note says so."""
    from analysis.cli.running import _violation_notes
    g, r = default
    limit = g.options.limit(model)
    assert r.violations(limit) == []
    low = dataclasses.replace(r, feet_min_flight=-2e-3)
    v = low.violations(r.torque_max_dense - 0.5)
    assert [name for name, _ in v] == ["torque limit", "feet above the ground in flight"]
    assert v[0][1] == pytest.approx(0.5) and v[1][1] == pytest.approx(2e-3)
    assert low.violations(limit, tol=1e-2) == []
    note = _violation_notes(v)[0]
    assert "VIOLATED torque limit by 0.5 N m; feet above the ground in flight by 0.002 m" \
        in note and _violation_notes([]) == []


def test_hermite_simpson_interpolant_is_exact_for_cubics():
    """States cubic and torques quadratic in time are reproduced exactly between the
    points (the interpolant of the transcription)."""
    tn = np.linspace(0.0, 0.6, 7)
    c = np.array([0.3, -1.0, 2.0, 0.7])
    x = lambda t: np.polyval(c, t)[None, :]                  # noqa: E731
    f = lambda t: np.polyval(np.polyder(c), t)[None, :]      # noqa: E731
    u = lambda t: np.polyval([1.5, -0.2, 0.1], t)[None, :]   # noqa: E731
    t = np.linspace(0.0, 0.6, 37)
    xi, ui = hermite_simpson(tn, x(tn), f(tn), u(tn), t)
    assert np.allclose(xi, x(t), atol=1e-13) and np.allclose(ui, u(t), atol=1e-13)


def test_phase_rhs_is_the_models_dynamics(model, small):
    g, _ = small
    fl = flight_model(model)
    n, ne = model.nq, fl.ne
    fs, ff = phase_rhs(model, "stance"), phase_rhs(model, "flight")
    xs, us = g.x_stance[:, 3], g.u_stance[:, 3]
    xf, uf = g.x_flight[:, 2], g.u_flight[:, 2]
    assert np.allclose(fs(xs, us)[n:], np.array(model.forward_dynamics(xs[:n], xs[n:], us)).ravel())
    assert np.allclose(ff(xf, uf)[ne:], np.array(fl.flight_dynamics(xf[:ne], xf[ne:], uf)).ravel())
    with pytest.raises(ValueError):
        phase_rhs(model, "double support")


def test_running_plot(tmp_path, model, small):
    from analysis.reporting.plots import save_figure
    from analysis.reporting.plots.running import running_plot
    g, _ = small
    fig = running_plot(model, g)
    axes = fig.get_axes()
    assert "RABBIT" in fig._suptitle.get_text() and "m/s" in fig._suptitle.get_text()
    assert axes[0].get_xlabel() == "x [m]" and axes[0].get_ylabel() == "z [m]"
    assert "[rad]" in axes[1].get_ylabel() and "[N m]" in axes[2].get_ylabel()
    assert "[s]" in axes[2].get_xlabel()
    assert all(ax.get_legend() is not None for ax in axes)
    t, _, _ = dense(model, g, "stance")
    assert t[-1] == pytest.approx(g.T_stance)
    out = save_figure(fig, tmp_path / "running.png")
    assert out and all((tmp_path / "running.png").exists() for _ in out)


@pytest.mark.slow
def test_the_how_to_example_runs(tmp_path, monkeypatch):
    """The running-gait example of docs/howto/running.md (its python block that calls
    optimize_running), as written there (its asserts included), in a temporary folder."""
    from pathlib import Path
    page = Path(__file__).resolve().parents[1] / "docs" / "howto" / "running.md"
    blocks = [b.split("```", 1)[0] for b in page.read_text().split("```python\n")[1:]]
    (block,) = [b for b in blocks if "optimize_running(" in b]
    monkeypatch.chdir(tmp_path)
    exec(compile(block, str(page), "exec"), {})
    assert (tmp_path / "running.json").exists() and (tmp_path / "running_step.png").exists()


# ----------------------------------------------------------- options, files, command line
@pytest.mark.parametrize("field, value", [
    ("speed", 0.0), ("speed", float("nan")), ("mu", -0.1), ("torque_limit", float("inf")),
    ("clearance", -0.01), ("n_stance", 1), ("n_flight", 2.5), ("n_flight", True),
    ("stance_time_bounds", (0.3, 0.1)), ("flight_time_bounds", (0.0, 0.2)),
    ("stance_time_bounds", (0.1,)), ("torque_rate_max", -1.0), ("ipopt", "max_iter=3"),
    ("trailing_clearance", -0.01), ("takeoff_cone_rate", 1), ("cone_quarter_points", None),
    ("mu_margin", -0.01), ("mu_margin", float("nan")), ("mu_margin", 0.6), ("mu_margin", "0.05"),
    ("mu_margin", None), ("stall_window", 0), ("stall_window", True), ("stall_window", 2.5)])
def test_options_refuse_bad_values(field, value):
    with pytest.raises(ValueError, match=f"RunningOptions.{field}"):
        RunningOptions(**{field: value})


@pytest.mark.parametrize("ipopt", [{"no_such_option": 1}, {"max_iter": -1}])
def test_options_ipopt_refuses_are_named(model, ipopt):
    """IPOPT refusing an option was CasADi's 'forbidden since you have not solved'."""
    with pytest.raises(ValueError, match="RunningOptions.ipopt: IPOPT refuses the options"):
        optimize_running(model, RunningOptions(n_stance=2, n_flight=2, ipopt=ipopt))


@pytest.mark.parametrize("args, words", [
    (lambda m: (m, {"speed": 1.5}), "opts must be RunningOptions"),
    (lambda m: (None, None), "model must be a robot model"),
    (lambda m: (m, None, "gait.json"), "guess must be a RunningGait")])
def test_problem_arguments_are_named(model, args, words):
    """AttributeErrors ('dict' object has no attribute 'for_model') and a TypeError of
    string indices before."""
    with pytest.raises(TypeError, match=words):
        optimize_running(*args(model))


def test_a_failed_solve_is_the_last_iterate(model):
    """IPOPT stopping on a failure raised CasADi's assertion; now success is False and
    the status says why."""
    g = optimize_running(model, RunningOptions(speed=1e300, n_stance=2, n_flight=2))
    assert not g.success and g.solver_stats["return_status"] == "Invalid_Number_Detected"


def test_options_keep_good_values():
    o = RunningOptions(speed=2, n_stance=6, stance_time_bounds=[0.1, 0.5], torque_rate_max=None)
    assert o.stance_time_bounds == (0.1, 0.5) and o.speed == 2 and o.torque_rate_max is None


@pytest.mark.parametrize("text, match", [
    ("{not json", "cannot read"), ('{"kind": "gait"}', "not a running gait"),
    ('[1, 2]', "not a running gait"),
    ('{"kind": "running gait", "options": {"speed": -1}}', "malformed")])
def test_load_names_the_file(tmp_path, text, match):
    p = tmp_path / "r.json"
    p.write_text(text)
    with pytest.raises(ValueError, match=match) as e:
        RunningGait.load(p)
    assert str(p) in str(e.value)


@pytest.mark.parametrize("args, names", [
    (["--speed", "-1"], "--speed"), (["--intervals", "1", "4"], "--intervals STANCE"),
    (["--intervals", "6", "500"], "--intervals FLIGHT"), (["--robot", "three_link"], "--robot"),
    (["--out", "r.txt"], "--out"), (["--max-iter", "0"], "--max-iter"),
    (["--mu-margin", "0.6"], "--mu-margin"), (["--mu-margin", "-0.1"], "--mu-margin"),
    (["--speed", "6", "--max-iter", "5", "--intervals", "6", "4"], "did not converge")])
def test_command_line_refuses_in_one_line(tmp_path, monkeypatch, capsys, args, names):
    from analysis.cli import main
    monkeypatch.chdir(tmp_path)
    assert main(["running", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and names in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []            # nothing written


def test_command_line_saves_checks_and_draws(tmp_path, capsys):
    from analysis.cli import main
    from analysis.cli.running import COARSE
    out, figs = tmp_path / "run.json", tmp_path / "figs"
    assert main(["running", "--intervals", "6", "4", "--out", str(out), "--plot", str(figs),
                 "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    g = RunningGait.load(out)
    assert s["cost"] == g.cost and s["step_length"] == g.step_length
    assert abs(s["speed"] - 1.5) < 1e-9 and s["T_flight"] > 0
    assert abs(s["checks"]["fz_takeoff"]) < 1e-6 and s["checks"]["periodicity_collocated"] < 1e-8
    assert (figs / "running_step.png").stat().st_size > 10_000
    # the 6 + 4 grid departs from its integration by more than COARSE: said, with the
    # grid that cuts it
    worst = max(s["checks"]["stance_end_error"], s["checks"]["flight_end_error"])
    assert (worst > COARSE) == bool(s["notes"])
    assert all("--intervals 12 8" in n for n in s["notes"])
    assert 0 < s["checks"]["interval_error"] < 1


@pytest.mark.parametrize("stance_end,interval,grid", [(5e-3, 1e-3, True), (11.0, 1.7e-2, False)])
def test_the_coarse_grid_note_tells_the_grids_error_from_the_open_loops(stance_end, interval,
                                                                       grid):
    """A finer grid cuts a phase's departure 16-fold only when the departure is the
    grid's own error; a departure the open-loop phase grew from much smaller interval
    errors (the sagittal Unitree H1 at 1 m/s: 11 after 1.7e-2 per interval, 8.9 on the
    doubled grid) is said as such."""
    from types import SimpleNamespace
    from analysis.cli.running import _grid_notes
    report = dict(stance_end_error=stance_end, flight_end_error=1e-5, interval_error=interval)
    (note,) = _grid_notes(report, SimpleNamespace(n_stance=16, n_flight=10))
    assert "--intervals 32 20" in note
    assert ("cuts that about 16-fold" in note) == grid
    assert ("grows the grid's error" in note) != grid
    report.update(stance_end_error=1e-4)
    assert _grid_notes(report, SimpleNamespace(n_stance=16, n_flight=10)) == []


# ----------------------------------------------------------- the friction cone between points
def _cone_excess_at(model, g, s, mu=None):
    """Largest |Fx| - mu Fz (N) at the fractions ``s`` of every stance interval, on the
    Hermite-Simpson interpolant and the exact ground force (as the dense check); mu
    default the gait's ``options.mu``."""
    fl = flight_model(model)
    n, tn = model.nq, g.t_stance
    ends = tn[::2]
    t = np.concatenate([ends[:-1] + si * np.diff(ends) for si in s])
    x, u = hermite_simpson(tn, g.x_stance, phase_rhs(model, "stance")(g.x_stance, g.u_stance),
                           g.u_stance, t)
    Fz, Fx = (np.array(v).ravel() for v in fl.takeoff_guard.map(t.size)(x[:n], x[n:], u))
    return float(np.max(np.abs(Fx) - (g.options.mu if mu is None else mu) * Fz))


def test_cone_at_takeoff_holds_on_the_dense_grid(model, small):
    """With the cone on the forces' rates at takeoff, the force just before takeoff is
    inside the cone between the points too (the dense check), not only at them.  (On
    this grid the cone holds there without the condition too; the slow test below, at
    1.0 m/s on the default grid, is where it is left without it.)"""
    g, r = small
    assert g.options.takeoff_cone_rate
    weight = model.description.total_mass * model.description.gravity
    assert r.friction_excess_nodes <= 1e-6 * weight
    assert r.friction_excess_dense <= 1e-6 * weight
    # the last stance interval, where Fz and Fx fall to zero, sampled finely
    assert _cone_excess_at(model, g, np.linspace(0.5, 1.0, 201)[:-1]) <= 1e-6 * weight


@pytest.mark.slow
def test_cone_left_near_takeoff_without_the_rate_condition(model):
    """At 1.0 m/s on the default grid, the gait without the takeoff cone condition leaves
    the cone between the last points (the force vanishes in a direction outside it);
    with it, it does not, for about the same cost."""
    o = RunningOptions(speed=1.0, mu_margin=0.0)          # the cone of the NLP is mu's
    weight = model.description.total_mass * model.description.gravity
    off = optimize_running(model, dataclasses.replace(o, takeoff_cone_rate=False))
    on = optimize_running(model, o)
    assert off.success and on.success
    r_off, r_on = check_running(model, off), check_running(model, on)
    assert r_off.friction_excess_nodes <= 1e-6 * weight
    assert r_off.friction_excess_dense > 1e-3 * weight
    assert r_on.friction_excess_dense <= 1e-6 * weight
    assert on.cost == pytest.approx(off.cost, rel=1e-3)


def test_cone_at_the_quarter_points(model):
    """``cone_quarter_points``: the cone holds at every stance interval's quarter points
    of the interpolant (what the NLP now constrains), within IPOPT's tolerance."""
    g = optimize_running(model, RunningOptions(speed=SPEED, n_stance=6, n_flight=4,
                                               cone_quarter_points=True))
    assert g.success
    weight = model.description.total_mass * model.description.gravity
    assert _cone_excess_at(model, g, [0.25, 0.75]) <= 1e-6 * weight
    assert check_running(model, g).friction_excess_dense <= 1e-6 * weight


# ----------------------------------------------------------- lengths scaled with the legs
def test_lengths_follow_the_leg(model, small):
    """The clearances' defaults are RABBIT's times leg length / 0.8 m: bit for bit the
    constants on RABBIT, given values kept, the solved gait's options complete."""
    from biped_casadi import robot
    from gait_opt.options import leg_scale
    from gait_opt.running import CLEARANCE, TRAILING_CLEARANCE
    o = RunningOptions()
    assert o.clearance is None and o.trailing_clearance is None
    full = o.for_model(model)
    assert leg_scale(model) == 1.0
    assert full.clearance == CLEARANCE and full.trailing_clearance == TRAILING_CLEARANCE
    g, _ = small
    assert g.options.clearance == CLEARANCE
    assert g.options.trailing_clearance == TRAILING_CLEARANCE
    other = robot("three_link")
    k = other.description.leg_length / model.description.leg_length
    assert k != 1.0
    f = o.for_model(other)
    assert f.clearance == pytest.approx(CLEARANCE * k, rel=1e-15)
    assert f.trailing_clearance == pytest.approx(TRAILING_CLEARANCE * k, rel=1e-15)
    given = RunningOptions(clearance=0.05, trailing_clearance=0.0).for_model(other)
    assert (given.clearance, given.trailing_clearance) == (0.05, 0.0)


# ----------------------------------------------------------- running steps kept in the cache
def test_cache_reuses_a_kept_step(tmp_path, model, small, monkeypatch):
    """The second call is read from the store (no NLP is built: building one would
    fail here); a failed solve is not kept; other options are another entry."""
    import gait_opt.running as running
    from gait_opt.running_cache import running_cache_path
    g, _ = small
    o = g.options
    path = running_cache_path(model, o, tmp_path)
    assert running_cache_path(model, RunningOptions(speed=SPEED, n_stance=6, n_flight=4),
                              tmp_path) == path            # lengths filled in: the same key
    assert running_cache_path(model, dataclasses.replace(o, mu=0.7), tmp_path) != path
    path.parent.mkdir(parents=True)
    g.save(path)                                            # as a first call keeps it
    def no_solve(*a, **k):
        raise AssertionError("an NLP was built")
    monkeypatch.setattr(running, "_phase", no_solve)
    said = []
    back = optimize_running(model, o, cache=True, cache_dir=tmp_path, progress=said.append)
    assert back.solver_stats["cache"] == "hit" and back.solver_stats["cache_file"] == str(path)
    assert said == []
    assert back.cost == g.cost and np.array_equal(back.x_stance, g.x_stance)
    # another option: solved again (and here it fails: one iteration), not kept
    monkeypatch.undo()
    bad = optimize_running(model, dataclasses.replace(o, ipopt={"max_iter": 1}), cache=True,
                           cache_dir=tmp_path, progress=said.append)
    assert not bad.success and bad.solver_stats["cache"].startswith("computed (no kept step)")
    assert "not kept" in bad.solver_stats["cache"] and len(said) == 1
    assert not running_cache_path(model, bad.options, tmp_path).exists()


def test_cache_recomputes_a_damaged_or_foreign_file(tmp_path, model, small):
    from gait_opt.running_cache import cached_running, running_cache_path
    g, _ = small
    path = running_cache_path(model, g.options, tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text("{broken")
    fresh = lambda: dataclasses.replace(g, solver_stats=dict(g.solver_stats))  # noqa: E731
    out = cached_running(model, g.options, tmp_path, None, fresh, RunningGait.load)
    assert out.solver_stats["cache"].startswith("computed (") and "cannot read" in \
        out.solver_stats["cache"]
    assert RunningGait.load(path).cost == g.cost             # replaced by the new one
    dataclasses.replace(g, options=dataclasses.replace(g.options, mu=0.5)).save(path)
    out = cached_running(model, g.options, tmp_path, None, fresh, RunningGait.load)
    assert out.solver_stats["cache"] == "computed (made with other options)"
    assert cached_running(model, g.options, tmp_path, None, fresh, RunningGait.load).solver_stats["cache"] == "hit"


def test_command_line_reuses_a_kept_step(tmp_path, monkeypatch, capsys, model, small):
    """biped running says when it reused a kept step; --no-cache solves again."""
    from analysis.cli import main
    from gait_opt.running_cache import running_cache_path
    g, _ = small
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path / "cache"))
    path = running_cache_path(model, g.options)
    path.parent.mkdir(parents=True)
    g.save(path)
    args = ["running", "--intervals", "6", "4", "--out", str(tmp_path / "r.json")]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"reused the running step kept in {path}")
    assert RunningGait.load(tmp_path / "r.json").cost == g.cost
    assert main([*args, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["solver"]["cache"] == "hit"
    assert main([*args, "--no-cache", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert "cache" not in s["solver"] and s["cost"] == pytest.approx(g.cost, rel=1e-6)


def test_a_file_from_before_the_takeoff_cone_says_so(tmp_path, small):
    """A step saved before ``takeoff_cone_rate`` existed was solved without it: loaded,
    its options say False, not the new default."""
    g, _ = small
    body = json.loads(g.save(tmp_path / "new.json").read_text())
    assert RunningGait.load(tmp_path / "new.json").options.takeoff_cone_rate is True
    del body["options"]["takeoff_cone_rate"]
    (tmp_path / "old.json").write_text(json.dumps(body))
    assert RunningGait.load(tmp_path / "old.json").options.takeoff_cone_rate is False


def test_a_file_from_before_the_friction_margin_says_so(tmp_path, small):
    """A step saved before ``mu_margin`` existed was solved with the cones at mu: loaded,
    its margin is 0, not the new default."""
    g, _ = small
    body = json.loads(g.save(tmp_path / "new.json").read_text())
    assert RunningGait.load(tmp_path / "new.json").options.mu_margin == MU_MARGIN > 0
    del body["options"]["mu_margin"]
    (tmp_path / "old.json").write_text(json.dumps(body))
    assert RunningGait.load(tmp_path / "old.json").options.mu_margin == 0.0


# ----------------------------------------------------------- the friction margin
def _cone_ratios(model, g):
    """(largest |Fx| - (mu - mu_margin) Fz over the stance points, N; the same on the
    interpolant over the last stance interval, where the force falls to the cone's apex,
    N; the landing impulse's |Fx| / Fz), from the exact model, not from the NLP."""
    fl = flight_model(model)
    n, o = model.nq, g.options
    mu = o.mu - o.mu_margin
    xs = g.x_stance
    Fz, Fx = (np.array(v).ravel() for v in fl.takeoff_guard.map(xs.shape[1])(xs[:n], xs[n:],
                                                                              g.u_stance))
    last = (1 - np.linspace(0.0, 1.0, 201)[1:]) / o.n_stance     # fractions of the stance
    tn = g.t_stance
    x, u = hermite_simpson(tn, xs, phase_rhs(model, "stance")(xs, g.u_stance), g.u_stance,
                           tn[-1] * (1 - last))
    Fz_d, Fx_d = (np.array(v).ravel() for v in fl.takeoff_guard.map(x.shape[1])(x[:n], x[n:], u))
    xf, ne = g.x_flight, fl.ne
    F = np.array(fl.landing_swing(xf[:ne, -1], xf[ne:, -1])[2]).ravel()
    return (float(np.max(np.abs(Fx) - mu * Fz)), float(np.max(np.abs(Fx_d) - mu * Fz_d)),
            float(abs(F[0]) / F[1]))


def test_friction_margin_holds_at_the_solution(model):
    """At 2 m/s (6 + 4 grid) the landing impulse of the gait without a margin sits on
    the cone's edge; with the default margin every cone of the NLP holds at mu -
    mu_margin (the stance points, the last interval on the interpolant, the impulse), the
    impulse is moved off mu by the margin, and the cost rises by less than 1 %."""
    o = RunningOptions(speed=2.0, n_stance=6, n_flight=4)
    assert o.mu_margin == MU_MARGIN > 0
    on = optimize_running(model, o)
    off = optimize_running(model, dataclasses.replace(o, mu_margin=0.0))
    assert on.success and off.success
    weight = model.description.total_mass * model.description.gravity
    nodes, last, impulse = _cone_ratios(model, on)
    assert nodes <= 1e-6 * weight and last <= 1e-6 * weight
    assert impulse <= o.mu - o.mu_margin + 1e-7
    assert _cone_ratios(model, off)[2] >= o.mu - 1e-6             # on the edge without it
    assert check_running(model, on).impulse_ratio == pytest.approx(impulse, abs=1e-12)
    assert off.cost <= on.cost * (1 + 1e-9) and on.cost <= 1.01 * off.cost


def test_default_gait_keeps_the_margin(model, running_gait):
    """The shared 1.5 m/s step (default options and grid) keeps every cone at mu -
    mu_margin, as solved."""
    assert running_gait.options.mu_margin == MU_MARGIN
    weight = model.description.total_mass * model.description.gravity
    nodes, last, impulse = _cone_ratios(model, running_gait)
    assert nodes <= 1e-6 * weight and last <= 1e-6 * weight
    assert impulse <= running_gait.options.mu - MU_MARGIN + 1e-7


def test_command_line_passes_the_margin(tmp_path, monkeypatch, capsys, small):
    """--mu-margin reaches the options solved; with --gait (a saved step) it is refused."""
    from analysis.cli import main, running as cli
    g, _ = small
    seen = []

    def solve(model, opts, **kw):
        seen.append(opts)
        return dataclasses.replace(g, solver_stats={"success": False})
    monkeypatch.setattr(cli, "optimize_running", solve)
    out = tmp_path / "r.json"
    assert main(["running", "--mu-margin", "0.1", "--out", str(out)]) == 2
    assert [o.mu_margin for o in seen] == [0.1] and "did not converge" in capsys.readouterr().err
    g.save(out)
    assert main(["running", "--gait", str(out), "--mu-margin", "0.1"]) == 2
    assert "--mu-margin" in capsys.readouterr().err
