"""M1 sweeps (paper §V-A, Fig. 2): counts against a direct evaluation, resumption after a
real SIGKILL, refusal of other settings, damaged chunks, a real Dask LocalCluster, the
``biped sweep`` command line."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from analysis import poincare_map, singular_m1_values
from analysis.cli import main as biped_main
from analysis.reporting.plots import one_d_sweeps_plot, save_figure
from analysis.stability import STATUSES
from analysis.sweeps import (SweepSettings, grid_points, line_points, load_sweep,
                            one_d_sweeps, run_sweep)


@pytest.fixture(scope="module")
def sweep_gait(gait):
    """The session's reference gait."""
    return gait


@pytest.fixture(scope="module")
def gait_file(sweep_gait, tmp_path_factory):
    return sweep_gait.save(tmp_path_factory.mktemp("gait") / "gait.json")


@pytest.fixture(scope="module")
def small_grid():
    return grid_points(5, -10, 10)          # 625 points, all four statuses but no_impact


@pytest.fixture(scope="module")
def reference(sweep_gait, small_grid, tmp_path_factory):
    """An uninterrupted run of the 5^4 grid in chunks of 4 (the layout of the kill test)."""
    out = tmp_path_factory.mktemp("sweep") / "reference"
    return run_sweep(sweep_gait, small_grid, out_dir=out, chunk_size=4,
                     progress=False)


def chunk_no(path: Path) -> int:
    return int(path.name.split(".")[0].split("-")[1])       # part-000012.<sha>.parquet


