"""Sweeps of the output matrix M1 (paper §V-A, Fig. 2): max|lambda| of A^z and the status
of docs: theory §4 for many M1, in parallel, stored as they are computed, resumable.

    from analysis.sweeps.sweep import grid_points, run_sweep
    r = run_sweep(gait, grid_points(9, -10, 10), out_dir="sweep9")
    r.counts          # {'stable': .., 'unstable': .., 'singular': .., 'no_impact': ..}
    r.point_status    # the status of docs: theory §4 of every point

The points are cut into chunks of ``chunk_size`` rows; each chunk is evaluated by
:meth:`analysis.stability.poincare.PoincareMap.jacobian_batch` (the vectorised variational
equation; ``SweepSettings(method='ad')`` uses the full AD map instead) in a worker
process that builds and caches the map once from the gait's dictionary, or on the
workers of a Dask distributed cluster (``scheduler='tcp://host:port'``).  With
``out_dir`` every finished chunk is written at once (``analysis.sweeps.storage``: Parquet per
chunk, atomic); a rerun with the same folder and settings reads what is stored, checks it,
recomputes only what is missing or corrupt, and returns exactly the same numbers as an
uninterrupted run.  A folder made with other settings is refused.

Where the work goes.  The variational path is one CasADi SX Function of M1 mapped over
threads, a fraction of a millisecond per M1, so the 9^4 grid is about a second of work:
starting worker processes (~1-2 s each: import CasADi, rebuild the gait and the map) costs
more than they save, and the default runs the chunks on threads of this process sharing
one map (measured in ``benchmarks/bench_sweep.py``: threads, one thread, processes).
``executor='process'`` pays off only for sweeps of 10^5 points and more; Dask when more
machines than cores are at hand.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biped_casadi import require_same_robot
from biped_casadi.control.reference import require_reference
from biped_casadi.caching import code_version

from ..stability.poincare import singular_m1_values
from .storage import META, SweepStore, digest_points

from .points import _check_points, grid_points, line_points, max_grid_n
from .results import RESULTS_VERSION, BestPoint, SweepResult, SweepSettings, _result
from .workers import SweepPayload, _progress_bar, dispatch, evaluate_chunk

__all__ = ["run_sweep", "SweepResult", "BestPoint", "SweepSettings", "grid_points", "line_points",
           "max_grid_n", "one_d_sweeps", "OneDSweeps", "load_sweep", "evaluate_chunk",
           "RESULTS_VERSION", "DEFAULT_CHUNK_SIZE"]

DEFAULT_CHUNK_SIZE = 256


@dataclass
class _Arrays:
    """The sweep's result arrays, filled chunk by chunk."""
    status: np.ndarray
    max_abs: np.ndarray
    ev: np.ndarray
    A: np.ndarray

    @classmethod
    def empty(cls, n):
        return cls(np.full(n, "", dtype="<U10"), np.full(n, np.nan),
                   np.full((n, 2), np.nan + 0j), np.full((n, 2, 2), np.nan))

    def fill(self, a, b, c):
        self.status[a:b] = c["status"]
        self.max_abs[a:b] = c["max_abs"]
        self.ev[a:b] = c["eigenvalues"]
        self.A[a:b] = c["A"]


def _check_run_arguments(gait, executor, workers, chunk_size):
    model = gait.model
    require_same_robot(model, gait)
    if executor not in ("process", "thread"):
        raise ValueError(f"executor must be 'process' or 'thread', got {executor!r}")
    if workers is not None and (isinstance(workers, bool)
                                or not isinstance(workers, (int, np.integer)) or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)) \
            or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")


def _read_stored(store, bounds, P, arrays):
    """Chunks already in the folder: (reused chunk numbers, corrupt chunk -> reason);
    damaged or foreign files are removed."""
    reused, corrupt = [], {}
    files = store.chunk_files()
    for k, a, b in bounds:
        for path in files.pop(k, []):
            if k in reused:             # a second copy of a chunk already read
                store.discard(path)
                continue
            try:
                c = store.read_chunk(path, k, a, P[a:b])
            except ValueError as e:
                corrupt[k] = str(e)
                store.discard(path)
                continue
            arrays.fill(a, b, c)
            reused.append(k)
    for k, paths in files.items():      # numbers outside this sweep's chunks
        corrupt[k] = "chunk number out of range"
        for path in paths:
            store.discard(path)
    return reused, {k: v for k, v in corrupt.items() if k not in reused}


