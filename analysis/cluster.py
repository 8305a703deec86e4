"""The one way to reach Dask: :func:`connect` to a scheduler's address, a client or a
``LocalCluster`` of this machine (started without waiting for its workers), and what
the processes of a cluster need (the bootstrapping check, the allocator)."""
from __future__ import annotations

import contextlib
import copy
import ctypes
import functools
import logging
import multiprocessing.resource_tracker
import signal

__all__ = ["connect", "close_cluster", "check_workers", "check_not_bootstrapping",
           "tune_allocator", "LOCAL_CLUSTER_CONFIG", "DASK_CONNECT_TIMEOUT",
           "DASK_WORKER_TIMEOUT"]

#: how long to wait for a Dask scheduler to answer, and for a first worker to join it
DASK_CONNECT_TIMEOUT = "10s"
DASK_WORKER_TIMEOUT = 60

#: a local cluster without its statistical profiler and disk and GIL monitors (they
#: sample every few milliseconds, for a dashboard nobody reads during a run)
LOCAL_CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False,
                        "distributed.admin.system-monitor.disk": False,
                        "distributed.admin.system-monitor.gil.enabled": False}


def check_not_bootstrapping():
    """Refuse to start a cluster in a new worker process that re-runs the parent's main
    module (a script without ``if __name__ == "__main__":``), which would start a
    cluster of its own while the parent waits for it.

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


def connect(scheduler, workers: int | None = None, preload=(), processes: bool = True):
    """A Dask client, and the cluster it started (None for an existing one).

    Parameters
    ----------
    scheduler : str or dask.distributed.Client
        'local': a ``LocalCluster`` of ``workers`` single-threaded processes that import
        ``preload`` as they start (or, with ``processes=False``, of ``workers`` threads
        of this process), returned at once, its workers joining in the background; an
        address ('tcp://host:8786'): that scheduler, once a worker has joined; a
        client: itself.
    workers : int, optional
        The local cluster's workers (default: the cores this process may use).
    preload : tuple of str
        Modules the local cluster's processes import as they start.
    processes : bool
        Processes or threads.

    Returns
    -------
    tuple
        (client, cluster or None).

    Raises
    ------
    ValueError
        Naming 'scheduler': dask.distributed missing, a malformed address or no
        scheduler answering at it within :data:`DASK_CONNECT_TIMEOUT`, or no worker
        joined it within :data:`DASK_WORKER_TIMEOUT` seconds.
    """
    try:
        import dask
        from dask.distributed import Client, LocalCluster
        from dask.system import CPU_COUNT
    except ImportError:
        raise ValueError("scheduler: dask.distributed is not installed "
                         "(pip install 'dask[distributed]')") from None
    if scheduler == "local":
        check_not_bootstrapping()
        n = workers or CPU_COUNT       # Dask's count: affinity, cgroup quota
        # SIGINT blocked in the cluster's threads and so in its workers: a terminal's Ctrl-C
        # stops this process, which closes them (the resource tracker first: it unblocks it)
        multiprocessing.resource_tracker.ensure_running()
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            with dask.config.set(LOCAL_CLUSTER_CONFIG):   # the nannies (made later) pass it on
                kw = dict(n_workers=0, threads_per_worker=1, env={"BIPED_THREADS": "1"},
                          preload=list(preload), config=copy.deepcopy(dask.config.config)) \
                    if processes else dict(n_workers=1, threads_per_worker=n)
                cluster = LocalCluster(processes=processes, dashboard_address=":0",
                                       silence_logs=logging.CRITICAL, **kw)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        from distributed.gc import disable_gc_diagnosis     # its gc callback (logs we
        disable_gc_diagnosis(force=True)    # silence) took a Ctrl-C raised in it for itself
        client = Client(cluster)        # before scale: a client waits for a scaling cluster
        if processes:
            cluster.scale(n)
        return client, cluster
    if not isinstance(scheduler, str):
        return scheduler, None
    try:        # an address without host and port, or no scheduler there: refused before
        from distributed.comm import get_address_host_port      # a client (its thread)
        get_address_host_port(scheduler)
        _identity(scheduler)
        client = Client(scheduler, timeout=DASK_CONNECT_TIMEOUT)
    except (OSError, TimeoutError, ValueError, AssertionError) as e:
        what = "Dask's client thread did not start within 10 s" if isinstance(
            e, AssertionError) else f"{type(e).__name__}: {e}"   # (the assertion it has)
        raise ValueError(f"scheduler: cannot connect to the Dask scheduler at {scheduler} "
                         f"({what}); is 'dask scheduler' running there? "
                         "(its log prints the address to give)") from None
    try:
        client.wait_for_workers(1, timeout=DASK_WORKER_TIMEOUT)
    except (TimeoutError, OSError) as e:
        client.close()
        raise ValueError(f"scheduler: no Dask worker joined {scheduler} within "
                         f"{DASK_WORKER_TIMEOUT} s ({e})") from None
    return client, None


def close_cluster(cluster, within: float = 10.0):
    """Close a local cluster :func:`connect` started, at once while its workers start too.

    Dask's nanny closes its worker only once it has started (20 s of imports under
    load); so the worker processes still starting are killed first (as Dask kills one
    that does not stop), their nannies ending as for workers that failed to start.

    Parameters
    ----------
    cluster : distributed.LocalCluster
        The cluster.
    within : float
        How long, s, at most, to wait for its nannies to end their starts.
    """
    import asyncio

    async def kill_starting():
        killed, end = set(), asyncio.get_running_loop().time() + within
        while asyncio.get_running_loop().time() < end and (nannies := [
                n for n in list(cluster._created) if hasattr(n, "process")
                and n.status.name == "init"]):      # (a nanny's, not a thread's worker)
            for w in {n.process for n in nannies} - killed - {None}:
                if w.status.name == "starting":     # (process created: killed once)
                    killed.add(w)
                    await w.process.kill()
            await asyncio.sleep(0.01)
    with contextlib.suppress(Exception):
        cluster.sync(kill_starting)
    cluster.close()


def _identity(address: str) -> dict:
    """What the Dask scheduler at ``address`` says it is, asked within the connect timeout
    (a client's handshake has none: a web server there held it for ever; one that
    answered something else made it allocate exabytes; a worker's address fails too)."""
    import asyncio
    import concurrent.futures
    from dask.utils import parse_timedelta
    from distributed.core import rpc
    timeout = parse_timedelta(DASK_CONNECT_TIMEOUT)

    async def ask():
        async with rpc(address, timeout=timeout) as server:
            return await asyncio.wait_for(server.identity(n_workers=0), timeout)

    with concurrent.futures.ThreadPoolExecutor(1) as pool:  # (a caller's running loop)
        try:
            return pool.submit(asyncio.run, ask()).result()
        except (OSError, TimeoutError) as e:           # (asyncio's timeout says nothing)
            raise type(e)(str(e) or f"no answer within {DASK_CONNECT_TIMEOUT}") from None
        except Exception as e:                      # noqa: BLE001 - not Dask's answer
            raise ValueError(f"what answers there is not a Dask scheduler ({type(e).__name__} "
                             "reading its answer)") from None


def check_workers(client, kind: str = "numerical"):
    """Refuse a cluster whose workers run other code than this process, before any work
    (each task is refused on such a worker too, one by one: a whole report of failed
    stages).

    Parameters
    ----------
    client : dask.distributed.Client
        Connected to the cluster.
    kind : str
        The code set to compare (:data:`biped_casadi.caching.CODE_SETS`).

    Raises
    ------
    ValueError
        Naming 'scheduler', the first worker that differs and its first file (or the
        first file changed on disk after the worker imported the toolkit).
    """
    from biped_casadi.caching import code_edited, code_files, files_differing
    mine, edited = code_files(kind), client.run(code_edited, kind)
    for address, theirs in sorted(client.run(code_files, kind).items()):
        if edited.get(address):
            raise ValueError(f"scheduler: the Dask worker {address} runs other code: "
                             f"{edited[address]} changed on disk after it imported the "
                             "toolkit; restart the worker")
        if differing := files_differing(mine, theirs):
            raise ValueError(f"scheduler: the Dask worker {address} runs other code: "
                             f"{differing} in this checkout; "
                             "run the same version of the toolkit on every worker")


@functools.cache
def tune_allocator():
    """Let this process's allocator keep freed memory (once per process; Linux/glibc).

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also fixes
    glibc's mmap threshold at 128 kB: every array above it is then mapped and unmapped
    afresh, which halves the walkers' throughput in a worker
    (``benchmarks/bench_terrain.py``).  Raising both thresholds here undoes that.
    """
    with contextlib.suppress(OSError, AttributeError):      # no glibc: nothing to tune
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 1 << 26)         # M_MMAP_THRESHOLD: 64 MB
        libc.mallopt(-1, 1 << 27)         # M_TRIM_THRESHOLD: 128 MB
