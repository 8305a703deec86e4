"""`biped reproduce`: re-runs of any mix of modes into the same folder, a failed stage
that skips its dependants (and only them), an interrupted run that leaves the previous
results, the second robot end to end, and the graph's keys that a docstring does not
move.  RABBIT's quick run end to end (and its warm re-run) is tested in
test_reproduce_cluster.py, on the same cold run the cluster's numbers are compared to."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from analysis.pipeline import graph, run_folder
from analysis.pipeline.graph import Figures, Stage, reproduce
from analysis.pipeline.paper import stage_fig2, stage_gait
from analysis.pipeline import figures as F
from task_examples import (after_marker, failing_stage, interrupted_stage, marker_figure,
                           marker_stage, slow_marker_figure)


# ------------------------------------------------- re-runs into the same folder
_GAIT = Stage("gait", stage_gait, model=True, resolution=False,
              figures=(Figures(F.gait_figures),))
LIGHT = (_GAIT, Stage("Fig. 2: 1-D sweeps", stage_fig2, (_GAIT,), figures=(Figures(F.fig2),)),
         Stage("marker", marker_stage, figures=(Figures(marker_figure),)))


@pytest.fixture
def light_stages(monkeypatch, tmp_path):
    """The real gait and Fig. 2 stages, plus a marker stage with a figure; a fresh
    cache."""
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(graph, "STAGES", LIGHT)
    return LIGHT


def _files(folder):
    """Every file under ``folder``: size, mtime."""
    return {p.relative_to(folder).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in folder.rglob("*") if p.is_file()}


def test_full_and_quick_runs_share_a_folder_without_mixing(tmp_path, gait, light_stages):
    out = tmp_path / "rep"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    small = dict(progress=False, animation_steps=0)
    full = reproduce(out, quick=False, line_points=5, **small)
    assert full.success and full.folder == str(out), full.message
    full_files = {k: v for k, v in _files(out).items() if not k.startswith("quick/")}
    quick = reproduce(out, quick=True, line_points=7, **small)
    assert quick.success and quick.folder == str(out / "quick"), quick.message
    # the quick run did not touch the full run's results (nor the user's notes) ...
    assert {k: v for k, v in _files(out).items() if not k.startswith("quick/")} == full_files
    # ... and each report and summary describes its own run
    assert json.loads((out / "summary.json").read_text())["fig2"]["points_per_component"] == 5
    assert json.loads((out / "quick" / "summary.json").read_text())["mode"] == "quick"
    assert "**Full run**" in (out / "report.md").read_text()
    assert "**Quick run**" in (out / "quick" / "report.md").read_text()
    again = reproduce(out, quick=False, line_points=9, **small)
    assert again.success, again.message
    assert json.loads((out / "summary.json").read_text())["marker"]["line_points"] == 9
    assert (out / "notes.txt").read_text() == "mine\n"
    assert not list(out.glob(".staging-*")) and not list(out.rglob("*.tmp*"))


def test_a_figure_still_running_counts_in_its_stage(tmp_path, monkeypatch):
    """A stage's counts include its figures' tasks, also one that finishes after every
    stage (they were counted before the figures had finished: 109 or 110 tasks in the
    same cold run)."""
    from dask.distributed import Client, LocalCluster
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(graph, "STAGES", (Stage("marker", marker_stage,
                                                figures=(Figures(slow_marker_figure),)),))
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      dashboard_address=":0") as cluster, Client(cluster) as client:
        r = reproduce(tmp_path / "rep", line_points=5, progress=False, scheduler=client)
    assert r.success, r.message
    assert r.stages["marker"]["computed"] == 2, r.stages       # the flow and its figure


def test_a_second_run_reads_every_result(tmp_path, gait, light_stages):
    out = tmp_path / "rep"
    first = reproduce(out, line_points=5, progress=False)
    assert all(v["computed"] > 0 for v in first.stages.values()), first.stages
    second = reproduce(out, line_points=5, progress=False)
    assert all(v["computed"] == 0 and v["reused"] > 0 for v in second.stages.values()), \
        second.stages
    assert second.summary["fig2"] == first.summary["fig2"]


def test_a_failed_stage_skips_its_dependants_only(tmp_path, gait, light_stages, monkeypatch):
    out = tmp_path / "rep"
    r = reproduce(out, line_points=5, progress=False)
    assert r.success and (out / "figures" / "marker.png").is_file()
    (out / "figures" / "my_sketch.png").write_bytes(b"mine")
    # the marker stage now fails: its dependant is skipped (no fallback), the others run,
    # and its old figure does not stay beside the new report
    failing = Stage("marker", failing_stage)
    monkeypatch.setattr(graph, "STAGES", (*light_stages[:2], failing,
                                          Stage("after", after_marker, (failing,))))
    r = reproduce(out, line_points=5, progress=False)
    assert not r.success and r.status == "failed" and "marker" in r.message
    st = r.stages
    assert st["marker"]["status"] == "failed" and "on purpose" in st["marker"]["error"]
    assert st["after"]["status"] == "skipped" and "'marker'" in st["after"]["reason"]
    assert st["gait"]["status"] == "ok" and st["Fig. 2: 1-D sweeps"]["status"] == "ok"
    assert not (out / "figures" / "marker.png").exists()
    assert (out / "figures" / "fig2.png").is_file()
    assert (out / "figures" / "my_sketch.png").read_bytes() == b"mine"
    report = (out / "report.md").read_text()
    assert "failed: marker_stage" not in report and "this stage fails on purpose" in report
    assert "skipped: needs 'marker'" in report
    assert "2 of 4 stages not ok" in report


def test_an_interrupted_run_leaves_the_previous_results(tmp_path, gait, light_stages,
                                                        monkeypatch):
    out = tmp_path / "rep"
    reproduce(out, line_points=5, progress=False)
    before = _files(out)
    monkeypatch.setattr(graph, "STAGES", (*light_stages,
                                          Stage("stop", interrupted_stage)))
    with pytest.raises(KeyboardInterrupt):
        reproduce(out, line_points=5, progress=False)
    assert _files(out) == before
    assert not list(out.glob(".staging-*"))


def test_an_interrupted_first_run_leaves_no_empty_folder(tmp_path, light_stages,
                                                         monkeypatch):
    """Ctrl-C before any result: the folders the run made (OUT, OUT/quick) are removed,
    a folder the user made or one with files is kept as it was."""
    monkeypatch.setattr(graph, "STAGES", (Stage("stop", interrupted_stage),))
    new = tmp_path / "new" / "out"
    with pytest.raises(KeyboardInterrupt):
        reproduce(new, quick=True, progress=False)
    assert not (tmp_path / "new").exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    with pytest.raises(KeyboardInterrupt):
        reproduce(mine, quick=True, progress=False)
    assert mine.is_dir() and not list(mine.iterdir())
    (mine / "quick").mkdir()
    (mine / "quick" / "notes.txt").write_text("kept")
    with pytest.raises(KeyboardInterrupt):
        reproduce(mine, quick=True, progress=False)
    assert _files(mine).keys() == {"quick/notes.txt"}


def test_each_kind_of_run_has_its_folder(tmp_path):
    from biped_casadi.model.description import builtin_path
    mine = tmp_path / "my_biped.toml"
    mine.write_text(builtin_path("three_link").read_text())
    rabbit_copy = tmp_path / "rabbit_copy.toml"
    rabbit_copy.write_text(builtin_path("rabbit").read_text())
    out = tmp_path / "rep"
    assert run_folder(out, False) == out
    assert run_folder(out, True) == out / "quick"
    assert run_folder(out, False, "three_link") == out / "three_link"
    assert run_folder(out, True, str(mine)) == out / "my_biped" / "quick"
    assert run_folder(out, False, str(rabbit_copy)) == out       # the same robot
    with pytest.raises(ValueError, match="neither a built-in robot"):
        run_folder(out, False, "octopus")


def test_reproduce_refuses_a_file_as_folder(tmp_path):
    f = tmp_path / "rep"
    f.write_text("a file")
    for quick in (False, True):
        with pytest.raises(ValueError, match="is a file"):
            reproduce(f, quick=quick, progress=False)
    assert f.read_text() == "a file" and sorted(tmp_path.iterdir()) == [f]


@pytest.mark.parametrize("kw, match", [
    (dict(grid_n=1), "grid_n must be an integer >= 2"),
    (dict(sim_steps=2.5), "sim_steps must be an integer"),
    (dict(terrain_sigmas=(0.004, -0.1)), r"terrain_sigmas\[1\] must be positive"),
    (dict(domain_range=(5, -5)), "low < high"),
    (dict(robustness=3), "robustness must be a RobustnessSettings"),
    (dict(workers=0), "workers must be an integer >= 1"),
    (dict(progress="no"), "progress must be True or False"),
    (dict(robot=""), "robot must be"),
    (dict(resolution={"grid": 3}), "unknown option 'grid'")])
def test_options_are_checked_before_anything_runs(tmp_path, kw, match):
    out = tmp_path / "rep"
    with pytest.raises(ValueError, match=match):
        reproduce(out, **kw)
    assert not out.exists()
    # a list where a tuple goes is kept as the tuple (the settings stay hashable)
    from analysis.pipeline.options import Resolution
    assert Resolution.make(False, mujoco_scales=[1, 2]).mujoco_scales == (1, 2)


def test_cli_json_is_the_result(tmp_path, gait, light_stages, capsys):
    from analysis.cli import main
    assert main(["reproduce", "--out", str(tmp_path / "r"), "--quick", "--json",
                 "--workers", "1"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["status"] == "ok" and body["success"] is True and body["mode"] == "quick"
    assert set(body) == {"status", "message", "mode", "folder", "report", "summary_file",
                         "stages", "total_time", "critical_path", "success"}
    assert np.isfinite(body["total_time"])
    assert main(["reproduce", "--out", str(tmp_path / "r"), "--workers", "2",
                 "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "--workers" in capsys.readouterr().err


@pytest.mark.slow
def test_reproduce_quick_three_link(tmp_path, gait3):
    """The same kind of report for the second robot: gait, 1-D sweeps, the stable domain
    in the (M1(1), M1(2)) plane with every solution of a = b = 0, the M1 NLP, VC vs TV."""
    out = tmp_path / "rep3"
    r = subprocess.run([sys.executable, "-m", "analysis.cli", "reproduce", "--quick",
                        "--robot", "three_link", "--out", str(out), "--json"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    head = json.loads(r.stdout)
    assert all(v["status"] == "ok" for v in head["stages"].values()), head["stages"]
    out = out / "three_link" / "quick"          # another robot has its own folder
    assert head["folder"] == str(out)
    s = json.loads((out / "summary.json").read_text())
    assert s["robot"]["name"] == "three_link" and s["robot"]["nu"] == 2
    assert "paper" not in s                  # the paper's numbers are RABBIT's
    assert s["grid"]["dim"] == 2 and sum(s["grid"]["counts"].values()) == s["grid"]["n"] ** 2
    assert s["domains"]["plane"] and s["domains"]["ab_set"]["kind"] == "line"
    assert set(s["m1_nlp"]) >= {"ab_line", "free"}
    assert s["m1_nlp"]["free"]["max_abs"] <= s["domains"]["best"]["max_abs"]
    assert s["vc_comparison"]["vc"]["status"] == "stable"
    for name in ("gait_stick", "fig2", "fig3", "m1_plane", "fig5_qu_error", "fig6_swing_torques"):
        assert (out / "figures" / f"{name}.png").stat().st_size > 1000, name
    report = (out / "report.md").read_text()
    assert "three_link" in report and "| quantity | ours | note |" in report
    assert "figures/m1_plane.png" in report
    # the robust design is left to the command that designs from the robot's gait (the
    # --robot form ends without a start: the starts are drawn for RABBIT)
    assert "biped m1 --robust --gait gait.json" in s["robust_design"]["skipped"]
