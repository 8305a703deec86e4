"""Sweeps of the output matrix M1 (paper §V-A, Fig. 2): max|lambda| of A^z and the status
of SPEC §4 for many M1, in parallel, stored as they are computed, resumable.

    from analysis.sweep import grid_points, run_sweep
    r = run_sweep(model, gait, grid_points(9, -10, 10), out_dir="sweep9")
    r.counts          # {'stable': .., 'unstable': .., 'singular': .., 'no_impact': ..}

The points are cut into chunks of ``chunk_size`` rows; each chunk is evaluated by
:meth:`analysis.poincare.PoincareMap.jacobian_batch` (the vectorised variational
equation; ``SweepSettings(method='ad')`` uses the full AD map instead) in a worker
process that builds and caches the map once from the gait's dictionary, or on the
workers of a Dask distributed cluster (``scheduler='tcp://host:port'``).  With
``out_dir`` every finished chunk is written at once (``analysis.storage``: Parquet per
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

import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .poincare import STATUSES, PoincareMap, singular_m1_values
from .storage import (SweepStore, SweepStoreError, digest_json, digest_points)

__all__ = ["run_sweep", "SweepResult", "SweepSettings", "grid_points", "line_points",
           "one_d_sweeps", "OneDSweeps", "plot_fig2", "load_sweep", "evaluate_chunk",
           "gait_to_dict", "gait_from_dict", "code_digest", "RESULTS_VERSION",
           "DEFAULT_CHUNK_SIZE"]

#: bump when a change in analysis/ alters the numbers computed for the same settings,
#: so that folders written before are refused instead of mixed
RESULTS_VERSION = 1
DEFAULT_CHUNK_SIZE = 256
#: how long to wait for a Dask scheduler to answer, and for a first worker to join
DASK_CONNECT_TIMEOUT = "10s"
DASK_WORKER_TIMEOUT = 60
METHODS = ("variational", "ad")
#: the modules whose code decides the numbers; their SHA-256 is part of a sweep's
#: settings (a folder written by other code is refused) and is checked on every result
#: coming back from a worker (a Dask worker running other code is an error, not a mix)
NUMERIC_MODULES = ("analysis.poincare", "analysis.variational", "biped_casadi.correction",
                   "biped_casadi.model", "gait_opt.gait", "gait_opt.reference")
_CODE_DIGEST = None


def code_digest() -> str:
    """SHA-256 of the source of :data:`NUMERIC_MODULES` (and RESULTS_VERSION)."""
    global _CODE_DIGEST
    if _CODE_DIGEST is None:
        import hashlib
        import importlib
        h = hashlib.sha256(f"results_version={RESULTS_VERSION}".encode())
        for name in NUMERIC_MODULES:
            h.update(name.encode())
            h.update(Path(importlib.import_module(name).__file__).read_bytes())
        _CODE_DIGEST = h.hexdigest()
    return _CODE_DIGEST


@dataclass(frozen=True)
class SweepSettings:
    """How each M1 is evaluated.  ``method``: 'variational' (batched variational
    equation, the sweep path) or 'ad' (full AD through the discrete map, ~1000x slower);
    ``n_pre``, ``n_post``, ``n_scan``, ``horizon``: options of
    :class:`analysis.poincare.PoincareMap`."""
    method: str = "variational"
    n_pre: int = 80
    n_post: int = 240
    n_scan: int = 250
    horizon: float = 2.0

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"settings.method must be one of {METHODS}, got {self.method!r}")
        for name in ("n_pre", "n_post", "n_scan"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise ValueError(f"settings.{name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        if not (isinstance(self.horizon, (int, float)) and math.isfinite(self.horizon)
                and self.horizon > 1):
            raise ValueError(f"settings.horizon must be a number > 1 (in steps T), "
                             f"got {self.horizon!r}")
        object.__setattr__(self, "horizon", float(self.horizon))

    def to_dict(self) -> dict:
        return dict(method=self.method, n_pre=self.n_pre, n_post=self.n_post,
                    n_scan=self.n_scan, horizon=self.horizon)

    def map_options(self) -> dict:
        return dict(n_pre=self.n_pre, n_post=self.n_post, n_scan=self.n_scan,
                    horizon=self.horizon)


@dataclass
class SweepResult:
    """Results of a sweep, row i for ``points[i]``.  ``status`` strings of SPEC §4;
    ``max_abs`` inf where singular or no impact; ``eigenvalues`` (n, 2) complex, |.|
    descending, NaN where undefined; ``A`` (n, 2, 2).  ``computed_chunks`` were evaluated
    by this run, ``reused_chunks`` read back from ``out_dir``, ``corrupt_chunks`` (chunk ->
    reason) found damaged and recomputed.  ``elapsed`` is this run's wall time, s."""
    points: np.ndarray
    status: np.ndarray
    max_abs: np.ndarray
    eigenvalues: np.ndarray
    A: np.ndarray
    counts: dict
    elapsed: float
    chunk_size: int
    settings: dict
    out_dir: Path | None = None
    computed_chunks: list = field(default_factory=list)
    reused_chunks: list = field(default_factory=list)
    corrupt_chunks: dict = field(default_factory=dict)
    n_computed: int = 0

    @property
    def n_points(self) -> int:
        return len(self.points)

    def best(self):
        """(M1, max_abs) of the smallest finite max|lambda|, or None."""
        finite = np.isfinite(self.max_abs)
        if not finite.any():
            return None
        i = int(np.flatnonzero(finite)[np.argmin(self.max_abs[finite])])
        return self.points[i].copy(), float(self.max_abs[i])

    def summary(self) -> dict:
        """The JSON summary printed by ``biped sweep --json``."""
        b = self.best()
        return dict(counts=dict(self.counts), n_points=self.n_points,
                    elapsed=round(self.elapsed, 4),
                    out=str(self.out_dir) if self.out_dir is not None else None,
                    best=None if b is None else dict(M1=b[0].tolist(), max_abs=b[1]),
                    computed_points=self.n_computed,
                    reused_points=self.n_points - self.n_computed,
                    corrupt_chunks=len(self.corrupt_chunks))

    def subset(self, rows) -> "SweepResult":
        rows = np.asarray(rows)
        st = self.status[rows]
        return SweepResult(self.points[rows], st, self.max_abs[rows],
                           self.eigenvalues[rows], self.A[rows], _counts(st), self.elapsed,
                           self.chunk_size, self.settings, self.out_dir)


