"""`biped reproduce`: end to end into a temporary folder (--quick), and re-runs of any mix
of modes into the same folder (issue 12: a quick run after a full one failed two stages
on the full run's sweeps and overwrote its report)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from analysis.reporting import reproduce as rp
from matplotlib.figure import Figure

from analysis.reporting.plots import save_figure


@pytest.mark.slow
def test_reproduce_quick(tmp_path, gait):
    out = tmp_path / "rep"
    r = subprocess.run([sys.executable, "-m", "analysis.cli", "reproduce", "--quick",
                        "--out", str(out), "--json"], capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    head = json.loads(r.stdout)
    assert head["status"] == "ok" and head["mode"] == "quick", head
    assert all(v["status"] == "ok" for v in head["stages"].values()), head["stages"]
    run = out / "quick"                         # a quick run has its own folder
    assert head["folder"] == str(run) and head["report"] == str(run / "report.md")
    s = json.loads((run / "summary.json").read_text())
    for key in ("gait", "singular", "fig2", "grid", "conjecture", "taylor", "domains",
                "m1_nlp", "vc_comparison", "simulation", "stages", "figures", "paper",
                "total_time", "mode"):
        assert key in s, key
    assert sum(s["grid"]["counts"].values()) == 9**4
    assert s["m1_nlp"]["group1"]["group"] == 1 and s["m1_nlp"]["group2"]["group"] == 2
    for name in ("gait_stick", "gait_profiles", "fig2", "fig3", "fig4", "fig5_qu_error",
                 "fig6_swing_torques"):
        for ext in (".png", ".pdf"):
            f = run / "figures" / f"{name}{ext}"
            assert f.is_file() and f.stat().st_size > 1000, f
    assert (run / "figures" / "walk_tv.gif").stat().st_size > 1000
    report = (run / "report.md").read_text()
    assert "| quantity | paper | ours |" in report and "figures/fig4.png" in report
    assert "**Quick run**" in report
    assert (run / "gait.json").is_file()
    assert not (out / "report.md").exists()     # nothing of a full run made up
    assert [p.name for p in out.iterdir()] == ["quick"]


# ------------------------------------------------- re-runs into the same folder
def _stage_marker(ctx):
    """A cheap stage whose figure says which options made it."""
    fig = Figure()
    fig.add_subplot().set_title(f"line_points {ctx.opts.line_points}")
    ctx.figures["marker"] = save_figure(fig, ctx.out / "figures" / "marker", rp.FORMATS)
    ctx.summary["marker"] = dict(line_points=ctx.opts.line_points)


def _stage_fails(ctx):
    raise RuntimeError("this stage fails on purpose")


def _stage_interrupted(ctx):
    raise KeyboardInterrupt


@pytest.fixture
def light_stages(monkeypatch):
    """The real gait and Fig. 2 stages (their sweeps are what collided), plus a marker."""
    stages = [("gait", rp.stage_gait, ()), ("Fig. 2: 1-D sweeps", rp.stage_fig2, ("gait",)),
              ("marker", _stage_marker, ())]
    monkeypatch.setattr(rp, "STAGES", stages)
    return stages


def _files(folder, sweeps=True):
    """Every file under ``folder`` (without ``sweeps/`` unless ``sweeps``): size, mtime."""
    return {p.relative_to(folder).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in folder.rglob("*")
            if p.is_file() and (sweeps or "sweeps" not in p.relative_to(folder).parts)}


def test_full_and_quick_runs_share_a_folder_without_mixing(tmp_path, gait, light_stages):
    out = tmp_path / "rep"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    small = dict(progress=False, animation_steps=0)
    full = rp.reproduce(out, quick=False, line_points=5, **small)
    assert full.success and full.folder == str(out), full.message
    full_files = {k: v for k, v in _files(out).items() if not k.startswith("quick/")}
    quick = rp.reproduce(out, quick=True, line_points=7, **small)
    assert quick.success and quick.folder == str(out / "quick"), quick.message
    # the quick run did not touch the full run's results (nor the user's notes) ...
    assert {k: v for k, v in _files(out).items() if not k.startswith("quick/")} == full_files
    # ... and each report and summary describes its own run
    assert json.loads((out / "summary.json").read_text())["fig2"]["points_per_component"] == 5
    assert json.loads((out / "quick" / "summary.json").read_text())["mode"] == "quick"
    assert "**Full run**" in (out / "report.md").read_text()
    assert "**Quick run**" in (out / "quick" / "report.md").read_text()
    # any mix of runs, also with other settings in the same mode: never a refused sweep
    again = rp.reproduce(out, quick=False, line_points=9, **small)
    assert again.success, again.message
    assert sorted(p.name for p in (out / "sweeps").iterdir()) == [
        "fig2_5pts_-10_10", "fig2_9pts_-10_10"]
    assert (out / "notes.txt").read_text() == "mine\n"
    assert not list(out.glob(".staging-*")) and not list(out.rglob("*.tmp*"))


def test_a_rerun_replaces_exactly_the_previous_runs_figures(tmp_path, gait, light_stages,
                                                            monkeypatch):
    out = tmp_path / "rep"
    r = rp.reproduce(out, line_points=5, progress=False, animation_steps=0)
    assert r.success and (out / "figures" / "marker.png").is_file()
    (out / "figures" / "my_sketch.png").write_bytes(b"mine")
    # the marker stage now fails: its old figure must not stay beside the new report
    monkeypatch.setattr(rp, "STAGES", [*light_stages[:2], ("marker", _stage_fails, ())])
    r = rp.reproduce(out, line_points=5, progress=False, animation_steps=0)
    assert not r.success and r.status == "failed" and "marker" in r.message
    assert not (out / "figures" / "marker.png").exists()
    assert (out / "figures" / "fig2.png").is_file()
    assert (out / "figures" / "my_sketch.png").read_bytes() == b"mine"
    report = (out / "report.md").read_text()
    assert "failed: RuntimeError: this stage fails on purpose" in report
    assert "1 of 3 stages not ok" in report


def test_an_interrupted_run_leaves_the_previous_results(tmp_path, gait, light_stages,
                                                        monkeypatch):
    out = tmp_path / "rep"
    rp.reproduce(out, line_points=5, progress=False, animation_steps=0)
    before = _files(out, sweeps=False)       # (a sweep logs every run that reuses it)
    monkeypatch.setattr(rp, "STAGES", [*light_stages, ("stop", _stage_interrupted, ())])
    with pytest.raises(KeyboardInterrupt):
        rp.reproduce(out, line_points=5, progress=False, animation_steps=0)
    assert _files(out, sweeps=False) == before
    assert not list(out.glob(".staging-*"))


def test_each_kind_of_run_has_its_folder(tmp_path):
    from biped_casadi.model.description import builtin_path
    mine = tmp_path / "my_biped.toml"
    mine.write_text(builtin_path("three_link").read_text())
    rabbit_copy = tmp_path / "rabbit_copy.toml"
    rabbit_copy.write_text(builtin_path("rabbit").read_text())
    out = tmp_path / "rep"
    assert rp.run_folder(out, False) == out
    assert rp.run_folder(out, True) == out / "quick"
    assert rp.run_folder(out, False, "three_link") == out / "three_link"
    assert rp.run_folder(out, True, str(mine)) == out / "my_biped" / "quick"
    assert rp.run_folder(out, False, str(rabbit_copy)) == out       # the same robot
    with pytest.raises(ValueError, match="neither a built-in robot"):
        rp.run_folder(out, False, "octopus")


def test_reproduce_refuses_a_file_as_folder(tmp_path):
    f = tmp_path / "rep"
    f.write_text("a file")
    for quick in (False, True):
        with pytest.raises(ValueError, match="is a file"):
            rp.reproduce(f, quick=quick, progress=False)
    assert f.read_text() == "a file" and sorted(tmp_path.iterdir()) == [f]


def test_cli_json_is_the_result(tmp_path, gait, light_stages, capsys):
    from analysis.cli import main
    assert main(["reproduce", "--out", str(tmp_path / "r"), "--quick", "--json"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["status"] == "ok" and body["success"] is True and body["mode"] == "quick"
    assert set(body) == {"status", "message", "mode", "folder", "report", "summary_file",
                         "stages", "total_time", "success"}
    assert np.isfinite(body["total_time"])


def test_readme_and_help_state_the_same_times(capsys):
    """Issue 12: the README's times disagreed with --help (and with the machine)."""
    from pathlib import Path

    from analysis.cli import main
    from analysis.cli.reproduce import TIME_FULL, TIME_QUICK
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert f"| `biped reproduce` (the default gait not yet cached) | {TIME_FULL} |" in readme
    assert f"| `biped reproduce --quick` | {TIME_QUICK} |" in readme
    assert "2-core" in readme
    assert main(["reproduce", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert f"A full run ({TIME_FULL} on a loaded 2-core VM)" in text
    assert f"({TIME_QUICK})" in text


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
