"""The Monte Carlo on Dask (issue 22): a LocalCluster, and a real ``dask scheduler`` with
two ``dask worker`` processes on loopback, give the numbers of the run in this process
for the same seed; the command line refuses a scheduler it cannot reach."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from analysis.design import ROBUST_GAIT
from analysis.terrain import MonteCarloSettings, WalkerSpec, monte_carlo
from gait_opt import GaitOptions, optimize_gait

M1R, REJOIN = (-8.2618, 2.5374, 0.0034, 8.5090), 0.75
SETTINGS = MonteCarloSettings(sigma=0.008, runs=12, max_steps=12, chunk=4)


@pytest.fixture(scope="module")
def robust_gait(model):
    return optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)


@pytest.fixture(scope="module")
def inline(robust_gait):
    return {kind: monte_carlo(robust_gait, spec, SETTINGS, scheduler="inline")
            for kind, spec in (("tv", WalkerSpec("tv", M1R, REJOIN)), ("vc", WalkerSpec("vc")))}


def _same(a, b):
    assert np.array_equal(a.walked, b.walked) and np.array_equal(a.failed, b.failed)
    assert np.array_equal(a.duration, b.duration, equal_nan=True)
    assert a.estimate.to_dict() == b.estimate.to_dict()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_local_cluster_gives_the_same_numbers(robust_gait, inline):
    r = monte_carlo(robust_gait, WalkerSpec("tv", M1R, REJOIN), SETTINGS, workers=2)
    _same(r, inline["tv"])
    assert r.chunks_computed == 3


@pytest.mark.slow
def test_real_scheduler_and_two_workers_give_the_same_numbers(robust_gait, inline, tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, BIPED_THREADS="1")
    dask = str(Path(sys.executable).with_name("dask"))
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, cwd=tmp_path)]
    try:
        time.sleep(2)
        for _ in range(2):
            procs.append(subprocess.Popen([dask, "worker", address, "--nthreads", "1",
                                           "--no-dashboard", "--local-directory",
                                           str(tmp_path)], env=env, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL, cwd=tmp_path))
        from dask.distributed import Client
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=120)
            assert len(client.scheduler_info()["workers"]) == 2
            for kind, spec in (("tv", WalkerSpec("tv", M1R, REJOIN)), ("vc", WalkerSpec("vc"))):
                r = monte_carlo(robust_gait, spec, SETTINGS, scheduler=client,
                                out_dir=tmp_path / f"mc_{kind}")
                _same(r, inline[kind])
        # the address itself, resuming from the chunks written: nothing computed again
        r = monte_carlo(robust_gait, WalkerSpec("tv", M1R, REJOIN), SETTINGS,
                        scheduler=address, out_dir=tmp_path / "mc_tv")
        assert r.chunks_reused == 3 and r.chunks_computed == 0
        _same(r, inline["tv"])
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs[::-1]:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


@pytest.mark.slow
def test_resume_after_sigkill(robust_gait, tmp_path):
    """``biped terrain --out`` killed (SIGKILL) part-way: the rerun keeps every stored
    chunk, computes only the missing ones and gives the uninterrupted run's numbers."""
    import json
    import signal
    out = tmp_path / "killed"
    gfile = robust_gait.save(tmp_path / "robust_gait.json")
    args = ["terrain", "--gait", str(gfile), "--m1", *map(str, M1R), "--rejoin", str(REJOIN), "--sigma", "0.008",
            "--runs", "40", "--max-steps", "20", "--chunk", "2", "--seed", "3",
            "--scheduler", "inline", "--out", str(out), "--json"]
    proc = subprocess.Popen([sys.executable, "-m", "analysis.cli", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    chunks = out / "chunks"
    deadline = time.monotonic() + 180
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if chunks.is_dir() and len(list(chunks.glob("part-*.parquet"))) >= 3:
                break
            time.sleep(0.005)
        assert proc.poll() is None, proc.stderr.read().decode()[-500:]
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        proc.stderr.close()
    stored = {p.name: p.stat().st_mtime_ns for p in chunks.glob("part-*.parquet")}
    assert 3 <= len(stored) < 20, "the kill must land part-way"
    spec = WalkerSpec("tv", M1R, REJOIN)
    st = MonteCarloSettings(sigma=0.008, runs=40, max_steps=20, chunk=2, seed=3)
    r = monte_carlo(robust_gait, spec, st, out_dir=out, scheduler="inline")
    assert r.chunks_reused == len(stored) and r.chunks_computed == 20 - len(stored)
    for p in chunks.glob("part-*.parquet"):
        if p.name in stored:
            assert p.stat().st_mtime_ns == stored[p.name]        # kept as they were
    fresh = monte_carlo(robust_gait, spec, st, scheduler="inline")
    _same(r, fresh)
    assert json.loads((out / "montecarlo.json").read_text())["format"] == \
        "biped-casadi-montecarlo"
