"""Long work on many cores: one way to connect to a Dask distributed cluster (a
scheduler's address, a client, or a ``LocalCluster`` of this machine), used by the sweeps,
the robustness searches and the Monte Carlo, and one progress bar."""
from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import sys
import time

__all__ = ["dask_client", "cluster_client", "progress_bar", "submit_chunks",
           "check_not_bootstrapping", "connect", "cores", "LOCAL_CLUSTER_CONFIG",
           "DASK_CONNECT_TIMEOUT", "DASK_WORKER_TIMEOUT"]

#: how long to wait for a Dask scheduler to answer, and for a first worker to join
DASK_CONNECT_TIMEOUT = "10s"
DASK_WORKER_TIMEOUT = 60


@contextlib.contextmanager
def dask_client(scheduler, connect_timeout=None):
    """A ``dask.distributed.Client`` with at least one worker.

    Parameters
    ----------
    scheduler : str or dask.distributed.Client
        A scheduler address ('tcp://host:port'; the client is closed afterwards) or a
        client (left open).
    connect_timeout : str, optional
        Default :data:`DASK_CONNECT_TIMEOUT`.

    Yields
    ------
    dask.distributed.Client

    Raises
    ------
    ValueError
        Naming 'scheduler' when dask.distributed is missing, the scheduler does not
        answer, or no worker joins within :data:`DASK_WORKER_TIMEOUT` seconds.
    """
    try:
        from dask.distributed import Client
    except ImportError:
        raise ValueError("scheduler: dask.distributed is not installed "
                         "(pip install 'dask[distributed]')") from None
    own = isinstance(scheduler, str)
    if own:
        try:
            client = Client(scheduler, timeout=connect_timeout or DASK_CONNECT_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as e:
            raise ValueError(f"scheduler: cannot connect to the Dask scheduler at "
                             f"{scheduler} ({type(e).__name__}: {e})") from None
    else:
        client = scheduler
    try:
        try:
            client.wait_for_workers(1, timeout=DASK_WORKER_TIMEOUT)
        except (TimeoutError, OSError) as e:
            raise ValueError(f"scheduler: no Dask worker joined {scheduler} within "
                             f"{DASK_WORKER_TIMEOUT} s ({e})") from None
        yield client
    finally:
        if own:
            client.close()


def check_not_bootstrapping():
    """Refuse to start a cluster while this process is a new worker process re-running
    the parent's main module (a script without ``if __name__ == "__main__":``).

    Without this check the worker would start a cluster of its own and the parent would
    wait for it forever.

    Raises
    ------
    RuntimeError
        In a process that ``multiprocessing`` is still bootstrapping.
    """
    import multiprocessing
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise RuntimeError(
            "a Dask worker process is re-running this script's main module and would "
            "start a cluster of its own: put the script's work under "
            "`if __name__ == \"__main__\":` (or pass scheduler=\"synchronous\")")


#: a local cluster without its statistical profiler and disk and GIL monitors (they
#: sample every few milliseconds, for a dashboard nobody reads during a run)
LOCAL_CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False,
                        "distributed.admin.system-monitor.disk": False,
                        "distributed.admin.system-monitor.gil.enabled": False}


def cores() -> int:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def _local_cluster(workers: int | None, preload=(), quiet: bool = False):
    """A ``LocalCluster`` of ``workers`` single-threaded processes (default: the cores),
    which import ``preload`` as they start; ``quiet``: no logs (a task's failure reaches
    its caller as a :class:`~analysis.tasks.TaskError`, not as a worker's log)."""
    import dask
    from dask.distributed import LocalCluster
    check_not_bootstrapping()
    kw = dict(dashboard_address=None, silence_logs=logging.CRITICAL) if quiet else \
        dict(dashboard_address=":0")
    with dask.config.set(LOCAL_CLUSTER_CONFIG):   # the workers get it from their nanny
        return LocalCluster(n_workers=workers or cores(), threads_per_worker=1,
                            processes=True, env={"BIPED_THREADS": "1"},
                            preload=list(preload), **kw)


def connect(scheduler, workers, preload=()):
    """(client, cluster or None) for a resolved scheduler: 'local' (a quiet
    ``LocalCluster`` whose processes import ``preload`` as they start), an address (its
    first worker waited for) or a client.

    Raises
    ------
    ValueError
        Naming 'scheduler': dask.distributed missing, no scheduler at the address, or
        no worker joined it.
    """
    try:
        from dask.distributed import Client
    except ImportError:
        raise ValueError("scheduler: dask.distributed is not installed "
                         "(pip install 'dask[distributed]')") from None
    if scheduler == "local":
        cluster = _local_cluster(workers, preload, quiet=True)
        return Client(cluster), cluster
    if not isinstance(scheduler, str):
        return scheduler, None
    try:
        client = Client(scheduler, timeout=DASK_CONNECT_TIMEOUT)
    except (OSError, TimeoutError, ValueError) as e:
        raise ValueError(f"scheduler: cannot connect to the Dask scheduler at {scheduler} "
                         f"({type(e).__name__}: {e})") from None
    try:
        client.wait_for_workers(1, timeout=DASK_WORKER_TIMEOUT)
    except (TimeoutError, OSError) as e:
        client.close()
        raise ValueError(f"scheduler: no Dask worker joined {scheduler} within "
                         f"{DASK_WORKER_TIMEOUT} s ({e})") from None
    return client, None


