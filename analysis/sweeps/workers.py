"""Where a sweep's chunks are evaluated: each chunk is a task of an engine
(:mod:`analysis.tasks`) run in this process, on threads of this process sharing one
Poincaré map (the default), on worker processes, or on the workers of a Dask cluster,
each building the map once from the gait's definition (:meth:`gait_opt.Gait.definition`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from biped_casadi.caching import cached, digest
from gait_opt import Gait

from ..reporting.progress import progress_bar
from ..stability.poincare import PoincareMap, poincare_map
from ..tasks import Engine, TaskError, resolve_scheduler, task

from .results import SweepSettings

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


@task(code="sweep")
def evaluate_chunk(payload: SweepPayload, points: np.ndarray) -> dict:
    """Evaluate one chunk of M1 (a task: in this process, a worker thread or process).

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
        ``|.|`` descending and ``A`` (n, 2, 2).
    """
    pm = _poincare_for(payload)
    P = np.asarray(points, dtype=float)
    if payload.map["method"] == "variational":
        jb = pm.jacobian_batch(P)
        status, A, ev, max_abs = jb.status, jb.A, jb.eigenvalues, jb.max_abs
        status = np.asarray(status).astype("<U10")
        order = np.argsort(-np.abs(ev), axis=1, kind="stable")
        ev = np.take_along_axis(ev, order, axis=1)
    else:
        rs = pm.analyse_batch(P)
        status = np.array([r.status for r in rs], dtype="<U10")
        A = np.stack([np.asarray(r.A, float) for r in rs])
        ev = np.stack([np.asarray(r.eigenvalues, complex) for r in rs])
        max_abs = np.array([r.max_abs for r in rs], dtype=float)
    return dict(status=status, max_abs=np.asarray(max_abs, float),
                eigenvalues=np.asarray(ev, complex), A=np.asarray(A, float))



def _progress_bar(progress, total, initial):
    return progress_bar(progress, total, initial, "M1", "sweep")


def dispatch(todo, payload, P, record, scheduler, workers, executor):
    """Evaluate the chunks ``todo`` where the caller asked, calling ``record`` for each as
    it arrives: ``scheduler`` resolved by :func:`analysis.tasks.resolve_scheduler`
    ('synchronous': chunk after chunk in this process; 'local': this machine's cores,
    threads of this process sharing one map, or processes with ``executor='process'``;
    a cluster: its workers)."""
    where = resolve_scheduler(scheduler, int(workers) if workers else None)
    where = "synchronous" if where == "local" and len(todo) == 1 else where
    threads = where == "local" and executor != "process"
    if threads or where == "synchronous":
        pm = _poincare_for(payload)             # built here, shared by the threads
        if payload.map["method"] == "variational":
            pm.variational
    with Engine(where, int(workers) if workers else None, cache=False, processes=not threads,
                preload=(__name__,)) as eng:
        try:
            for (k, a, b), c in eng.each(evaluate_chunk, {t: (payload, P[t[1]:t[2]])
                                                          for t in todo}):
                record(k, a, b, c)
        except TaskError as e:
            raise ValueError(f"scheduler: {e}") from None