def run_sweep(gait, points, out_dir=None, chunk_size: int | None = None,
              workers: int | None = None, scheduler=None, progress: bool = True,
              settings: SweepSettings | dict | None = None,
              executor: str = "thread") -> SweepResult:
    """max|lambda| and status for every M1 in ``points``.

    Parameters
    ----------
    gait : Reference
        A :class:`gait_opt.Gait` made for ``model``.
    points : array_like
        (n, nu) output matrices M1 (nu = ``model.nu``).
    out_dir : str or Path, optional
        Folder for the results, written chunk by chunk and resumable; None keeps them in
        memory only.
    chunk_size : int, optional
        Points per chunk (default 256; when resuming, the folder's own).
    workers : int, optional
        Local workers (default: all cores); 1 runs chunk after chunk in this process.
    scheduler : None, str or dask.distributed.Client, optional
        Where the chunks run (:func:`analysis.tasks.resolve_scheduler`, the same meaning
        for every function): 'synchronous', chunk after chunk in this process; 'local'
        (the default outside a task), this machine's cores (threads of this process
        sharing one map); a Dask scheduler's address ('tcp://host:port') or client: its
        workers.
    progress : bool
        A progress bar on stderr (when it is a terminal).
    settings : SweepSettings or dict, optional
        How each M1 is evaluated (default ``SweepSettings()``).
    executor : {'thread', 'process'}
        Threads of this process sharing one map (default), or spawned processes, each
        rebuilding the map (~1 s each to start, worth it only for very large sweeps).

    Returns
    -------
    SweepResult
        Row i for ``points[i]``.
    """
    model = require_reference(gait).model
    t0 = time.perf_counter()
    settings = _settings(settings)
    P = _check_points(points, model.nu)
    if chunk_size is None and out_dir is not None:
        chunk_size = _stored_chunk_size(out_dir)
    chunk_size = DEFAULT_CHUNK_SIZE if chunk_size is None else chunk_size
    _check_run_arguments(gait, executor, workers, chunk_size)
    chunk_size = int(chunk_size)
    gdict = gait.definition()
    payload = SweepPayload(gait=gdict, gait_sha256=gait.cache_key, map=settings.to_dict())
    n = len(P)
    bounds = [(k, a, min(a + chunk_size, n)) for k, a in enumerate(range(0, n, chunk_size))]
    identity = dict(results_version=RESULTS_VERSION, code_sha256=code_version("sweep"),
                    gait_sha256=payload.gait_sha256,
                    robot=model.params.name, points_sha256=digest_points(P), n_points=n,
                    m1_size=model.nu, chunk_size=chunk_size, map=settings.to_dict())
    arrays = _Arrays.empty(n)
    reused, computed, corrupt = [], [], {}
    store = SweepStore(out_dir, identity).open() if out_dir is not None else None
    try:
        if store is not None:
            reused, corrupt = _read_stored(store, bounds, P, arrays)
        todo = [bd for bd in bounds if bd[0] not in set(reused)]
        if store is not None:
            store.log(dict(event="start", time=time.time(), pid=os.getpid(),
                           n_chunks=len(bounds), reused=len(reused),
                           corrupt={str(k): v for k, v in corrupt.items()},
                           to_compute=[k for k, _, _ in todo]))
        bar = _progress_bar(progress, total=n, initial=n - sum(b - a for _, a, b in todo))

        def record(k, a, b, c):
            arrays.fill(a, b, c)
            if store is not None:
                store.write_chunk(k, a, P[a:b], c["status"], c["max_abs"], c["A"],
                                  c["eigenvalues"])
            computed.append(k)
            bar.update(b - a)

        try:
            if todo:
                dispatch(todo, payload, P, record, scheduler, workers, executor)
        finally:
            bar.close()
            if store is not None:
                done = len(reused) + len(computed) == len(bounds)
                store.log(dict(event="done" if done else "stopped", time=time.time(),
                               pid=os.getpid(), computed=sorted(computed)))
    finally:
        if store is not None:
            store.close()
    return _result(P, arrays.status, arrays.max_abs, arrays.ev, arrays.A,
                   elapsed=time.perf_counter() - t0, chunk_size=chunk_size, settings=identity,
                   out_dir=Path(out_dir) if out_dir is not None else None,
                   computed_chunks=sorted(computed), reused_chunks=sorted(reused),
                   corrupt_chunks=corrupt,
                   n_computed=sum(b - a for k, a, b in bounds if k in set(computed)))


