"""The reproduction's two processes share results through claims: one computes, the other
waits for it; a claim left by a process that died is taken over."""
from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from analysis.reporting.context import claimed


def test_a_live_claim_is_waited_for(tmp_path):
    path = tmp_path / "result.pkl"
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        lock = tmp_path / "result.pkl.lock"
        lock.write_text(str(holder.pid))

        def release():
            time.sleep(0.6)
            path.write_text("done")
            lock.unlink()
        threading.Thread(target=release).start()
        t = time.perf_counter()
        with claimed(path, poll=0.05):
            waited = time.perf_counter() - t
            assert path.read_text() == "done"          # the holder's result is there
            assert lock.read_text() == str(__import__("os").getpid())
        assert waited >= 0.5
        assert not lock.exists()                           # released after the block
    finally:
        holder.kill()
        holder.wait()


def test_a_dead_claim_is_taken_over(tmp_path):
    path = tmp_path / "result.pkl"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / "result.pkl.lock").write_text(str(dead.pid))
    t = time.perf_counter()
    with claimed(path, poll=0.05):
        assert time.perf_counter() - t < 1.0
    assert not (tmp_path / "result.pkl.lock").exists()


def test_an_unwritable_folder_runs_unguarded(tmp_path):
    target = tmp_path / "file"
    target.write_text("x")
    ran = []
    with claimed(target / "sub" / "result.pkl"):           # a file where a folder should be
        ran.append(True)
    assert ran == [True]


def test_shared_result_is_computed_once(tmp_path):
    """Two processes asking for one result: the first computes it, the second waits and
    reads it (and says so)."""
    from biped_casadi.caching import shared_result
    path = tmp_path / "unit.pkl"
    child = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; sys.path[:0] = %r\n"
        "from biped_casadi.caching import shared_result\n"
        "print(shared_result(%r, lambda: (time.sleep(1.0), 'child')[1])[1])") % (
        sys.path, str(path))], stdout=subprocess.PIPE, text=True)
    try:
        while not (tmp_path / "unit.pkl.lock").exists():     # the child holds the claim
            time.sleep(0.02)
        value, read = shared_result(path, lambda: "parent")
        assert (value, read) == ("child", True)
        assert child.communicate(timeout=30)[0].strip() == "False"  # it computed
        assert shared_result(path, lambda: "again") == ("child", True)
    finally:
        child.kill()
        child.wait()


def test_compiled_functions_are_kept_by_content(tmp_path, monkeypatch):
    """A compiled Function evaluates as the SX one, its library is kept in the cache
    folder, and an equal Function built again loads it instead of compiling."""
    import casadi as ca
    import numpy as np
    from biped_casadi.numerics import compiled
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path))
    x = ca.SX.sym("x", 3)

    def build():
        return ca.Function("f_test", [x], [ca.vertcat(ca.sin(x[0]) * x[1], x[2] ** 3)])
    f = build()
    g = compiled(f)
    libs = list((tmp_path / "compiled").glob("f_test_*.so"))
    assert len(libs) == 1
    v = np.array([0.3, -1.2, 2.0])
    np.testing.assert_array_equal(np.array(g(v)), np.array(f(v)))
    t = libs[0].stat().st_mtime_ns
    compiled(build())
    assert [p.stat().st_mtime_ns for p in (tmp_path / "compiled").glob("f_test_*.so")] == [t]


def test_a_claim_that_does_not_wait(tmp_path):
    """``wait=False``: a live claim raises Claimed at once; a result already written is
    read without looking at the claim; a free claim is taken as usual."""
    from biped_casadi.caching import Claimed, shared_result
    path = tmp_path / "unit.pkl"
    lock = tmp_path / "unit.pkl.lock"
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        lock.write_text(str(holder.pid))
        t = time.perf_counter()
        with pytest.raises(Claimed, match=str(holder.pid)):
            with claimed(path, poll=0.05, wait=False):
                pass
        with pytest.raises(Claimed):
            shared_result(path, lambda: "mine", wait=False)
        assert time.perf_counter() - t < 1.0
        assert lock.read_text() == str(holder.pid)        # the holder's claim is untouched
        shared_result(tmp_path / "other.pkl", lambda: "other")
        (tmp_path / "other.pkl").rename(path)             # the holder's result appears
        assert shared_result(path, lambda: "mine", wait=False) == ("other", True)
    finally:
        holder.kill()
        holder.wait()
    assert shared_result(tmp_path / "free.pkl", lambda: "free", wait=False) == ("free", False)
    assert not (tmp_path / "free.pkl.lock").exists()
