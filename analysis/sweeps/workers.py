"""Where a sweep's chunks are evaluated: threads of this process, worker processes, or the
workers of a Dask cluster.  Every worker builds the Poincaré map once from the gait's
definition (:meth:`gait_opt.Gait.definition`) and returns chunks tagged with the digest of
the code that computed them."""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from biped_casadi.caching import cached, digest
from gait_opt import Gait

from ..cluster import DASK_CONNECT_TIMEOUT, dask_client, progress_bar, submit_chunks
from ..stability.poincare import PoincareMap, poincare_map
from ..tasks import resolve_scheduler

from .results import SweepSettings, code_digest

__all__ = ["SweepPayload", "evaluate_chunk", "dispatch"]


@dataclass(frozen=True)
class SweepPayload:
    """What a worker needs to evaluate chunks: the gait's dictionary, its digest and the
    map settings (picklable, sent once to every process or Dask worker)."""
    gait: dict
    gait_sha256: str
    map: dict

    @property
    def cache_key(self):
        return (self.gait_sha256, digest(self.map))


@cached(maxsize=4)
def _poincare_for(payload: SweepPayload) -> PoincareMap:
    """The PoincareMap of a payload: built once per process (memoised by the gait's
    digest and the options, the same key as the caller's own ``poincare_map``)."""
    gait = Gait.from_dict(payload.gait)
    return poincare_map(gait, **SweepSettings(**payload.map).map_options())


def _init_worker(payload):
    _poincare_for(payload)


def evaluate_chunk(payload: SweepPayload, points: np.ndarray) -> dict:
    """Evaluate one chunk of M1 (runs in worker processes and on Dask workers).

    Parameters
    ----------
    payload : SweepPayload
        The gait's dictionary, its digest and the map settings (the map is built once
        per process from it).
    points : numpy.ndarray
        (n, nu) output matrices.

    Returns
    -------
    dict
        ``status`` (n,) strings, ``max_abs`` (n,), ``eigenvalues`` (n, 2) complex with
        ``|.|`` descending, ``A`` (n, 2, 2), and ``code_sha256`` (:func:`code_digest`
        of the worker's code).
    """
    pm = _poincare_for(payload)
    P = np.asarray(points, dtype=float)
    if payload.map["method"] == "variational":
        jb = pm.jacobian_batch(P)
        status, A, ev, max_abs = jb.status, jb.A, jb.eigenvalues, jb.max_abs
        status = np.asarray(status).astype("<U9")
        order = np.argsort(-np.abs(ev), axis=1, kind="stable")
        ev = np.take_along_axis(ev, order, axis=1)
    else:
        rs = pm.analyse_batch(P)
        status = np.array([r.status for r in rs], dtype="<U9")
        A = np.stack([np.asarray(r.A, float) for r in rs])
        ev = np.stack([np.asarray(r.eigenvalues, complex) for r in rs])
        max_abs = np.array([r.max_abs for r in rs], dtype=float)
    return dict(status=status, max_abs=np.asarray(max_abs, float),
                eigenvalues=np.asarray(ev, complex), A=np.asarray(A, float),
                code_sha256=code_digest())



def _cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def _progress_bar(progress, total, initial):
    return progress_bar(progress, total, initial, "M1", "sweep")


def _run_threads(payload, P, todo, record, workers):
    from concurrent.futures import ThreadPoolExecutor, as_completed
    with ThreadPoolExecutor(max_workers=min(workers, len(todo))) as ex:
        futs = {ex.submit(evaluate_chunk, payload, P[a:b]): (k, a, b) for k, a, b in todo}
        try:
            for f in as_completed(futs):
                record(*futs[f], f.result())
        except BaseException:
            for f in futs:
                f.cancel()
            raise


def _run_processes(payload, P, todo, record, workers):
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed
    # spawn: safe whatever threads the caller runs (a Dask client, tqdm's monitor)
    ex = ProcessPoolExecutor(max_workers=min(workers, len(todo)),
                             mp_context=mp.get_context("spawn"),
                             initializer=_init_worker, initargs=(payload,))
    try:
        futs = {ex.submit(evaluate_chunk, payload, P[a:b]): (k, a, b) for k, a, b in todo}
        for f in as_completed(futs):
            record(*futs[f], f.result())
    except BaseException:
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown(wait=True)


def _run_dask(scheduler, payload, P, todo, record):
    with dask_client(scheduler, DASK_CONNECT_TIMEOUT) as client:
        submit_chunks(client, evaluate_chunk, payload, todo, record,
                      f"sweep-{payload.gait_sha256[:8]}", args_of=lambda t: (P[t[1]:t[2]],))


def dispatch(todo, payload, P, record, scheduler, workers, executor):
    """Evaluate the chunks ``todo`` where the caller asked, calling ``record`` for each:
    ``scheduler`` resolved by :func:`analysis.tasks.resolve_scheduler` ('synchronous':
    chunk after chunk in this process; 'local': this machine's cores, threads of this
    process sharing one map (or processes, ``executor='process'``); a cluster: its
    workers)."""
    where = resolve_scheduler(scheduler, int(workers) if workers else None)
    if where not in ("synchronous", "local"):
        _run_dask(where, payload, P, todo, record)
        return
    workers = 1 if where == "synchronous" else (workers or _cpu_count())
    if executor == "process" and workers > 1 and len(todo) > 1:
        _run_processes(payload, P, todo, record, workers)
        return
    pm = _poincare_for(payload)             # shared by the threads of this process
    if payload.map["method"] == "variational":
        pm.variational                      # build the tables before any thread uses them
    if workers == 1 or len(todo) == 1:
        for k, a, b in todo:
            record(k, a, b, evaluate_chunk(payload, P[a:b]))
    else:
        _run_threads(payload, P, todo, record, workers)


