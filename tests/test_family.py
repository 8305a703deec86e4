"""Gait families by continuation (gait_opt.gait_family): every member an exact orbit of
the problem at its speed, the same optimum as a cold solve, the file and its resumption,
gaits between the members, folds, the figures against speed, and the command line."""
from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest

from analysis import vc_eigenvalue
from analysis.cli import main as biped_main
from analysis.gait_metrics import actuator_work, cost_of_transport, family_figures
from analysis.reporting.plots import gait_family_plot, save_figures
from biped_casadi.caching import digest
from gait_opt import (ORBIT_TOL, Gait, GaitFamily, GaitFileError, gait_family,
                      optimize_gait, parse_speed_range, speed_range)

SPEEDS = (0.7, 0.75, 0.8)


@pytest.fixture(scope="module")
def family_path(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("family") / "family.json"
    gait_family(model, SPEEDS, path=path)
    return path


@pytest.fixture(scope="module")
def family(family_path, model):
    return GaitFamily.load(family_path, model)


# ------------------------------------------------------------------ speed grids
def test_speed_range_is_the_grid():
    v = parse_speed_range("0.4:1.2:0.05")
    assert v.size == 17 and v[0] == 0.4 and v[-1] == 1.2
    assert np.allclose(np.diff(v), 0.05, rtol=0, atol=1e-12)
    assert speed_range(0.3, 1.3, 0.05).size == 21


@pytest.mark.parametrize("text, words", [
    ("0.8:0.8:0.05", "empty"), ("1.0:0.5:0.05", "reversed"), ("nan:1:0.1", "finite"),
    ("0.5:inf:0.1", "finite"), ("0.5:1", "A:B:STEP"), ("a:b:c", "A:B:STEP"),
    ("0.5:1:0", "step must be positive"), ("0.5:1:-0.1", "step must be positive"),
    ("-1:1:0.5", "positive"), ("0.5:1.02:0.05", "whole number"),
    ("0.5:1:0.00001", "more than"), ("", "A:B:STEP")])
def test_bad_speed_ranges(text, words):
    with pytest.raises(ValueError, match="speeds") as e:
        parse_speed_range(text)
    assert words in str(e.value)


def test_bad_speed_sequences(model):
    for speeds, words in (([0.7], "2 to"), ([0.8, 0.7], "increasing"),
                          ([0.7, math.nan], "finite"), ([0.5, 4.5], "out of reach")):
        with pytest.raises(ValueError, match=words):
            gait_family(model, speeds)


# ------------------------------------------------------------- the short family
def test_every_member_is_an_exact_orbit_at_its_speed(family):
    assert family.success and family.status == "complete"
    assert list(family.member_speeds) == list(SPEEDS)
    for g, r, v in zip(family.gaits, family.records, SPEEDS):
        res = g.orbit_residual()
        assert res["worst"] <= ORBIT_TOL
        assert r.orbit_residual == pytest.approx(res["worst"], abs=1e-13)
        assert g.options.speed == v
        assert g.speed == pytest.approx(v, abs=1e-9)          # step length / T
        assert g.violations() == [] and r.violations == []
        assert g.reintegration_error() < 1e-8                 # the unactuated row holds


def test_members_are_the_cold_solves_optimum(model, family):
    """Continuation lands on the optimum a cold solve finds, with far fewer iterations."""
    from gait_opt.optimize import _solve
    cold = _solve(model, speed=0.75)
    g = family.gait(0.75)
    assert g.T == pytest.approx(cold.gait.T, abs=1e-7)
    assert np.max(np.abs(g.alpha - cold.gait.alpha)) < 1e-6
    assert all(r.iterations < cold.iterations / 2 for r in family.records[1:])


def test_member_refined_like_a_cold_solve(model):
    """At 1.35 m/s the friction cone is exceeded between the nodes: the member's node
    margin is found from none, as a cold solve finds it, and the gaits agree."""
    fam = gait_family(model, (1.3, 1.35))
    rec, g = fam.records[1], fam.gaits[1]
    from gait_opt.optimize import _solve
    cold = _solve(model, speed=1.35)
    assert set(rec.margins) == {"friction cone"} and rec.violations == []
    assert cold.refinements[-1]["margins"]["friction cone"] == pytest.approx(
        rec.margins["friction cone"], rel=1e-6)
    assert g.T == pytest.approx(cold.gait.T, abs=1e-8) and g.violations() == []


def test_active_constraints_are_at_their_bounds(family):
    """The knee limits reported active: some Bezier coefficient of a knee at 0 rad."""
    g, r = family.gaits[0], family.records[0]
    knees = np.r_[g.alpha[0], g.alpha[3]]          # RABBIT: q2 (stance), q5 (swing)
    assert ("knee limits" in r.active) == bool(np.min(np.abs(knees)) < 1e-6)


# --------------------------------------------------------------- the file
def test_family_file_round_trip(family_path, family, model, tmp_path):
    again = GaitFamily.load(family_path)
    for a, b in zip(family.gaits, again.gaits):
        assert np.array_equal(a.alpha, b.alpha) and a.T == b.T
    assert again.to_dict() == family.to_dict()
    # a member written out alone is a gait file
    body = json.loads(family_path.read_text())["members"][1]
    (tmp_path / "member.json").write_text(json.dumps(body))
    g = Gait.load(tmp_path / "member.json", model)
    assert g.T == family.gaits[1].T


def _resign(body):
    body = dict(body)
    body.pop("sha256")
    body["sha256"] = digest(body)
    return body


def test_family_file_tampering(family_path, tmp_path):
    body = json.loads(family_path.read_text())
    bad = copy.deepcopy(body)
    bad["records"][0]["T"] += 1e-3
    (tmp_path / "a.json").write_text(json.dumps(bad))
    with pytest.raises(GaitFileError, match="checksum"):
        GaitFamily.load(tmp_path / "a.json")
    bad = copy.deepcopy(body)                   # a member that is no longer an orbit
    bad["members"][1]["solution"]["T"] += 1e-4
    bad["members"][1] = _resign(bad["members"][1])
    (tmp_path / "b.json").write_text(json.dumps(_resign(bad)))
    with pytest.raises(GaitFileError, match="member 2 is not a periodic orbit"):
        GaitFamily.load(tmp_path / "b.json")
    bad = copy.deepcopy(body)
    bad["records"][1]["speed"] = 0.76
    (tmp_path / "d.json").write_text(json.dumps(_resign(bad)))
    with pytest.raises(GaitFileError, match="records' speeds"):
        GaitFamily.load(tmp_path / "d.json")
    bad = copy.deepcopy(body)
    bad["members"] = bad["members"][:2]
    (tmp_path / "c.json").write_text(json.dumps(_resign(bad)))
    with pytest.raises(GaitFileError, match="one gait per record"):
        GaitFamily.load(tmp_path / "c.json")


def _member_less(body: dict) -> dict:
    """A family file's content as an interrupted solve leaves it before its first member."""
    body = copy.deepcopy(body)
    body.update(records=[], members=[], status="partial", message="0 of 3 speeds done")
    return body


@pytest.mark.parametrize("edit, words", [
    # the records, events and end steer what is read back (a record's branch decides
    # whether gaits are interpolated across it); a wrong type was taken as it came
    (lambda b: b["records"][0].update(branch="b"), "record 1: 'branch' must be a count"),
    (lambda b: b["records"][0].update(T="x"), "record 1: 'T' must be a positive number"),
    (lambda b: b["records"][1].update(status=5), "record 2: 'status' must be 'ok' or"),
    (lambda b: b["records"][0].update(active=5), "'active' must be a list"),
    (lambda b: b["records"][0].update(violations=["x"]), "'violations' must be a list of"),
    (lambda b: b["records"][0].update(iterations=-1), "'iterations' must be a count"),
    (lambda b: b.update(events=[5]), "event 1 must be an object"),
    (lambda b: b.update(events=[dict(speed=0.7, change="grew", constraint=None,
                                     detail="")]), "event 1 must be an object"),
    (lambda b: b.update(end={"speed": "x"}), "'end' must be null or an object"),
    (lambda b: b.update(message=5), "'message' must be a string"),
    (lambda b: b.update(total_time="x"), "'total_time' must be a number"),
    # 'complete' with a member removed: a rerun of its --speeds took it as finished
    (lambda b: (b["records"].pop(), b["members"].pop()),
     "status 'complete' does not match its contents (2 of 3 speeds solved"),
    (lambda b: b.update(status="partial"), "status 'partial' does not match"),
])
def test_family_file_fields_of_the_wrong_type(family_path, tmp_path, edit, words):
    body = json.loads(family_path.read_text())
    edit(body)
    (tmp_path / "e.json").write_text(json.dumps(_resign(body)))
    with pytest.raises(GaitFileError) as e:
        GaitFamily.load(tmp_path / "e.json")
    assert words in str(e.value) and "e.json" in str(e.value)


def test_interrupted_family_resumes(model, family, tmp_path):
    path = tmp_path / "f.json"
    calls = []

    def stop(line):
        calls.append(line)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        gait_family(model, SPEEDS, path=path, progress=stop)
    partial = GaitFamily.load(path)
    assert partial.status == "partial" and len(partial) == 1
    done = gait_family(model, SPEEDS, path=path, progress=calls.append)
    assert done.status == "complete" and len(calls) == 1 + 2      # only the missing two
    for a, b in zip(done.gaits, family.gaits):       # equal to IPOPT's tolerance
        assert np.max(np.abs(a.alpha - b.alpha)) < 1e-8 and abs(a.T - b.T) < 1e-8
    calls.clear()
    assert gait_family(model, SPEEDS, path=path, progress=calls.append).success
    assert calls == []                                # a finished family is read back
    with pytest.raises(ValueError, match="path: .* other options or speeds"):
        gait_family(model, (0.7, 0.75), path=path)


# ------------------------------------------------------------ gaits between
def test_gait_between_members(family, model):
    r = family.gait_at(0.725)
    assert r.success and r.status == "ok" and not r.resolved
    g = r.gait
    assert g.orbit_residual()["worst"] <= ORBIT_TOL and g.violations() == []
    assert g.speed == pytest.approx(0.725, abs=1e-9)
    # the interpolant was not an orbit; its residual is the polish's first
    assert r.interpolant_residual == g.solver_stats["family_interpolation"][
        "polish_residuals"][0]
    assert 1e-9 < r.interpolant_residual < 1e-3 and 0 < r.parameter_change < 1e-3
    best = optimize_gait(model, speed=0.725)         # near the optimum there, not equal
    assert 0 < abs(g.T - best.T) < 1e-4
    assert g.cost == pytest.approx(best.cost, rel=1e-6)


def test_gait_at_members_resolve_and_outside(family):
    m = family.gait_at(0.75)
    assert m.status == "member" and m.gait is family.gait(0.75)
    r = family.gait_at(0.775, resolve=True)
    assert r.success and r.resolved and r.iterations > 0
    for bad in (0.69, 0.81, math.nan, "x"):
        with pytest.raises(ValueError, match="speed"):
            family.gait_at(bad)


# --------------------------------------------------------------------- folds
def test_fold_between_branches(model):
    """RABBIT's branch from the default guess folds between 1.15 and 1.2 m/s (measured
    at 1.1525 +- 0.003 on a fine grid): the solution jumps to another branch there."""
    fam = gait_family(model, (1.1, 1.15, 1.2))
    assert fam.success and [r.branch for r in fam.records] == [0, 0, 1]
    fold = [e for e in fam.events if e["change"] == "branch"]
    assert len(fold) == 1 and 1.15 <= fold[0]["speed_low"] < fold[0]["speed_high"] <= 1.2
    assert fold[0]["speed_high"] - fold[0]["speed_low"] <= 0.05 / 4 + 1e-12
    r = fam.gait_at(1.17)                       # no interpolation across the fold
    assert r.resolved and r.success and math.isnan(r.interpolant_residual)
    stop = gait_family(model, (1.1, 1.15, 1.2), across_folds=False)
    assert stop.status == "ended" and stop.end["reason"] == "fold"
    assert list(stop.member_speeds) == [1.1, 1.15] and not stop.success


def test_three_link_family(model3):
    fam = gait_family(model3, (0.7, 0.75, 0.8))
    assert fam.success
    for g in fam.gaits:
        assert g.orbit_residual()["worst"] <= ORBIT_TOL and g.violations() == []


# --------------------------------------------------------------- the figures
def test_actuator_work_is_the_energy_change(gait):
    """The signed work of the actuators over the step equals E(T-) - E(0+), which the
    impact dissipates (periodic orbit); the absolute work bounds it."""
    m = gait.model
    e0 = float(m.energy(gait.q(0.0), gait.dq(0.0))[2])
    eT = float(m.energy(gait.q(gait.T), gait.dq(gait.T))[2])
    qp, dqp = m.impact(gait.q(gait.T), gait.dq(gait.T))
    assert actuator_work(gait, absolute=False) == pytest.approx(eT - e0, rel=1e-6)
    assert eT - float(m.energy(qp, dqp)[2]) == pytest.approx(eT - e0, rel=1e-9)
    assert actuator_work(gait) > actuator_work(gait, absolute=False) > 0
    assert cost_of_transport(gait) == pytest.approx(cost_of_transport(gait, 16001),
                                                    rel=1e-6)


def test_family_figures_and_plot(family, model, tmp_path):
    f = family_figures(family)
    assert f.success and f.speed == list(SPEEDS)
    g = family.gaits[2]
    assert f.vc_eigenvalue[2] == vc_eigenvalue(g).eigenvalue
    assert f.peak_torque[2] == g.check()["max_abs_torque"]
    assert f.period == [g.T for g in family.gaits]
    assert f.torso_lean == [g.torso_lean() for g in family.gaits]
    assert max(f.torso_lean) < f.fall_bound and "fall bound" not in f.message
    assert all(0 < c < 1 for c in f.cost_of_transport)
    files = save_figures({"gait_family": gait_family_plot(f)}, tmp_path)
    assert (tmp_path / "gait_family.png").stat().st_size > 10_000 and len(files) == 1


# ------------------------------------------------------------- command line
def _run(capsys, *argv):
    rc = biped_main(["gait", *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_cli_family_and_gait_between(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc, out, err = _run(capsys, "--speeds", "0.7:0.8:0.05", "--out", "f.json", "--json",
                        "--plot", "figs")
    assert rc == 0 and err == ""
    d = json.loads(out)
    assert [m["speed"] for m in d["members"]] == list(SPEEDS)
    assert all(m["orbit_residual"] <= ORBIT_TOL for m in d["members"])
    assert (tmp_path / "figs" / "gait_family.png").exists()
    rc, out, _ = _run(capsys, "--family", "f.json", "--speed", "0.76", "--out", "g.json",
                      "--json", "--plot", "one")
    d = json.loads(out)
    assert rc == 0 and d["status"] == "ok" and d["interpolant_residual"] > 0
    assert (tmp_path / "one" / "gait_stick.png").exists()
    g = Gait.load(tmp_path / "g.json")
    assert g.speed == pytest.approx(0.76, abs=1e-9)


@pytest.mark.parametrize("argv, words", [
    (["--speeds", "0.8:0.8:0.05"], "--speeds: the range 0.8:0.8 is empty"),
    (["--speeds", "1:0.5:0.05"], "reversed"),
    # a step longer than the range: the one speed 0.7 ('a family needs 2 ... got 1')
    (["--speeds", "0.7:0.8:1e300"], "--speeds: the step 1e+300 is longer than the range "
                                     "0.7:0.8 (at most 0.1)"),
    (["--speeds", "nan:1:0.1"], "finite"),
    (["--speeds", "0.5-1"], "A:B:STEP"),
    (["--speeds", "-1:1:0.5"], "positive"),
    (["--speeds", "0.5:5:0.5"], "4.5 m/s is out of reach"),
    (["--speeds", "0.5:1:0.1", "--speed", "0.7"], "exclude"),
    (["--family", "missing.json", "--speed", "0.7"], "not found"),
    (["--family", "f.json"], "needs --speed"),
    (["--family", "f.json", "--speed", "0.9"], "outside the family"),
    (["--family", "f.json", "--speed", "0.75", "--mu", "0.5"], "--mu does not apply"),
    (["--resolve"], "--resolve applies"),
    (["--speeds", "0.7:0.8:0.05", "--out", "f.json"], "--out: f.json holds"),
    (["--speeds", "0.7:0.8:0.05", "--out", "f.json/o.json"], "is a file, not a folder"),
])
def test_cli_bad_input(argv, words, capsys, tmp_path, monkeypatch, family_path):
    monkeypatch.chdir(tmp_path)
    body = json.loads(family_path.read_text())
    body["speeds"] = [0.7, 0.75, 0.8, 0.85]     # another request than --speeds 0.7:0.8:0.05
    body.update(status="partial", message="3 of 4 speeds done")      # as such a file says
    (tmp_path / "f.json").write_text(json.dumps(_resign(body)))
    before = sorted(p.name for p in tmp_path.iterdir())
    rc, out, err = _run(capsys, *argv, *([] if "--out" in argv else ["--out", "o.json"]))
    assert rc == 2 and out == "" and words in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("argv", [
    ["gait", "--family", "{f}", "--speed", "0.75", "--out", "g.json"],
    ["simulate", "--gait", "{f}", "--speeds", "0.75", "0.75", "--controller", "vc"],
])
def test_cli_family_without_members(argv, capsys, tmp_path, monkeypatch, family_path):
    """A family file whose solve stopped before its first member: an internal IndexError
    before; one line naming the file, exit 2, nothing written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "f.json").write_text(json.dumps(_resign(_member_less(
        json.loads(family_path.read_text())))))
    rc = biped_main([a.format(f="f.json") for a in argv])
    out, err = capsys.readouterr()
    assert (rc, out) == (2, ""), err
    assert len(err.strip().splitlines()) == 1 and "internal error" not in err, err
    assert "f.json holds no gait yet" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.json"]


def test_cli_family_beyond_its_existence(capsys, tmp_path, monkeypatch):
    """No gait at the first speed: one line, exit 2, nothing written."""
    monkeypatch.chdir(tmp_path)
    rc, out, err = _run(capsys, "--speeds", "3:3.2:0.1", "--out", "f.json")
    assert rc == 2 and out == "" and "no gait at the first speed 3 m/s" in err
    assert not (tmp_path / "f.json").exists()


# ------------------------------------------------------------------ the range
@pytest.mark.slow
def test_rabbit_family_covers_0p4_to_1p2(model):
    fam = gait_family(model, speed_range(0.4, 1.2, 0.05))
    assert fam.success and len(fam) == 17
    for g in fam.gaits:
        assert g.orbit_residual()["worst"] <= ORBIT_TOL and g.violations() == []
        assert g.speed == pytest.approx(g.options.speed, abs=1e-9)
    changes = {(e["change"], e["constraint"]) for e in fam.events}
    assert ("active", "impact impulse cone") in changes and ("branch", None) in changes


@pytest.mark.slow
def test_three_link_family_range(model3):
    fam = gait_family(model3, speed_range(0.3, 2.5, 0.05))
    assert fam.success and len(fam) == 45
    assert all(g.orbit_residual()["worst"] <= ORBIT_TOL for g in fam.gaits)


def test_family_of_a_robot_without_a_torque_limit(capsys, tmp_path, monkeypatch):
    """A URDF without effort limits (an infinite torque limit in the robot's record): the
    family file keeps it as a gait file does, and reads back."""
    from pathlib import Path
    urdf = Path(__file__).resolve().parents[1] / "docs" / "howto" / "walker" / "walker.urdf"
    monkeypatch.chdir(tmp_path)
    rc, out, err = _run(capsys, "--robot", str(urdf), "--torque-limit", "150", "--speeds",
                        "0.7:0.75:0.05", "--out", "f.json")
    assert rc == 0, err
    fam = GaitFamily.load(tmp_path / "f.json")
    assert len(fam) == 2 and math.isinf(fam.model.params.torque_limit)
    assert fam.gait(0.75).options.torque_limit == 150


def test_gait_between_branches_prints_no_nan_and_names_a_fall(capsys, tmp_path, monkeypatch,
                                                              family_path):
    """``biped gait --family F --speed V`` where no interpolant was made (between two
    branches: the gait solved instead) says so instead of 'interpolant residual nan ...',
    and a gait whose torso leans past the fall bound is named as in ``biped gait``."""
    import dataclasses

    from analysis.cli import gait_family as cli_family
    real = GaitFamily.gait_at

    def solved(self, speed, resolve=False):
        r = real(self, speed, resolve=True)
        return dataclasses.replace(r, interpolant_residual=math.nan,
                                   interpolant_orbit_residual=math.nan,
                                   parameter_change=math.nan, T_change=math.nan)

    monkeypatch.setattr(GaitFamily, "gait_at", solved)
    monkeypatch.setattr(cli_family, "torso_fall", lambda g: (2.1, True, 1.5708))
    monkeypatch.chdir(tmp_path)
    rc, out, _ = _run(capsys, "--family", str(family_path), "--speed", "0.76", "--out",
                      "g.json")
    assert rc == 0 and "nan" not in out, out
    assert "interpolant          none" in out
    assert "PAST the simulator's fall bound" in out
    rc, out, _ = _run(capsys, "--family", str(family_path), "--speed", "0.76", "--out",
                      "g.json", "--json")
    d = json.loads(out)
    assert d["torso_past_fall_bound"] is True and d["interpolant_residual"] is None


def test_activations_are_named_in_the_legend_once_each_not_written_across_the_curves():
    from matplotlib.figure import Figure

    from analysis.reporting.plots.speed_family import _mark_activations
    ax = Figure().subplots()
    ax.plot([0.4, 1.2], [0.3, 0.6])
    events = [dict(change="active", constraint="impact impulse cone", speed=1.1),
              dict(change="active", constraint="friction cone", speed=1.15),
              dict(change="active", constraint="friction cone", speed=1.18),
              dict(change="active", constraint="torque limit", speed=0.9)]   # another panel
    _mark_activations(ax, "impact_impulse_ratio", events)
    labels = ax.get_legend_handles_labels()[1]
    assert labels == ["impact impulse cone active from here", "friction cone active from here"]
    assert len(ax.lines) == 1 + 3 and not ax.texts
    styles = {line.get_label(): line.get_linestyle() for line in ax.lines[1:]}
    assert len(set(styles.values()) - {"-"}) == 2           # the two constraints told apart


def test_gait_metrics_name_bad_arguments(gait):
    """n = 0 or 1 trapezoid points were IndexErrors; a path for the gait an
    AttributeError."""
    from analysis.gait_metrics import torso_fall
    for bad in (0, 1, 2.5):
        with pytest.raises(ValueError, match=r"^n \(trapezoid points\) must be an integer >= 2"):
            actuator_work(gait, n=bad)
        with pytest.raises(ValueError, match=r"^n \(trapezoid points\)"):
            cost_of_transport(gait, n=bad)
    for f in (actuator_work, cost_of_transport, torso_fall):
        with pytest.raises(TypeError, match="^gait: a gait is needed"):
            f("gait.json")
    assert actuator_work(gait, n=2) > 0
