"""benchmarks/bench_running_m1.py saves each speed as it finishes and resumes from its
file: a run stopped after one speed, run again, measures only the speeds it lacks; a
file it cannot use (unreadable, another benchmark's, other settings) is one line and
exit code 2.  The measurement itself is replaced by a stand-in (a speed's real row takes
minutes); what is tested is the bookkeeping around it."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import _results  # noqa: E402
from summary_compare import leaves  # noqa: E402
import bench_running_m1 as bench  # noqa: E402


class _Robot:
    class description:
        torque_limit = 150.0


def _row(v):
    return dict(speed=v, plain=5.0 + v, hand=1.0, best_c=dict(c=0.9, radius=0.8),
                chosen=dict(M1=[0.0, 1.0, 1.0, 0.0], spectral_radius=0.5 / v,
                            n_evaluations=3, seconds=1.0))


@pytest.fixture
def env(tmp_path, monkeypatch):
    """The results folder in tmp_path, the robot and the measurement stood in for;
    ``env.run(*args)`` runs the benchmark's main, ``env.calls`` the speeds measured."""
    results = tmp_path / "results"
    monkeypatch.setattr(_results, "RESULTS", results)
    monkeypatch.setattr(bench, "RESULTS", results)
    monkeypatch.setattr(bench, "rabbit", lambda: _Robot)

    class Env:
        calls, stop_after, path = [], None, results / "m1.json"

        @staticmethod
        def run(*args):
            monkeypatch.setattr(sys, "argv", ["bench_running_m1.py", "--name", "m1",
                                              "--out", str(tmp_path), *args])
            bench.main()

    def measure(m, v, a):
        if Env.stop_after is not None and len(Env.calls) == Env.stop_after:
            raise KeyboardInterrupt
        Env.calls.append(v)
        return _row(v)

    monkeypatch.setattr(bench, "measure", measure)
    return Env


def test_interrupted_run_resumes_without_measuring_again(env):
    env.stop_after = 1
    with pytest.raises(KeyboardInterrupt):
        env.run("--speeds", "1.0", "2.0", "1.5")
    assert env.calls == [1.0]
    saved = json.loads(env.path.read_text())         # saved as the first speed finished
    assert [r["speed"] for r in saved["data"]["rows"]] == [1.0]
    assert saved["data"]["foot"] == "sliding" and saved["data"]["max_evaluations"] == 150
    env.stop_after = None
    env.run("--speeds", "1.0", "2.0", "1.5")
    assert env.calls == [1.0, 2.0, 1.5]               # 1.0 not measured again
    saved = json.loads(env.path.read_text())
    assert [r["speed"] for r in saved["data"]["rows"]] == [1.0, 1.5, 2.0]
    assert saved["data"]["rows"][0]["chosen"]["spectral_radius"] == 0.5
    assert "measured" in saved["data"]["rows"][0]
    whats = [r["what"] for r in saved["rows"]]
    assert whats.count("1.5 m/s, chosen M1: spectral radius") == 1 and len(whats) == 12
    env.run("--speeds", "2.0", "3.0")                 # the file's other speeds kept
    assert env.calls == [1.0, 2.0, 1.5, 3.0]
    assert [r["speed"] for r in json.loads(env.path.read_text())["data"]["rows"]] == \
        [1.0, 1.5, 2.0, 3.0]


def _refused(env, capsys, *args):
    before = env.path.read_text()
    with pytest.raises(SystemExit) as e:
        env.run(*args)
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and err.startswith("error: ") and "\n" not in err
    assert env.path.read_text() == before and env.calls == [1.0]    # nothing measured
    return err


def test_other_settings_or_foreign_or_damaged_file_refused(env, capsys):
    env.run("--speeds", "1.0")
    assert "max_evaluations 150 (now 20)" in _refused(env, capsys, "--max-evaluations", "20")
    assert "reserve 5.0 (now 3.0)" in _refused(env, capsys, "--reserve", "3")
    body = json.loads(env.path.read_text())
    del body["data"]["foot"]                          # written before the foot was recorded
    env.path.write_text(json.dumps(body))
    assert "foot not recorded (now sliding)" in _refused(env, capsys)
    body["title"] = "something else"
    env.path.write_text(json.dumps(body))
    assert "not a result of bench_running_m1.py" in _refused(env, capsys)
    env.path.write_text(json.dumps(dict(title=bench.TITLE, data={})))
    assert "not a result of bench_running_m1.py (no 'rows')" in _refused(env, capsys)
    env.path.write_text(env.path.read_text()[:-5])
    assert "not readable JSON" in _refused(env, capsys)
    assert "No such file" in _refused(env, capsys, "--combine", str(env.path) + ".none")


