"""Work on a Dask distributed cluster: one way to connect, used by the sweeps
(:mod:`analysis.sweeps.sweep`) and the robustness searches (:mod:`analysis.robustness.s_star`)."""
from __future__ import annotations

import contextlib

__all__ = ["dask_client", "DASK_CONNECT_TIMEOUT", "DASK_WORKER_TIMEOUT"]

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
