"""A real Dask cluster on loopback for the tests: a ``dask scheduler`` and ``dask worker``
processes, each worker with an environment of its own."""
from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time
from pathlib import Path

DASK = str(Path(sys.executable).with_name("dask"))


@contextlib.contextmanager
def dask_cluster(folder: Path, worker_envs: list, scheduler_env=None, cwd=None):
    """Start a scheduler (with ``scheduler_env``) and one single-threaded worker per
    environment of ``worker_envs``; yield the scheduler's address; stop them all."""
    file = Path(folder) / "scheduler.json"
    procs = [subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", str(file)],
                              env=scheduler_env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    try:
        for _ in range(300):
            if file.is_file() and file.stat().st_size:
                break
            time.sleep(0.1)
        address = json.loads(file.read_text())["address"]
        procs += [subprocess.Popen([DASK, "worker", address, "--nworkers", "1", "--nthreads",
                                    "1", "--no-dashboard"], env=env, cwd=cwd,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                  for env in worker_envs]
        yield address
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs:
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