def test_older_file_settings_read_from_its_rows(env):
    """A file written before the settings were saved whole: the grid of c from its rows,
    the reserve from a row that used it (150 - 145 N m), any reserve where none did."""
    want = bench.settings(150, 5.0)
    row = dict(_row(2.5), sweep_c=dict(c=want["c_grid"]), gait_torque_limit=145.0,
               default_gait={})
    body = dict(title=bench.TITLE, date="d", commit="c",
                data=dict(rows=[row], Kp=400.0, Kd=30.0, hand=want["hand"],
                          max_evaluations=150, foot="sliding"))
    env.path.parent.mkdir()
    env.path.write_text(json.dumps(body))
    rows = bench.saved_rows(env.path, want, 150.0)
    assert rows[0]["measured"] == dict(date="d", commit="c")
    with pytest.raises(ValueError, match="reserve 5.0 .now 10"):
        bench.saved_rows(env.path, bench.settings(150, 10.0), 150.0)
    del row["default_gait"]
    env.path.write_text(json.dumps(body))
    assert bench.saved_rows(env.path, bench.settings(150, 10.0), 150.0)
    row["sweep_c"]["c"] = [0.5, 1.0]
    env.path.write_text(json.dumps(body))
    with pytest.raises(ValueError, match="c_grid"):
        bench.saved_rows(env.path, want, 150.0)


def test_saturation_reads_the_saved_choice(env, monkeypatch):
    """benchmarks/running_saturation.py takes its chosen M1 from these files: the row of
    the speed and gait bound, chosen with the sliding foot; anything else is refused."""
    import running_saturation as sat
    env.run("--speeds", "2.5")
    body = json.loads(env.path.read_text())
    body["data"]["rows"][0]["gait_torque_limit"] = 145.0
    env.path.write_text(json.dumps(body))
    monkeypatch.setattr(sat, "RESULTS", env.path.parent)
    assert sat.chosen_m1("m1", 2.5, 145.0) == (0.0, 1.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="no M1 chosen at 2.5 m/s on the gait at the "):
        sat.chosen_m1("m1", 2.5, None)
    with pytest.raises(ValueError, match="no M1 chosen at 2 m/s"):
        sat.chosen_m1("m1", 2.0, 145.0)
    with pytest.raises(ValueError, match="No such file"):
        sat.chosen_m1("none", 2.5, 145.0)
    del body["data"]["foot"]
    env.path.write_text(json.dumps(body))
    with pytest.raises(ValueError, match="foot not recorded, not the sliding one"):
        sat.chosen_m1("m1", 2.5, 145.0)


def test_a_saved_figure_is_named_by_its_path_in_the_checkout(tmp_path, monkeypatch):
    """A results file is committed: a figure drawn in the checkout is saved as
    ``docs/...``, not as this machine's absolute path (a figure elsewhere as given)."""
    monkeypatch.setattr(_results, "RESULTS", tmp_path / "results")
    with _results.Run("figs", "figures") as run:
        run.data["figure"] = [str(ROOT / "docs" / "_static" / "x.png"), "/elsewhere/y.png"]
    saved = json.loads((tmp_path / "results" / "figs.json").read_text())
    assert saved["data"]["figure"] == ["docs/_static/x.png", "/elsewhere/y.png"]


def test_no_committed_result_names_a_file_of_the_machine_that_made_it():
    """The benchmarks page reads the committed results: a file named by an absolute path
    (``/tmp/...`` of the run that made it) points nowhere in a clone."""
    found = {p.name: s for p in sorted((ROOT / "benchmarks" / "results").glob("*.json"))
             for _, s in leaves(json.loads(p.read_text()))
             if isinstance(s, str) and s.startswith("/") and Path(s).suffix in (".png", ".pdf", ".json", ".svg")}
    assert not found, found


def test_the_gait_again_with_the_reserve_where_no_design_is_stable(monkeypatch, capsys):
    """``measure`` optimises the gait again at the limit less the reserve where the
    robot's limit gives no stable design: none feasible, or a choice whose radius is at
    least 1 (RABBIT at 2.5 m/s since the running step keeps its torques within the limit
    between the points); a stable choice is kept as it is."""
    from types import SimpleNamespace
    calls = []

    def speed_row(m, v, max_evaluations, gait_torque_limit=None):
        calls.append(gait_torque_limit)
        rho = radii[len(calls) - 1]
        chosen = None if rho is None else dict(spectral_radius=rho, message=f"radius {rho}")
        feasible = None if rho is None else 1.1        # the plain, hand-picked and best c
        return dict(speed=v, gait_torque_limit=gait_torque_limit, gait_success=True,
                    plain=feasible, hand=feasible, best_c=dict(c=0.7, radius=feasible),
                    hand_message="torque u1 <= 150 N m violated", chosen=chosen)

    monkeypatch.setattr(bench, "speed_row", speed_row)
    monkeypatch.setattr(bench, "_stamp", lambda: {})
    a = SimpleNamespace(max_evaluations=150, reserve=5.0)
    for radii, limits in (([1.07, 0.58], [None, 145.0]), ([None, 0.58], [None, 145.0]),
                          ([0.39], [None])):
        calls.clear()
        row = bench.measure(_Robot, 2.5, a)
        assert calls == limits and row["gait_torque_limit"] == limits[-1]
        assert ("default_gait" in row) == (len(limits) == 2)
        if len(limits) == 2:
            assert row["default_gait"]["chosen"] == (None if radii[0] is None else
                                                     dict(spectral_radius=1.07,
                                                          message="radius 1.07"))
            assert "again with the torque limit 145 N m" in capsys.readouterr().out
    calls.clear()
    radii = [1.07]
    assert "default_gait" not in bench.measure(_Robot, 2.5, SimpleNamespace(
        max_evaluations=150, reserve=0.0)) and calls == [None]