def same_results(a, b):
    assert np.array_equal(a.points, b.points)
    assert np.array_equal(a.point_status, b.point_status)
    for name in ("max_abs", "eigenvalues", "A"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes(), f"{name} differs"       # bit for bit
    assert a.counts == b.counts


# ------------------------------------------------------------------- points
def test_grid_and_line_points():
    P = grid_points(9, -10, 10)
    assert P.shape == (9 ** 4, 4)
    assert np.array_equal(np.unique(P[:, 2]), np.linspace(-10, 10, 9))
    assert np.array_equal(P[0], [-10] * 4) and np.array_equal(P[1], [-10, -10, -10, -7.5])
    assert len(np.unique(P, axis=0)) == 9 ** 4
    L = line_points(2, [1.0, 2.0])
    assert np.array_equal(L, [[0, 0, 1, 0], [0, 0, 2, 0]])
    for bad in [(0, -1, 1), (3, 1, 1), (3, 2, -2), (3, 0, np.inf)]:
        with pytest.raises(ValueError):
            grid_points(*bad)
    with pytest.raises(ValueError, match="j"):
        line_points(4, [1.0])


# ---------------------------------------------------------- results correct
def test_counts_match_direct_jacobian_batch(sweep_gait, reference, small_grid):
    r = reference
    assert sum(r.counts.values()) == r.n_points == len(small_grid)
    assert set(r.counts) == set(STATUSES)
    pm = poincare_map(sweep_gait)
    jb = pm.jacobian_batch(small_grid)
    status, A, max_abs = jb.status, jb.A, jb.max_abs
    assert np.array_equal(r.point_status, status)
    assert r.counts == {s: int(np.sum(status == s)) for s in STATUSES}
    assert r.counts["stable"] > 0 and r.counts["singular"] > 0 and r.counts["unstable"] > 0
    fin = np.isfinite(max_abs)
    assert np.array_equal(np.isfinite(r.max_abs), fin)
    np.testing.assert_allclose(r.max_abs[fin], max_abs[fin], rtol=1e-12)
    np.testing.assert_allclose(r.A[fin], A[fin], rtol=1e-12, atol=1e-14)
    # the stored eigenvalues are those of the stored A, |.| descending, stable <=> < 1
    ok = np.flatnonzero(fin)
    np.testing.assert_allclose(np.abs(r.eigenvalues[ok, 0]), r.max_abs[ok], rtol=1e-14)
    assert np.all(np.abs(r.eigenvalues[ok, 0]) >= np.abs(r.eigenvalues[ok, 1]))
    assert np.all((r.max_abs < 1) == (r.point_status == "stable"))
    assert np.all(r.max_abs[r.point_status == "singular"] == np.inf)
    # and a few points through the full AD map agree with the variational path
    for i in ok[:: max(1, len(ok) // 3)][:3]:
        ad = pm.analyse(small_grid[i], method="ad")
        assert ad.status == r.point_status[i]
        assert abs(ad.max_abs - r.max_abs[i]) <= 1e-6 * max(1.0, ad.max_abs)


def test_parallel_modes_give_identical_results(sweep_gait, reference, small_grid):
    threads = run_sweep(sweep_gait, small_grid, chunk_size=4, workers=2,
                        executor="thread", progress=False)
    same_results(threads, reference)
    serial = run_sweep(sweep_gait, small_grid[:64], chunk_size=4, workers=1,
                       progress=False)
    same_results(serial, reference.subset(np.arange(64)))
    procs = run_sweep(sweep_gait, small_grid[:64], chunk_size=4, workers=2,
                      executor="process", progress=False)
    same_results(procs, reference.subset(np.arange(64)))


# ------------------------------------------------------------------- resume
def test_resume_after_sigkill(sweep_gait, gait_file, reference, tmp_path):
    out = tmp_path / "killed"
    n_chunks = -(-reference.n_points // 4)
    cmd = [sys.executable, "-m", "analysis.cli", "sweep", "--gait", str(gait_file),
           "--grid", "5", "--range", "-10", "10", "--out", str(out), "--chunk-size", "4",
           "--workers", "1", "--no-progress", "--json"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    chunks = out / "chunks"
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if chunks.is_dir() and len(list(chunks.glob("part-*.parquet"))) >= 8:
                break
            time.sleep(0.005)
        assert proc.poll() is None, f"sweep ended before it could be killed: " \
                                    f"{proc.stderr.read().decode()[-500:]}"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    stored = {chunk_no(p): (p, p.stat()) for p in chunks.glob("part-*.parquet")}
    assert 8 <= len(stored) < n_chunks, "kill must land part-way"

    r = run_sweep(sweep_gait, grid_points(5, -10, 10), out_dir=out, progress=False)
    assert r.chunk_size == 4                       # taken from the folder
    assert r.reused_chunks == sorted(stored)       # everything stored was kept ...
    assert r.computed_chunks == sorted(set(range(n_chunks)) - set(stored))   # ... not redone
    assert r.n_computed == sum(min(4, r.n_points - 4 * k) for k in r.computed_chunks)
    assert not r.corrupt_chunks
    for k, (p, st) in stored.items():              # stored files untouched
        now = p.stat()
        assert (now.st_ino, now.st_mtime_ns, now.st_size) == (st.st_ino, st.st_mtime_ns,
                                                             st.st_size)
    start = [e for e in map(json.loads, (out / "log.jsonl").read_text().splitlines())
             if e["event"] == "start"]
    assert len(start) == 2 and start[-1]["to_compute"] == r.computed_chunks
    same_results(r, reference)                     # exactly the uninterrupted results
    same_results(load_sweep(out), reference)
    again = run_sweep(sweep_gait, grid_points(5, -10, 10), out_dir=out, progress=False)
    assert again.computed_chunks == [] and again.n_computed == 0
    same_results(again, reference)


def test_damaged_chunks_are_detected_and_recomputed(sweep_gait, reference, small_grid, tmp_path):
    import shutil
    out = tmp_path / "damaged"
    shutil.copytree(reference.out_dir, out)
    c = out / "chunks"
    p3, p7, p9, p4 = (next(c.glob(f"part-{k:06d}.*.parquet")) for k in (3, 7, 9, 4))
    p3.write_bytes(p3.read_bytes()[: p3.stat().st_size // 2])          # truncated
    data = bytearray(p7.read_bytes())                                  # one byte flipped
    data[len(data) // 3] ^= 0x01
    p7.write_bytes(bytes(data))
    p9.write_bytes(b"")                                                # empty
    (c / ".part-000011.parquet.123.tmp").write_bytes(b"half a chunk")  # left by a kill
    p4.unlink()                                                        # missing
    r = run_sweep(sweep_gait, small_grid, out_dir=out, progress=False)
    assert set(r.corrupt_chunks) == {3, 7, 9}
    assert r.computed_chunks == [3, 4, 7, 9]
    assert not list(c.glob(".*.tmp"))
    same_results(r, reference)


def test_other_settings_are_refused(sweep_gait, reference, small_grid, tmp_path):
    out = reference.out_dir
    before = sorted((p.name, p.stat().st_mtime_ns) for p in (out / "chunks").iterdir())
    cases = [dict(points=small_grid[:-1]),                       # other points
             dict(points=small_grid * 1.0000001),
             dict(points=small_grid, chunk_size=8),              # other layout
             dict(points=small_grid, settings=SweepSettings(n_post=200)),   # other map
             dict(points=small_grid, settings={"method": "ad"})]
    for case in cases:
        with pytest.raises(ValueError, match="other settings"):
            run_sweep(sweep_gait, out_dir=out, progress=False, **case)
    after = sorted((p.name, p.stat().st_mtime_ns) for p in (out / "chunks").iterdir())
    assert before == after                      # nothing written, nothing removed
    other = tmp_path / "not_a_sweep"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not a sweep folder"):
        run_sweep(sweep_gait, small_grid[:8], out_dir=other, progress=False)
    assert [p.name for p in other.iterdir()] == ["notes.txt"]


# --------------------------------------------------------------------- Dask
def test_dask_local_cluster_same_results(sweep_gait, reference, small_grid, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, host="127.0.0.1") as cluster:
        r = run_sweep(sweep_gait, small_grid[:64], out_dir=tmp_path / "dask",
                      chunk_size=4, scheduler=cluster.scheduler_address, progress=False)
        with distributed.Client(cluster.scheduler_address) as client:
            pids = client.run(os.getpid)
    assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()
    assert r.computed_chunks == list(range(16))
    same_results(r, reference.subset(np.arange(64)))
    same_results(load_sweep(tmp_path / "dask"), reference.subset(np.arange(64)))


def test_unreachable_scheduler_is_a_user_error(sweep_gait, small_grid, monkeypatch):
    import analysis.cluster
    monkeypatch.setattr(analysis.cluster, "DASK_CONNECT_TIMEOUT", "1s")
    import socket
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()                                   # nothing listens there
    with pytest.raises(ValueError, match="scheduler"):
        run_sweep(sweep_gait, small_grid[:8], scheduler=f"tcp://127.0.0.1:{port}",
                  progress=False)


# ------------------------------------------------------------------- Fig. 2
def test_one_d_sweeps_and_fig2(sweep_gait, tmp_path):
    values = np.sort(np.r_[np.linspace(-3, 3, 61), 1.70])
    lines = one_d_sweeps(sweep_gait, values, progress=False)
    sv = singular_m1_values(sweep_gait)
    np.testing.assert_allclose(lines.singular_values, sv)
    for j, r in enumerate(lines.results):
        assert np.array_equal(r.points[:, j], values)
        assert np.all(np.delete(r.points, j, axis=1) == 0)
    assert lines.sweep.n_points == 4 * len(values)
    # M1(1): the controller is singular just at D11/D12(1) (eq. 24: 1.70 lies between its
    # value at q^d(T) and its extreme over the step), regular elsewhere, and max|lambda|
    # jumps there
    r1 = lines.results[0]
    assert sv[0] < 1.70 < sv[0] + 0.05
    assert r1.point_status[values == 1.70] == "singular"
    assert np.all(r1.point_status[np.abs(values - sv[0]) > 0.1] != "singular")
    fin = np.isfinite(r1.max_abs)
    peak = values[fin][np.argmax(r1.max_abs[fin])]
    assert abs(peak - sv[0]) < 0.3 and r1.max_abs[fin].max() > 5 * np.median(r1.max_abs[fin])
    fig = one_d_sweeps_plot(lines)
    for ax, r in zip(fig.axes, lines.results):         # a kind with no point says so
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        stable = next(t for t in labels if t.startswith("stable"))
        assert stable.endswith("(none)") == (not np.any(r.point_status == "stable")), labels
    paths = [Path(p) for p in save_figure(fig, tmp_path / "fig2.png", formats=("png", "pdf"))]
    assert [p.suffix for p in paths] == [".png", ".pdf"]
    assert paths[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and paths[0].stat().st_size > 20000
    assert paths[1].read_bytes()[:5] == b"%PDF-"


# ---------------------------------------------------------------------- CLI
def test_cli_json(gait_file, tmp_path, capsys):
    out = tmp_path / "cli"
    rc = biped_main(["sweep", "--gait", str(gait_file), "--grid", "3", "--range", "-5", "5",
                     "--out", str(out), "--json", "--no-progress"])
    assert rc == 0
    body = json.loads(capsys.readouterr().out)
    assert set(body["counts"]) == set(STATUSES)
    assert sum(body["counts"].values()) == body["n_points"] == 81
    assert body["out_dir"] == str(out) and body["elapsed"] >= 0 and body["success"]
    assert len(body["best"]["M1"]) == 4 and body["best"]["max_abs"] > 0
    assert body["computed_points"] == 81
    stored = load_sweep(out)
    assert stored.counts == body["counts"]
    assert body["best"]["max_abs"] == float(np.min(stored.max_abs))
    rc = biped_main(["sweep", "--gait", str(gait_file), "--grid", "3", "--range", "-5", "5",
                     "--out", str(out), "--json", "--no-progress"])
    again = json.loads(capsys.readouterr().out)
    assert rc == 0 and again["computed_points"] == 0 and again["counts"] == body["counts"]
    # human output
    assert biped_main(["sweep", "--gait", str(gait_file), "--grid", "2", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "stable" in text and "16" in text


def test_cli_line_mode_writes_fig2(gait_file, tmp_path, capsys):
    rc = biped_main(["sweep", "--gait", str(gait_file), "--line", "21", "--range", "-3", "3",
                     "--plot", str(tmp_path), "--json", "--no-progress"])
    assert rc == 0
    body = json.loads(capsys.readouterr().out)
    assert body["n_points"] == 84 and len(body["singular_values"]) == 4
    assert [Path(p).suffix for p in body["plots"]] == [".png", ".pdf"]
    assert all(Path(p).is_file() for p in body["plots"])


@pytest.mark.parametrize("args, message", [
    (["--gait", "{missing}", "--grid", "3"], "not found"),
    (["--gait", "{garbage}", "--grid", "3"], "JSON"),
    (["--gait", "{sweep_gait}", "--grid", "3", "--range", "5", "-5"], "--range"),
    (["--gait", "{sweep_gait}", "--grid", "0"], "--grid"),
    (["--gait", "{sweep_gait}", "--grid", "3", "--out", "{used}"], "other settings"),
])
def test_cli_user_errors_exit_2(gait_file, tmp_path, capsys, args, message):
    garbage = tmp_path / "garbage.json"
    garbage.write_text("{not json")
    used = tmp_path / "used"
    assert biped_main(["sweep", "--gait", str(gait_file), "--grid", "2", "--out", str(used),
                       "--json", "--no-progress"]) == 0
    capsys.readouterr()
    subs = dict(missing=str(tmp_path / "nope.json"), garbage=str(garbage),
                sweep_gait=str(gait_file), used=str(used))
    rc = biped_main(["sweep"] + [a.format(**subs) for a in args] + ["--no-progress"])
    cap = capsys.readouterr()
    assert rc == 2
    assert cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith("biped sweep: error:")


def test_open_orbit_sweep_is_stored_and_read_back(model, sweep_gait, tmp_path, capsys):
    """A gait that is not an orbit (--allow-open-orbit): every point's status is
    'open_orbit', which the chunk files now store (it raised "tuple.index(x): x not in
    tuple" with --out, and in `biped m1 --allow-open-orbit`'s grid); a rerun reads it."""
    from gait_opt import Gait
    g = sweep_gait
    open_gait = Gait(model, g.options, g.alpha, g.x0 + np.array([0.0, 0.01]), g.T)
    pts = grid_points(2, -1, 1)
    r = run_sweep(open_gait, pts, out_dir=tmp_path / "s", workers=1, progress=False)
    assert r.counts["open_orbit"] == len(pts)
    again = run_sweep(open_gait, pts, out_dir=tmp_path / "s", workers=1, progress=False)
    assert again.counts == r.counts and again.n_computed == 0
    assert list(load_sweep(tmp_path / "s").point_status) == ["open_orbit"] * len(pts)
    # in memory too: the counts were all 0 beside "total 16" ('open_orbi' counted nowhere)
    r = run_sweep(open_gait, pts, workers=1, progress=False)
    assert r.counts["open_orbit"] == len(pts) and set(r.point_status) == {"open_orbit"}
    path = open_gait.save(tmp_path / "open.json")
    assert biped_main(["sweep", "--gait", str(path), "--allow-open-orbit", "--grid", "2"]) == 0
    out = capsys.readouterr().out
    assert "open_orbit       16" in out and "(open_orbit)" in out, out


def test_points_and_sweeps_name_bad_arguments(sweep_gait):
    with pytest.raises(ValueError, match="^lo must be less than hi, got lo = 1, hi = -1$"):
        grid_points(3, 1.0, -1.0)
    with pytest.raises(ValueError, match="^lo, hi must be finite"):
        grid_points(3, float("nan"), 1.0)
    with pytest.raises(ValueError, match="^values must be"):
        line_points(0, "ab")
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        run_sweep("gait.json", np.zeros((2, 4)), progress=False)
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        singular_m1_values(None)