def load_sweep(out_dir) -> SweepResult:
    """Read a finished sweep folder back (without the gait).

    Every chunk is checked on the way (digests, settings, rows).

    Parameters
    ----------
    out_dir : str or Path
        A folder written by :func:`run_sweep` (or ``biped sweep --out``).

    Returns
    -------
    SweepResult
        Row i for the i-th stored point; ``elapsed`` 0.

    Raises
    ------
    ValueError
        When the folder is not a sweep folder, or is incomplete or damaged.
    """
    import pyarrow.parquet as pq
    root = Path(out_dir)
    try:
        identity = json.loads((root / META).read_text())["settings"]
        n, cs, nm = identity["n_points"], identity["chunk_size"], identity["m1_size"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"out_dir: {root} is not a readable sweep folder ({e})") from None
    store = SweepStore(root, identity)
    files = store.chunk_files()
    cols = []
    for k, a in enumerate(range(0, n, cs)):
        for path in files.get(k, []):
            try:
                t = pq.read_table(path, columns=[f"M1_{j + 1}" for j in range(nm)])
                pts = np.stack([t.column(j).to_numpy() for j in range(nm)], axis=1)
                cols.append((pts, store.read_chunk(path, k, a, pts)))
                break
            except Exception:       # noqa: BLE001 - damaged: try another copy, or fail
                continue
        else:
            raise ValueError(f"out_dir: {root} is incomplete (chunk {k} missing or "
                             f"damaged); rerun the sweep to finish it")
    P = np.concatenate([p for p, _ in cols])
    st = np.concatenate([c["status"] for _, c in cols]).astype("<U10")
    return _result(P, st, np.concatenate([c["max_abs"] for _, c in cols]),
                   np.concatenate([c["eigenvalues"] for _, c in cols]),
                   np.concatenate([c["A"] for _, c in cols]), elapsed=0.0, chunk_size=cs,
                   settings=identity, out_dir=root, reused_chunks=list(range(len(cols))))


def _settings(s) -> SweepSettings:
    if s is None:
        return SweepSettings()
    if isinstance(s, SweepSettings):
        return s
    if isinstance(s, dict):
        try:
            return SweepSettings(**s)
        except TypeError as e:
            raise ValueError(f"settings: {e}") from None
    raise ValueError(f"settings must be a SweepSettings or a dict, got {type(s).__name__}")


def _stored_chunk_size(out_dir):
    try:
        return int(json.loads((Path(out_dir) / META).read_text())["settings"]["chunk_size"])
    except (OSError, ValueError, KeyError, TypeError):
        return None        # no (readable) folder yet: SweepStore.open says the rest



# ----------------------------------------------------- Fig. 2: 1-D sweeps
@dataclass
class OneDSweeps:
    """The 1-D sweeps of Fig. 2: one per component of M1 (four for RABBIT).

    Parameters
    ----------
    values : list of numpy.ndarray
        ``values[j]``: the values of component j.
    results : list of SweepResult
        ``results[j]``: the sweep over ``values[j]`` with the other components zero.
    singular_values : numpy.ndarray
        (nu,): D11/D12(j) at q^d(T), where component j alone makes the controller
        singular (eq. 24).
    sweep : SweepResult
        All the points as one sweep.
    """
    values: list
    results: list
    singular_values: np.ndarray
    sweep: SweepResult


def one_d_sweeps(gait, values, out_dir=None, **kw) -> OneDSweeps:
    """Fig. 2: max|lambda| against each component M1(j) with the others zero.

    Parameters
    ----------
    gait : Reference
        A :class:`gait_opt.Gait` made for ``model``.
    values : array_like or list of array_like
        One array for every component, or one array per component (nu of them).
    out_dir : str or Path, optional
        Runs as one sweep (one pool, one folder).
    **kw
        Passed to :func:`run_sweep`.

    Returns
    -------
    OneDSweeps
        One sweep per component and the singular values.
    """
    model = gait.model
    nu = model.nu
    if isinstance(values, (list, tuple)) and len(values) == nu and np.ndim(values[0]) == 1:
        vals = [np.asarray(v, dtype=float).ravel() for v in values]
    else:
        vals = [np.asarray(values, dtype=float).ravel()] * nu
    P = np.concatenate([line_points(j, v, nu) for j, v in enumerate(vals)])
    r = run_sweep(gait, P, out_dir=out_dir, **kw)
    ends = np.cumsum([0] + [len(v) for v in vals])
    parts = [r.subset(np.arange(ends[j], ends[j + 1])) for j in range(nu)]
    return OneDSweeps(vals, parts, singular_m1_values(gait), r)
