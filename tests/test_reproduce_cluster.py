"""`biped reproduce --quick` end to end on the default local cluster (its folder,
report, figures, a warm re-run that computes nothing), and the same numbers wherever it
runs: on the default local cluster, on a real Dask scheduler with two workers on
loopback, and after a run killed with SIGKILL in the middle and started again."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dask_cluster import dask_cluster
from summary_compare import differences


def _env(cache):
    env = dict(os.environ, BIPED_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    env.pop("BIPED_SCHEDULER", None)
    return env


def _reproduce(out, cache, *extra, **kw):
    return subprocess.run([sys.executable, "-m", "analysis.cli", "reproduce", "--quick",
                           "--out", str(out), "--json", *extra], capture_output=True,
                          text=True, env=_env(cache), timeout=900, **kw)


def _summary(out):
    return json.loads((Path(out) / "quick" / "summary.json").read_text())


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """A cold quick run on the default local cluster: its folder, cache, JSON head and
    summary (read before any test re-runs into the folder)."""
    tmp = tmp_path_factory.mktemp("local")
    r = _reproduce(tmp / "rep", tmp / "cache")
    assert r.returncode == 0, r.stderr[-3000:]
    return tmp / "rep", tmp / "cache", json.loads(r.stdout), _summary(tmp / "rep")


@pytest.fixture(scope="module")
def local(quick_run):
    """The summary of that cold run."""
    return quick_run[3]


@pytest.mark.slow
def test_reproduce_quick(quick_run):
    """End to end into a temporary folder, then a warm re-run that computes nothing."""
    out, cache, head, s = quick_run
    assert head["status"] == "ok" and head["mode"] == "quick", head
    assert all(v["status"] == "ok" for v in head["stages"].values()), head["stages"]
    assert all(v["computed"] > 0 for v in head["stages"].values())
    run = out / "quick"                         # a quick run has its own folder
    assert head["folder"] == str(run) and head["report"] == str(run / "report.md")
    for key in ("gait", "singular", "fig2", "grid", "conjecture", "taylor", "domains",
                "m1_nlp", "vc_comparison", "simulation", "robust_design", "terrain", "mujoco",
                "stages",
                "figures", "paper", "total_time", "mode", "critical_path"):
        assert key in s, key
    assert sum(s["grid"]["counts"].values()) == 9**4
    assert s["m1_nlp"]["group1"]["group"] == 1 and s["m1_nlp"]["group2"]["group"] == 2
    assert 0 < s["critical_path"]["seconds"] < s["total_time"]
    for name in ("gait_stick", "gait_profiles", "fig2", "fig3", "fig4", "fig5_qu_error",
                 "fig6_swing_torques", "basin_default", "basin_robust", "terrain_mfpt",
                 "family", "speed_ramp", "mujoco"):
        for ext in (".png", ".pdf"):
            f = run / "figures" / f"{name}{ext}"
            assert f.is_file() and f.stat().st_size > 1000, f
    assert (run / "figures" / "walk_tv.gif").stat().st_size > 1000
    report = (run / "report.md").read_text()
    assert "| quantity | paper | ours |" in report and "figures/fig4.png" in report
    assert "**Quick run**" in report
    untitled = [x for x in report.splitlines() if x.startswith("### ") and "_" in x]
    assert not untitled, untitled                # every figure has its title and caption
    assert s["family"]["ramp"]["runs"]["virtual constraints"]["steps"] > 0
    assert (run / "gait.json").is_file()
    assert not (out / "report.md").exists()     # nothing of a full run made up
    assert [p.name for p in out.iterdir()] == ["quick"]
    # a warm re-run computes nothing and gives the same numbers
    r2 = _reproduce(out, cache)
    assert r2.returncode == 0, r2.stderr[-3000:]
    warm = json.loads(r2.stdout)
    assert all(v["computed"] == 0 for v in warm["stages"].values()), warm["stages"]
    s2 = json.loads((run / "summary.json").read_text())
    assert s2["robust_design"]["design"] == s["robust_design"]["design"]
    assert s2["terrain"]["mfpt"] == s["terrain"]["mfpt"]


@pytest.fixture
def cluster(tmp_path):
    """A Dask scheduler and two single-threaded workers on loopback: its address."""
    env = dict(_env(tmp_path / "worker-cache"), BIPED_THREADS="1")
    with dask_cluster(tmp_path, [env, env]) as address:
        yield address


@pytest.mark.slow
def test_a_dask_cluster_gives_the_local_numbers(local, cluster, tmp_path):
    r = _reproduce(tmp_path / "out", tmp_path / "cache", "--scheduler", cluster)
    assert r.returncode == 0, r.stderr[-3000:]
    head = json.loads(r.stdout)
    assert all(v["status"] == "ok" for v in head["stages"].values()), head["stages"]
    assert differences(local, _summary(tmp_path / "out")) == []


@pytest.mark.slow
def test_a_killed_run_resumes_with_the_same_numbers(local, tmp_path):
    """SIGKILL to the whole run (its process group: the local cluster too) once it has
    kept some results but not all; the run started again reuses them and ends with the
    numbers of an uninterrupted run."""
    cache, out = tmp_path / "cache", tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "analysis.cli", "reproduce", "--quick",
                          "--out", str(out), "--no-progress"], env=_env(cache),
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)
    kept = lambda: len(list((cache / "tasks").rglob("*.pkl")))          # noqa: E731
    t0 = time.time()
    while kept() < 25 and p.poll() is None and time.time() - t0 < 600:
        time.sleep(0.2)
    assert p.poll() is None, "the run ended before it could be killed"
    os.killpg(p.pid, signal.SIGKILL)
    p.wait(30)
    assert not (out / "quick" / "summary.json").exists()
    before = kept()
    assert before >= 25
    r = _reproduce(out, cache)
    assert r.returncode == 0, r.stderr[-3000:]
    stages = json.loads(r.stdout)["stages"]
    assert sum(v["reused"] for v in stages.values()) >= before // 2
    assert differences(local, _summary(out)) == []