# ------------------------------------------------------------------ points
def grid_points(n: int, lo: float, hi: float) -> np.ndarray:
    """The n^4 grid, each component of M1 in ``linspace(lo, hi, n)``, component 1
    varying slowest: shape (n^4, 4).  The paper's grid is ``grid_points(9, -10, 10)``."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n (grid points per component) must be a positive integer, got {n!r}")
    if n ** 4 > 50_000_000:
        raise ValueError(f"n = {n} gives {n ** 4} points; at most 50 million (n <= 84)")
    lo, hi = _check_range(lo, hi)
    v = np.linspace(lo, hi, int(n))
    return np.stack(np.meshgrid(v, v, v, v, indexing="ij"), axis=-1).reshape(-1, 4)


def line_points(j: int, values) -> np.ndarray:
    """M1 with component ``j`` (0-based: the paper's M1(j+1)) set to each of ``values``
    and the other three zero: shape (len(values), 4)."""
    if isinstance(j, bool) or not isinstance(j, (int, np.integer)) or not 0 <= j <= 3:
        raise ValueError(f"j (component of M1, 0..3) must be 0, 1, 2 or 3, got {j!r}")
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0 or not np.all(np.isfinite(v)):
        raise ValueError("values must be a non-empty list of finite numbers")
    P = np.zeros((v.size, 4))
    P[:, j] = v
    return P


def _check_range(lo, hi):
    try:
        lo, hi = float(lo), float(hi)
    except (TypeError, ValueError):
        raise ValueError(f"range must be two numbers, got {lo!r} {hi!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"range must be finite, got {lo} {hi}")
    if not lo < hi:
        raise ValueError(f"range: LO must be less than HI, got {lo:g} {hi:g}")
    return lo, hi


def _check_points(points) -> np.ndarray:
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 4 or P.shape[0] == 0:
        raise ValueError(f"points must be a non-empty (n, 4) array of M1, got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("points must be finite")
    return np.ascontiguousarray(P)


def _counts(status) -> dict:
    return {s: int(np.count_nonzero(status == s)) for s in STATUSES}


# ------------------------------------------------------- gait <-> dictionary
def gait_to_dict(gait) -> dict:
    """What defines the reference: robot, options, solution (not the solver's stats)."""
    d = gait.to_dict()
    return dict(format=d["format"], version=d["version"], robot=d["robot"],
                options=d["options"], solution=d["solution"])


def gait_from_dict(d: dict):
    from biped_casadi import RobotParams, rabbit
    from gait_opt import Gait, GaitOptions
    sol = d["solution"]
    return Gait(rabbit(RobotParams.from_dict(d["robot"])), GaitOptions.from_dict(d["options"]),
                sol["alpha"], sol["x0"], sol["T"])


# ------------------------------------------------------------ worker side
_MAPS: dict = {}
_MAPS_LOCK = threading.Lock()


def _map_key(payload):
    return payload["gait_sha256"], digest_json(payload["map"])


def _poincare_for(payload) -> PoincareMap:
    """The PoincareMap for a payload, built once per process (or taken from the caller)."""
    key = _map_key(payload)
    with _MAPS_LOCK:
        pm = _MAPS.get(key)
        if pm is None:
            gait = gait_from_dict(payload["gait"])
            opts = SweepSettings(**payload["map"]).map_options()
            pm = _MAPS[key] = PoincareMap(gait.model, gait, **opts)
        return pm


def _init_worker(payload):
    _poincare_for(payload)


def evaluate_chunk(payload: dict, points: np.ndarray) -> dict:
    """Evaluate one chunk of M1 (runs in worker processes and on Dask workers):
    dict of status (str), max_abs, eigenvalues (|.| descending), A."""
    pm = _poincare_for(payload)
    P = np.asarray(points, dtype=float)
    if payload["map"]["method"] == "variational":
        status, A, ev, max_abs = pm.jacobian_batch(P)
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


# -------------------------------------------------------------- the sweep
def run_sweep(model, gait, points, out_dir=None, chunk_size: int | None = None,
              workers: int | None = None, scheduler=None, progress: bool = True,
              settings: SweepSettings | dict | None = None,
              executor: str = "thread") -> SweepResult:
    """max|lambda| and status for every M1 in ``points`` (n, 4).

    out_dir: folder for the results (written chunk by chunk, resumable); None keeps them
        in memory only.
    chunk_size: points per chunk (default 256; when resuming, the folder's own).
    workers: local workers (default: all cores); 1 runs chunk after chunk in this
        process (each chunk is still spread over the cores by CasADi's thread map).
    scheduler: a Dask scheduler address ('tcp://host:port') or a
        ``dask.distributed.Client``; the chunks then run on its workers.
    settings: :class:`SweepSettings` (or a dict of its fields).
    executor: 'thread' (default: workers are threads of this process sharing one
        map) or 'process' (spawned processes, each rebuilding the map: ~1 s each to
        start, worth it only for very large sweeps; see the module docstring).
    """
    t0 = time.perf_counter()
    settings = _settings(settings)
    P = _check_points(points)
    if gait.model.params != model.params:
        raise ValueError("gait: made for other robot parameters than the model")
    if executor not in ("process", "thread"):
        raise ValueError(f"executor must be 'process' or 'thread', got {executor!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer))
                                or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    workers = int(workers) if workers else _cpu_count()

    gdict = gait_to_dict(gait)
    payload = dict(gait=gdict, gait_sha256=digest_json(gdict), map=settings.to_dict())
    if chunk_size is None and out_dir is not None:
        chunk_size = _stored_chunk_size(out_dir)
    chunk_size = DEFAULT_CHUNK_SIZE if chunk_size is None else chunk_size
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)) or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    chunk_size = int(chunk_size)
    n = len(P)
    bounds = [(k, a, min(a + chunk_size, n)) for k, a in enumerate(range(0, n, chunk_size))]
    identity = dict(results_version=RESULTS_VERSION, code_sha256=code_digest(),
                    gait_sha256=payload["gait_sha256"],
                    robot=model.params.name, points_sha256=digest_points(P), n_points=n,
                    chunk_size=chunk_size, map=settings.to_dict())

    status = np.full(n, "", dtype="<U9")
    max_abs = np.full(n, np.nan)
    ev = np.full((n, 2), np.nan + 0j)
    A = np.full((n, 2, 2), np.nan)
    reused, computed, corrupt = [], [], {}

    store = SweepStore(out_dir, identity).open() if out_dir is not None else None
    try:
        if store is not None:
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
                    _fill((status, max_abs, ev, A), a, b, c)
                    reused.append(k)
            for k, paths in files.items():      # numbers outside this sweep's chunks
                corrupt[k] = "chunk number out of range"
                for path in paths:
                    store.discard(path)
            corrupt = {k: v for k, v in corrupt.items() if k not in reused}
        todo = [bd for bd in bounds if bd[0] not in set(reused)]
        if store is not None:
            store.log(dict(event="start", time=time.time(), pid=os.getpid(),
                           n_chunks=len(bounds), reused=len(reused),
                           corrupt={str(k): v for k, v in corrupt.items()},
                           to_compute=[k for k, _, _ in todo]))
        bar = _progress_bar(progress, total=n, initial=n - sum(b - a for _, a, b in todo))

        def record(k, a, b, c):
            if c.get("code_sha256") != identity["code_sha256"]:
                raise ValueError(
                    "a worker runs other analysis code than this process (code_sha256 "
                    f"{str(c.get('code_sha256'))[:12]} vs {identity['code_sha256'][:12]}); "
                    "install the same version of the toolkit on every Dask worker")
            _fill((status, max_abs, ev, A), a, b, c)
            if store is not None:
                store.write_chunk(k, a, P[a:b], c["status"], c["max_abs"], c["A"],
                                  c["eigenvalues"])
            computed.append(k)
            bar.update(b - a)

        try:
            if todo:
                if scheduler is not None:
                    _run_dask(scheduler, payload, P, todo, record)
                elif workers == 1 or len(todo) == 1:
                    _register_caller_map(payload, model, gait, settings)
                    for k, a, b in todo:
                        record(k, a, b, evaluate_chunk(payload, P[a:b]))
                elif executor == "thread":
                    _register_caller_map(payload, model, gait, settings)
                    _run_threads(payload, P, todo, record, workers)
                else:
                    _run_processes(payload, P, todo, record, workers)
        finally:
            bar.close()
            if store is not None:
                done = len(reused) + len(computed) == len(bounds)
                store.log(dict(event="done" if done else "stopped", time=time.time(),
                               pid=os.getpid(), computed=sorted(computed)))
    finally:
        if store is not None:
            store.close()

    return SweepResult(P, status, max_abs, ev, A, _counts(status), time.perf_counter() - t0,
                       chunk_size, identity, Path(out_dir) if out_dir is not None else None,
                       computed_chunks=sorted(computed), reused_chunks=sorted(reused),
                       corrupt_chunks=corrupt,
                       n_computed=sum(b - a for k, a, b in bounds if k in set(computed)))


def load_sweep(out_dir) -> SweepResult:
    """Read a finished sweep folder back (without the gait): raises ValueError when it is
    incomplete or damaged."""
    import json
    from .storage import META
    root = Path(out_dir)
    try:
        identity = json.loads((root / META).read_text())["settings"]
    except (OSError, ValueError, KeyError) as e:
        raise ValueError(f"out_dir: {root} is not a readable sweep folder ({e})") from None
    n, cs = identity["n_points"], identity["chunk_size"]
    store = SweepStore(root, identity)
    files = store.chunk_files()
    cols = []
    import pyarrow.parquet as pq
    for k, a in enumerate(range(0, n, cs)):
        for path in files.get(k, []):
            try:
                t = pq.read_table(path, columns=[f"M1_{j + 1}" for j in range(4)])
                pts = np.stack([t.column(j).to_numpy() for j in range(4)], axis=1)
                cols.append((pts, store.read_chunk(path, k, a, pts)))
                break
            except Exception:       # noqa: BLE001 - damaged: try another copy, or fail
                continue
        else:
            raise ValueError(f"out_dir: {root} is incomplete (chunk {k} missing or "
                             f"damaged); rerun the sweep to finish it")
    P = np.concatenate([p for p, _ in cols])
    st = np.concatenate([c["status"] for _, c in cols]).astype("<U9")
    return SweepResult(P, st, np.concatenate([c["max_abs"] for _, c in cols]),
                       np.concatenate([c["eigenvalues"] for _, c in cols]),
                       np.concatenate([c["A"] for _, c in cols]), _counts(st), 0.0, cs,
                       identity, root, reused_chunks=list(range(len(cols))))


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
    import json
    from .storage import META
    try:
        return int(json.loads((Path(out_dir) / META).read_text())["settings"]["chunk_size"])
    except (OSError, ValueError, KeyError, TypeError):
        return None        # no (readable) folder yet: SweepStore.open says the rest


def _cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def _fill(arrays, a, b, c):
    status, max_abs, ev, A = arrays
    status[a:b] = c["status"]
    max_abs[a:b] = c["max_abs"]
    ev[a:b] = c["eigenvalues"]
    A[a:b] = c["A"]


def _progress_bar(progress, total, initial):
    from tqdm.auto import tqdm
    enabled = bool(progress) and sys.stderr.isatty()
    return tqdm(total=total, initial=initial, unit="M1", desc="sweep", disable=not enabled,
                file=sys.stderr, dynamic_ncols=True)


def _register_caller_map(payload, model, gait, settings):
    """In-process runs use the caller's gait object directly (no rebuild from the dict)."""
    key = _map_key(payload)
    with _MAPS_LOCK:
        if key not in _MAPS:
            from .poincare import poincare_map
            _MAPS[key] = poincare_map(model, gait, **settings.map_options())
    pm = _MAPS[key]
    if settings.method == "variational":
        pm.variational      # build the tables before any thread uses them


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
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise ValueError("scheduler: dask.distributed is not installed "
                         "(pip install 'dask[distributed]')") from None
    own = isinstance(scheduler, str)
    if own:
        try:
            client = Client(scheduler, timeout=DASK_CONNECT_TIMEOUT)
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
        [pf] = client.scatter([payload], broadcast=True)
        futs = {}
        for k, a, b in todo:
            f = client.submit(evaluate_chunk, pf, P[a:b], pure=False,
                              key=f"sweep-{payload['gait_sha256'][:8]}-{k}-{os.getpid()}-"
                                  f"{time.monotonic_ns()}")
            futs[f] = (k, a, b)
        try:
            for f in as_completed(list(futs)):
                record(*futs[f], f.result())
        except BaseException:
            client.cancel(list(futs))
            raise
    finally:
        if own:
            client.close()


# ----------------------------------------------------- Fig. 2: 1-D sweeps
@dataclass
class OneDSweeps:
    """The four 1-D sweeps of Fig. 2: ``results[j]`` over ``values[j]`` for component j
    (others zero), ``singular_values[j]`` = D11/D12(j) at q^d(T) (eq. 24)."""
    values: list
    results: list
    singular_values: np.ndarray
    sweep: SweepResult


def one_d_sweeps(model, gait, values, out_dir=None, **kw) -> OneDSweeps:
    """Fig. 2: max|lambda| against each component M1(j) with the other three zero.
    ``values``: one array for all four components or a list of four arrays.  Runs as
    one sweep (one pool, one folder); ``kw`` go to :func:`run_sweep`."""
    if isinstance(values, (list, tuple)) and len(values) == 4 and np.ndim(values[0]) == 1:
        vals = [np.asarray(v, dtype=float).ravel() for v in values]
    else:
        vals = [np.asarray(values, dtype=float).ravel()] * 4
    P = np.concatenate([line_points(j, v) for j, v in enumerate(vals)])
    r = run_sweep(model, gait, P, out_dir=out_dir, **kw)
    ends = np.cumsum([0] + [len(v) for v in vals])
    parts = [r.subset(np.arange(ends[j], ends[j + 1])) for j in range(4)]
    return OneDSweeps(vals, parts, singular_m1_values(model, gait), r)


def plot_fig2(results, singular_values, path) -> list[Path]:
    """Fig. 2: four panels of max|lambda| against M1(j), log scale, stable points red,
    the singular values of eq. (24) as vertical dashed lines (where inside the range).
    ``results``: :class:`OneDSweeps` or four :class:`SweepResult`.  Writes ``path`` with
    suffix .png and .pdf; returns both paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    if isinstance(results, OneDSweeps):
        results = results.results
    if len(results) != 4:
        raise ValueError(f"results must hold the four 1-D sweeps, got {len(results)}")
    sv = np.asarray(singular_values, dtype=float).ravel()
    base = Path(path)
    base = base.with_suffix("") if base.suffix.lower() in (".png", ".pdf") else base
    base.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 2, figsize=(9, 6.5), constrained_layout=True)
    for j, (ax, r) in enumerate(zip(axes.ravel(), results)):
        x = r.points[:, j]
        fin = np.isfinite(r.max_abs)
        st = r.status == "stable"
        ax.semilogy(x[fin & ~st], r.max_abs[fin & ~st], ".", ms=3, color="0.25",
                    label="unstable")
        ax.semilogy(x[st], r.max_abs[st], ".", ms=5, color="red",
                    label="stable, max|λ| < 1")
        sing = r.status == "singular"
        if sing.any():
            ax.plot(x[sing], np.full(sing.sum(), 1.0), "|", color="tab:blue", ms=6,
                    transform=ax.get_xaxis_transform(), clip_on=False,
                    label="singular controller")
        ax.axhline(1.0, color="0.5", lw=0.8, ls=":")
        if x.min() <= sv[j] <= x.max():
            ax.axvline(sv[j], color="tab:blue", lw=1, ls="--",
                       label=f"eq. (24): {sv[j]:.4g}")
        ax.set_xlabel(f"$M_1({j + 1})$")
        ax.set_ylabel(r"max $|\lambda_{1,2}|$")
        ax.legend(fontsize=7, loc="best")
        ax.grid(True, which="major", alpha=0.3)
    fig.suptitle("max|λ| of $A^z$ against one component of $M_1$, the others zero")
    out = [base.with_suffix(".png"), base.with_suffix(".pdf")]
    fig.savefig(out[0], dpi=150)
    fig.savefig(out[1])
    plt.close(fig)
    return out
