"""The reproduction's two processes share results through claims: one computes, the other
waits for it; a claim left by a process that died is taken over."""
from __future__ import annotations

import subprocess
import sys
import threading
import time

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
