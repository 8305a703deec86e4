"""The running controller in MuJoCo (biped_casadi.mujoco.running, biped mujoco-running):
RABBIT's 1.5 m/s step (solved once per session, from the on-disk cache after the first
time) under PD Kp 400, Kd 30, the stable design M1 = (0, 0.95, 0.95, 0) of
docs/howto/running.md against plain tracking M1 = 0.

The deviations are measured from the collocated landing state (1.1e-4 from the exact
fixed point: far below MuJoCo's stride-to-stride jitter of tenths of a rad/s, so the
exact map is not built here).  Runs at dt 1 ms unless said.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from analysis.cli import main as biped_main
from biped_casadi.control.running import RunningController
from biped_casadi.mujoco import STIFF, ContactSettings
from biped_casadi.mujoco.running import (RUN_OUTCOMES, RunningLoop, decay_rate,
                                         fit_running_map, run_in_mujoco)

mujoco = pytest.importorskip("mujoco")

STABLE_M1 = (0.0, 0.95, 0.95, 0.0)
KP, KD = 400.0, 30.0
FINE = ContactSettings(timestep=0.001)


@pytest.fixture(scope="session")
def run_gait15(running_gait):
    return running_gait


@pytest.fixture(scope="session")
def stable_ctl(model, run_gait15):
    return RunningController(model, run_gait15, KP, KD, M1=STABLE_M1)


@pytest.fixture(scope="session")
def loop_fine(stable_ctl):
    return RunningLoop(stable_ctl, FINE)


@pytest.fixture(scope="session")
def stable_run(loop_fine):
    """30 strides from the landing state with 0.03 rad on every angle."""
    x0 = loop_fine.x_star.copy()
    x0[:5] += 0.03
    return loop_fine.run(x0, 30)


@pytest.fixture(scope="session")
def plain_run(stable_ctl):
    return run_in_mujoco(stable_ctl.with_gains(M1=np.zeros(4)), None, 30, FINE)


def test_stable_design_runs_its_strides(stable_run, run_gait15):
    r = stable_run
    assert r.status == "ran" and r.success and r.strides_run == 30
    X = r.landing_states
    assert X.shape == (31, 10) and np.all(np.isfinite(X))
    for s in r.strides:
        assert s.stance > 0 and s.flight > 0 and np.isfinite(s.deviation)
        assert abs(s.slip) < 0.05 and s.peak_torque < 2 * r.torque_limit
    # after the perturbation's first strides (1.80, 1.28, 1.36 m/s measured), the speed
    # stays near the gait's: the run neither stalls nor runs away
    v = np.array([s.speed for s in r.strides[3:]])
    assert np.all(np.abs(v / run_gait15.speed - 1) < 0.1), v
    d = r.to_dict()
    json.dumps(d, allow_nan=False)
    assert d["strides_run"] == 30 and len(d["strides"]) == 30


def test_stable_design_forgets_a_perturbation(stable_run):
    """The deviation after the first stride (the perturbation moved onto the map's modes)
    falls to MuJoCo's jitter level: the median over strides 10-30 is well below it."""
    d = np.array(stable_run.deviations)
    assert d[1] > 0.5                              # a perturbation large against the jitter
    assert np.median(d[10:]) < 0.35 * d[1], d


def test_plain_tracking_falls_within_a_few_strides(plain_run, stable_run):
    """The exact map's 7.1 per stride: MuJoCo's run stops early, its deviation growing."""
    r = plain_run
    assert r.status in RUN_OUTCOMES and r.status != "ran" and not r.success
    assert r.strides_run <= 5, r.message
    assert r.message.startswith(f"stride {r.strides_run + 1}:")
    d = np.array(r.deviations)
    assert d[-1] > 2 * d[1] > 0
    assert stable_run.strides_run == 30


def test_phase_durations_follow_the_reference(stable_run, run_gait15):
    """Stance and flight against the gait's.  Tolerances from the runs measured (docs:
    Running in MuJoCo): at stiff contact the loaded foot chatters and leaves the floor a
    few ms before the rigid model's takeoff (stance 0.3 to 2 % short at 1 ms), and the
    landing states' jitter moves single flights by up to 8 %; the mean over the strides
    is closer."""
    st = np.array([s.stance for s in stable_run.strides[3:]])
    fl = np.array([s.flight for s in stable_run.strides[3:]])
    Ts, Tf = run_gait15.T_stance, run_gait15.T_flight
    assert np.all(np.abs(st / Ts - 1) < 0.04), st
    assert np.all(np.abs(fl / Tf - 1) < 0.15), fl
    # the mean flight: 5.3 % long on the gait without the friction margin, 6.2 % with the
    # default margin 0.05 (dt 1 ms, 0.02 and 0.03 rad on every angle alike)
    assert abs(st.mean() / Ts - 1) < 0.025 and abs(fl.mean() / Tf - 1) < 0.08


def test_default_time_step_runs_too(stable_ctl):
    r = run_in_mujoco(stable_ctl, None, 30, STIFF)
    assert r.status == "ran" and r.settings["timestep"] == 0.002


def test_fitted_stride_map_is_stable(stable_ctl):
    """MuJoCo's stride map, fitted on a long run's landing states, contracts (the exact
    spectral radius is 0.41; the same fit of the exact map with MuJoCo's residuals gives
    0.49 to 0.59; MuJoCo's measured 0.58 at 1 ms, 0.46 at 2 ms on 300 strides)."""
    r = run_in_mujoco(stable_ctl, None, 200, STIFF)
    f = fit_running_map(r)
    assert f.status == "ok" and f.pairs == 199
    assert f.max_abs < 0.95 and f.max_abs + 3 * f.max_abs_spread < 1.1
    assert np.array(f.A).shape == (10, 10) and 0 < f.relative_residual < 1
    json.dumps(f.to_dict(), allow_nan=False)


def test_flight_clock_starts_at_the_model_guard(stable_run, loop_fine):
    """By default the flight clock starts where the rigid model's takeoff guard crossed
    zero on MuJoCo's states: within a few ms of MuJoCo's first zero-force state, in
    every stride; 'contact' keeps the first zero-force state (no gap recorded)."""
    gaps = np.array([s.takeoff_guard_gap for s in stable_run.strides])
    assert loop_fine.takeoff_clock == "guard" and np.all(np.isfinite(gaps))
    assert np.all(np.abs(gaps) < 0.015), gaps        # measured: -3 to +7.3 ms
    assert loop_fine.at(timestep=0.002).takeoff_clock == "guard"
    r = RunningLoop(loop_fine.controller, FINE, takeoff_clock="contact").run(None, 3)
    assert r.status == "ran" and all(np.isnan(s.takeoff_guard_gap) for s in r.strides)


def test_guard_clock_takes_out_most_of_the_jitter(stable_ctl):
    """At dt 2 ms, MuJoCo's takeoff scatters by a few ms with the contact's chatter; the
    flight clock started at the model's guard leaves a smaller stride-to-stride spread of
    the landing states (300 strides: 0.15 against 0.61, largest component's std)."""
    spread = {}
    for clock in ("guard", "contact"):
        r = run_in_mujoco(stable_ctl, None, 40, STIFF, takeoff_clock=clock)
        assert r.status == "ran"
        spread[clock] = float(np.max(np.std(r.landing_states[10:], axis=0)))
    assert spread["guard"] < 0.6 * spread["contact"], spread


def test_stride_flight_clock_continues_the_stance_clock(stable_ctl, run_gait15):
    """``flight_clock='stride'`` gives the flight law the time since landing less
    T_stance, the exact map's 'stride' clock: in the first stride (landing at 0) its
    first flight time is the 'takeoff' clock's plus the stance's duration less T_stance
    (the two runs are the same until then)."""
    first = {}
    for clock in ("takeoff", "stride"):
        loop = RunningLoop(stable_ctl, FINE, flight_clock=clock)
        law, times = loop._flight_law, []
        loop._flight_law = lambda qe, dqe, t, law=law, times=times: times.append(t) or \
            law(qe, dqe, t)
        r = loop.run(None, 1)
        assert r.status == "ran" and loop.flight_clock == clock
        first[clock] = (times[0], r.strides[0].stance)
    (t0, stance0), (t1, stance1) = first["takeoff"], first["stride"]
    assert stance1 == stance0 and 0 < t0 < 0.02
    assert t1 == pytest.approx(t0 + stance0 - run_gait15.T_stance, abs=1e-12)


def test_fit_and_decay_need_strides(plain_run):
    assert fit_running_map(plain_run).status == "failed"
    assert np.isnan(decay_rate(plain_run)["rate"])


@pytest.mark.parametrize("kw, words", [
    (dict(max_slip=0), "max_slip"),
    (dict(time_limits=1.0), "time_limits"),
    (dict(min_stance=1.5), "min_stance"),
    (dict(liftoff_time=-1), "liftoff_time"),
    (dict(takeoff_clock="late"), "takeoff_clock"),
    (dict(flight_clock="late"), "flight_clock"),
    (dict(fixed_point=[1, 2]), "fixed_point"),
    (dict(settings="stiff"), "settings"),
])
def test_bad_loop_arguments(stable_ctl, kw, words):
    with pytest.raises(ValueError, match=words):
        RunningLoop(stable_ctl, **kw)


def test_bad_run_arguments(loop_fine, run_gait15):
    with pytest.raises(ValueError, match="controller"):
        RunningLoop(run_gait15)
    with pytest.raises(ValueError, match="strides"):
        loop_fine.run(None, 0)
    with pytest.raises(ValueError, match="start"):
        loop_fine.run(np.zeros(3), 1)


def test_a_saturating_law_is_clipped_in_the_loop(model, run_gait15, loop_fine):
    """With saturate=True the loop's Python law gives the torques clipped at the limit,
    as the controller's C export does (so the two runs' records compare); without it,
    the law as it is."""
    sat = RunningController(model, run_gait15, KP, KD, M1=STABLE_M1, saturate=True,
                            torque_limit=60.0)
    loop = RunningLoop(sat, FINE)
    for phase, n in (("stance", 5), ("flight", 7)):
        X = np.asarray(getattr(run_gait15, f"x_{phase}"), float)
        q, dq = X[:n, 3] + 0.3, X[n:, 3] + 3.0
        u = getattr(loop_fine, f"_{phase}_law")(q, dq, 0.1)[0].ravel()
        if phase == "stance":
            assert np.max(np.abs(u)) > 60.0
        clipped = getattr(loop, f"_{phase}_law")(q, dq, 0.1)[0].ravel()
        assert np.array_equal(clipped, np.clip(u, -60.0, 60.0))


@pytest.fixture(scope="session")
def gait_file(run_gait15, tmp_path_factory):
    return str(run_gait15.save(tmp_path_factory.mktemp("runmj") / "run15.json"))


def test_command_json(gait_file, capsys):
    rc = biped_main(["mujoco-running", "--gait", gait_file, "--strides", "3", "--timestep",
                     "0.001", "--json"])
    r = json.loads(capsys.readouterr().out)
    assert rc == 0 and r["status"] == "ran" and r["strides_run"] == 3
    assert r["fixed_point_kind"] == "collocated" and r["settings"]["timestep"] == 0.001
    assert r["controller"]["M1"] == list(STABLE_M1) and r["takeoff_clock"] == "guard"
    assert r["flight_clock"] == "takeoff"
    assert all(math.isfinite(s["takeoff_guard_gap"]) for s in r["strides"])


def test_command_plain_tracking_exits_1(gait_file, capsys):
    rc = biped_main(["mujoco-running", "--gait", gait_file, "--m1", "0", "0", "0", "0",
                     "--strides", "10"])
    out = capsys.readouterr().out
    assert rc == 1 and "M1 = [0.0, 0.0, 0.0, 0.0]" in out


@pytest.mark.parametrize("argv, words", [
    (["--strides", "0"], "--strides"),
    (["--m1", "1", "2"], "--m1"),
    (["--kp", "-1"], "--kp"),
    (["--fit", "5"], "--fit"),
    (["--perturb", "nan"], "--perturb"),
    (["--timestep", "-1"], "--timestep"),
    (["--solref", "0.001"], "--solref"),
    (["--takeoff-clock", "late"], "--takeoff-clock"),
])
def test_command_bad_input_is_one_line_and_exit_2(gait_file, argv, words, capsys):
    assert biped_main(["mujoco-running", "--gait", gait_file] + argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1 and words in err, err


def test_command_missing_gait_file(tmp_path, capsys):
    assert biped_main(["mujoco-running", "--gait", str(tmp_path / "none.json")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "--gait" in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_command_fit_with_exact_map_reports_the_reference(gait_file, capsys):
    """--exact --fit: the fit also run on the exact map with its own residuals."""
    rc = biped_main(["mujoco-running", "--gait", gait_file, "--strides", "2", "--exact",
                     "--fit", "60", "--json"])
    r = json.loads(capsys.readouterr().out)
    f = r["fit"]
    assert rc == 0 and f["status"] == "ok"
    assert abs(f["reference_radius"] - r["exact"]["spectral_radius"]) < 1e-9
    assert f["reference_max_abs"] > f["reference_radius"] and f["reference_max_abs_spread"] > 0
