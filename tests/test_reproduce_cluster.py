"""`biped reproduce --quick` gives the same numbers wherever it runs: on the default
local cluster, on a real Dask scheduler with two workers on loopback, and after a run
killed with SIGKILL in the middle and started again."""
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
def local(tmp_path_factory):
    """A quick run on the default local cluster, with a fresh cache."""
    tmp = tmp_path_factory.mktemp("local")
    r = _reproduce(tmp / "out", tmp / "cache")
    assert r.returncode == 0, r.stderr[-3000:]
    return _summary(tmp / "out")


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