@contextlib.contextmanager
def cluster_client(scheduler=None, workers: int | None = None):
    """A Dask client: the given one, a scheduler's address, or a ``LocalCluster``'s.

    Parameters
    ----------
    scheduler : None, 'local', str or dask.distributed.Client
        None or 'local': a ``LocalCluster`` of ``workers`` processes on this machine
        (closed afterwards); otherwise as :func:`dask_client`.
    workers : int, optional
        Processes of the ``LocalCluster`` (default: this machine's cores).

    Yields
    ------
    dask.distributed.Client

    Raises
    ------
    ValueError
        Naming 'scheduler' (see :func:`dask_client`).
    """
    if scheduler is None or scheduler == "local":
        try:
            import dask.distributed as _dd                    # noqa: F401
        except ImportError:
            raise ValueError("scheduler: dask.distributed is not installed") from None
        cluster = _local_cluster(workers)
        try:
            with dask_client(cluster.scheduler_address, DASK_CONNECT_TIMEOUT) as client:
                yield client
        finally:
            cluster.close()
        return
    with dask_client(scheduler, DASK_CONNECT_TIMEOUT) as client:
        yield client


def progress_bar(progress: bool, total: int, initial: int, unit: str, desc: str):
    """A tqdm bar on stderr, shown only when ``progress`` and stderr is a terminal.

    Parameters
    ----------
    progress : bool
        Whether progress is wanted.
    total, initial : int
        Units of work in all, and already done (resumed).
    unit, desc : str
        What a unit is, and what the work is.

    Returns
    -------
    tqdm.tqdm
    """
    from tqdm.auto import tqdm
    return tqdm(total=total, initial=initial, unit=unit, desc=desc,
                disable=not (bool(progress) and sys.stderr.isatty()), file=sys.stderr,
                dynamic_ncols=True)


_ALLOCATOR_TUNED = False


def tune_allocator():
    """Let this process's allocator keep freed memory (once per process; Linux/glibc).

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also fixes
    glibc's mmap threshold at 128 kB: every array above it (a walker's chunk of nodes
    is megabytes) is then mapped and unmapped afresh, its pages faulted in on every
    call, which halves the walkers' throughput in a worker
    (``benchmarks/bench_terrain.py``).  Raising both thresholds here undoes that.
    """
    global _ALLOCATOR_TUNED
    if _ALLOCATOR_TUNED:
        return
    _ALLOCATOR_TUNED = True
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 1 << 26)         # M_MMAP_THRESHOLD: 64 MB
        libc.mallopt(-1, 1 << 27)         # M_TRIM_THRESHOLD: 128 MB
    except (OSError, AttributeError):
        pass


def _in_worker(fn, payload, *args):
    """Run one chunk on a worker, its allocator tuned (:func:`tune_allocator`)."""
    tune_allocator()
    return fn(payload, *args)


def submit_chunks(client, fn, payload, todo, record, name: str, args_of=None):
    """Evaluate chunks on a Dask cluster, recording each as it completes.

    The payload is scattered to every worker once; chunk ``task = (k, ...)`` runs
    ``fn(payload, *args_of(task))`` under a unique key; on any error (or an interruption)
    the chunks not yet done are cancelled and the error is raised.

    Parameters
    ----------
    client : dask.distributed.Client
        The cluster.
    fn : callable
        ``fn(payload, *args) -> result`` (importable by the workers).
    payload : object
        What every chunk needs (sent once).
    todo : list of tuple
        One task ``(k, ...)`` per chunk, k its number.
    record : callable
        ``record(*task, result)`` for each finished chunk, in completion order.
    name : str
        Prefix of the task keys.
    args_of : callable, optional
        The arguments of ``fn`` after the payload for a task (default: ``task[1:]``).
    """
    from dask.distributed import as_completed
    [pf] = client.scatter([payload], broadcast=True)
    args_of = args_of or (lambda task: task[1:])
    futs = {client.submit(_in_worker, fn, pf, *args_of(task), pure=False,
                          key=f"{name}-{task[0]}-{os.getpid()}-{time.monotonic_ns()}"): task
            for task in todo}
    try:
        for f in as_completed(list(futs)):
            record(*futs[f], f.result())
    except BaseException:
        client.cancel(list(futs))
        raise
