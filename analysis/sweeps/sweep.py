"""Sweeps of the output matrix M1 (paper §V-A, Fig. 2): max|lambda| of A^z and the status
of SPEC §4 for many M1, in parallel, stored as they are computed, resumable.

    from analysis.sweeps.sweep import grid_points, run_sweep
    r = run_sweep(model, gait, grid_points(9, -10, 10), out_dir="sweep9")
    r.counts          # {'stable': .., 'unstable': .., 'singular': .., 'no_impact': ..}
    r.point_status    # the status of SPEC §4 of every point

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

import hashlib
import importlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from biped_casadi import RobotParams, description_from_dict, require_same_robot, robot
from biped_casadi.caching import cached
from biped_casadi.control.output_law import check_M1_range
from biped_casadi.results import Result, internal
from gait_opt import Gait, GaitOptions

from ..cluster import DASK_CONNECT_TIMEOUT, dask_client
from ..stability.poincare import STATUSES, PoincareMap, poincare_map, singular_m1_values
from .storage import META, SweepStore, digest_json, digest_points

__all__ = ["run_sweep", "SweepResult", "SweepSettings", "grid_points", "line_points",
           "one_d_sweeps", "OneDSweeps", "load_sweep", "evaluate_chunk",
           "gait_to_dict", "gait_from_dict", "code_digest", "RESULTS_VERSION",
           "DEFAULT_CHUNK_SIZE"]

#: bump when a change in analysis/ alters the numbers computed for the same settings,
#: so that folders written before are refused instead of mixed
RESULTS_VERSION = 1
DEFAULT_CHUNK_SIZE = 256
#: how long to wait for a Dask scheduler to answer, and for a first worker to join
METHODS = ("variational", "ad")
#: the modules whose code decides the numbers; their SHA-256 is part of a sweep's
#: settings (a folder written by other code is refused) and is checked on every result
#: coming back from a worker (a Dask worker running other code is an error, not a mix)
NUMERIC_MODULES = ("analysis.stability.poincare", "analysis.stability.variational", "biped_casadi.control.output_law",
                   "biped_casadi.numerics", "biped_casadi.model", "gait_opt.gait",
                   "gait_opt.parametrisation")
_CODE_DIGEST = None


def code_digest() -> str:
    """A digest of the code that decides a sweep's numbers.

    Returns
    -------
    str
        SHA-256 (hex) of the source of :data:`NUMERIC_MODULES` and of
        :data:`RESULTS_VERSION`; part of a sweep folder's settings.
    """
    global _CODE_DIGEST
    if _CODE_DIGEST is None:
        h = hashlib.sha256(f"results_version={RESULTS_VERSION}".encode())
        for name in NUMERIC_MODULES:
            h.update(name.encode())
            h.update(Path(importlib.import_module(name).__file__).read_bytes())
        _CODE_DIGEST = h.hexdigest()
    return _CODE_DIGEST


@dataclass(frozen=True)
class SweepSettings:
    """How each M1 of a sweep is evaluated.

    Parameters
    ----------
    method : {'variational', 'ad'}
        'variational' (the batched variational equation, the sweep path) or 'ad' (full
        AD through the discrete map, ~1000x slower).
    n_pre, n_post, n_scan : int
        RK4 steps from the section to the impact and back, and of the impact scan
        (options of :class:`analysis.PoincareMap`).
    horizon : float
        The swing foot must strike before ``horizon`` T (> 1).
    """
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
        """The settings by name, as stored in a sweep folder.

        Returns
        -------
        dict
            ``method``, ``n_pre``, ``n_post``, ``n_scan``, ``horizon``.
        """
        return dict(method=self.method, n_pre=self.n_pre, n_post=self.n_post,
                    n_scan=self.n_scan, horizon=self.horizon)

    def map_options(self) -> dict:
        """The keyword arguments of :func:`analysis.poincare_map` these settings give.

        Returns
        -------
        dict
            ``n_pre``, ``n_post``, ``n_scan``, ``horizon``.
        """
        return dict(n_pre=self.n_pre, n_post=self.n_post, n_scan=self.n_scan,
                    horizon=self.horizon)


@dataclass
class SweepResult(Result):
    """Results of a sweep, row i for ``points[i]``.

    ``status`` is 'complete' (every point has its result; ``success``).  The per-point
    arrays are left out of ``to_dict()``.

    Parameters
    ----------
    counts : dict
        Number of points per status of SPEC §4.
    elapsed : float
        This run's wall time, s.
    chunk_size : int
        Points per chunk.
    settings : dict
        Everything that identifies the sweep (code and gait digests, robot, points'
        digest, map settings), as stored in its folder.
    out_dir : Path or None
        The results folder (None: in memory only).
    computed_chunks : list of int
        Chunks evaluated by this run.
    reused_chunks : list of int
        Chunks read back from ``out_dir``.
    corrupt_chunks : dict
        Chunk -> reason, for chunks found damaged and recomputed.
    n_computed : int
        Points evaluated by this run.
    status : str
        'complete'.
    message : str
        Empty for a complete sweep.
    points : numpy.ndarray
        (n, nu) the M1 of the sweep.
    point_status : numpy.ndarray
        (n,) strings of SPEC §4.
    max_abs : numpy.ndarray
        (n,) max ``|lambda|``, inf where singular or without impact.
    eigenvalues : numpy.ndarray
        (n, 2) complex, ``|.|`` descending, NaN where undefined.
    A : numpy.ndarray
        (n, 2, 2) the Jacobians A^z.
    """
    counts: dict
    elapsed: float
    chunk_size: int
    settings: dict = internal()
    out_dir: Path | None = None
    computed_chunks: list = field(default_factory=list)
    reused_chunks: list = field(default_factory=list)
    corrupt_chunks: dict = field(default_factory=dict)
    n_computed: int = 0
    status: str = "complete"
    message: str = ""
    points: np.ndarray = internal(default=None)
    point_status: np.ndarray = internal(default=None)
    max_abs: np.ndarray = internal(default=None)
    eigenvalues: np.ndarray = internal(default=None)
    A: np.ndarray = internal(default=None)

    SUCCESS = ("complete",)

    @property
    def n_points(self) -> int:
        """Number of M1 in the sweep."""
        return len(self.points)

    def best(self):
        """The M1 of the sweep with the smallest finite max ``|lambda|``.

        Returns
        -------
        tuple or None
            (M1 (nu,), max_abs), or None when no point has a finite value.
        """
        finite = np.isfinite(self.max_abs)
        if not finite.any():
            return None
        i = int(np.flatnonzero(finite)[np.argmin(self.max_abs[finite])])
        return self.points[i].copy(), float(self.max_abs[i])

    def to_dict(self) -> dict:
        """Counts, timing, storage and the best point (the JSON of ``biped sweep``).

        Returns
        -------
        dict
            The fields of :meth:`Result.to_dict` (without the per-point arrays), plus
            ``n_points``, ``best`` (``M1`` and ``max_abs``, or None),
            ``computed_points`` and ``reused_points``.
        """
        b = self.best()
        return dict(super().to_dict(), n_points=self.n_points,
                    best=None if b is None else dict(M1=b[0].tolist(), max_abs=b[1]),
                    computed_points=self.n_computed,
                    reused_points=self.n_points - self.n_computed)

    def subset(self, rows) -> "SweepResult":
        """Some rows as a sweep result of their own.

        Parameters
        ----------
        rows : array_like
            Row indices or a boolean mask over the points.

        Returns
        -------
        SweepResult
            With counts of those rows only.
        """
        rows = np.asarray(rows)
        st = self.point_status[rows]
        return _result(self.points[rows], st, self.max_abs[rows], self.eigenvalues[rows],
                       self.A[rows], elapsed=self.elapsed, chunk_size=self.chunk_size,
                       settings=self.settings, out_dir=self.out_dir)


def _result(P, st, max_abs, ev, A, **kw) -> SweepResult:
    return SweepResult(counts=_counts(st), points=P, point_status=st, max_abs=max_abs,
                       eigenvalues=ev, A=A, **kw)


# ------------------------------------------------------------------ points
def grid_points(n: int, lo: float, hi: float, dim: int = 4) -> np.ndarray:
    """The n^dim grid of M1, component 1 varying slowest.

    Parameters
    ----------
    n : int
        Points per component (at least 2: the grid spans LO to HI), each in
        ``linspace(lo, hi, n)``.
    lo, hi : float
        Range of every component.
    dim : int
        Components of M1: the robot's nu (4 for RABBIT, 2 for the three-link biped).

    Returns
    -------
    numpy.ndarray
        (n^dim, dim).  The paper's grid is ``grid_points(9, -10, 10)``.
    """
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise ValueError(f"dim (components of M1) must be a positive integer, got {dim!r}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n (grid points per component) must be an integer >= 2 (the grid "
                         f"spans LO to HI), got {n!r}")
    if float(n) ** dim > 50_000_000:
        raise ValueError(f"n = {n} gives {n ** dim} points; at most 50 million "
                         f"(n <= {max_grid_n(dim)})")
    lo, hi = _check_range(lo, hi)
    v = np.linspace(lo, hi, int(n))
    return np.stack(np.meshgrid(*([v] * int(dim)), indexing="ij"), axis=-1).reshape(-1, int(dim))


def max_grid_n(dim: int = 4) -> int:
    """The most points per component of a grid of at most 50 million M1 in ``dim``
    components (84 for RABBIT's 4)."""
    return int(50_000_000 ** (1 / dim) + 1e-9)


def line_points(j: int, values, nu: int = 4) -> np.ndarray:
    """M1 with one component set to each of ``values`` and the others zero.

    Parameters
    ----------
    j : int
        The component, 0-based (the paper's M1(j+1)).
    values : array_like
        Its values.
    nu : int
        Components of M1 (4 for RABBIT).

    Returns
    -------
    numpy.ndarray
        (len(values), nu).
    """
    if isinstance(j, bool) or not isinstance(j, (int, np.integer)) or not 0 <= j < nu:
        raise ValueError(f"j (component of M1, 0..{nu - 1}) must be one of "
                         f"{', '.join(map(str, range(nu)))}, got {j!r}")
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0 or not np.all(np.isfinite(v)):
        raise ValueError("values must be a non-empty list of finite numbers")
    P = np.zeros((v.size, nu))
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
    check_M1_range([lo, hi], "range")
    return lo, hi


def _check_points(points, m: int = 4) -> np.ndarray:
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != m or P.shape[0] == 0:
        raise ValueError(f"points must be a non-empty (n, {m}) array of M1, got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("points must be finite")
    check_M1_range(P, "points")
    return np.ascontiguousarray(P)


def _counts(status) -> dict:
    return {s: int(np.count_nonzero(status == s)) for s in STATUSES}


# ------------------------------------------------------- gait <-> dictionary
def gait_to_dict(gait) -> dict:
    """What defines a gait, as a plain dictionary (sent to sweep workers).

    Parameters
    ----------
    gait : Gait
        A gait of :mod:`gait_opt`.

    Returns
    -------
    dict
        ``format``, ``version``, ``robot``, ``options``, ``solution`` (not the solver's
        statistics).
    """
    d = gait.to_dict()
    return dict(format=d["format"], version=d["version"], robot=d["robot"],
                options=d["options"], solution=d["solution"])


def gait_from_dict(d: dict):
    """The gait a dictionary of :func:`gait_to_dict` describes.

    Parameters
    ----------
    d : dict
        From :func:`gait_to_dict` (or a gait file's content).

    Returns
    -------
    gait_opt.Gait
        Rebuilt on the model of the recorded robot.
    """
    sol = d["solution"]
    rec = d["robot"]
    desc = (RobotParams.from_dict(rec).to_description() if RobotParams.is_legacy_record(rec)
            else description_from_dict(rec))
    return Gait(robot(desc), GaitOptions.from_dict(d["options"]), sol["alpha"], sol["x0"],
                sol["T"])


# ------------------------------------------------------------ worker side
@dataclass(frozen=True)
class SweepPayload:
    """What a worker needs to evaluate chunks: the gait's dictionary, its digest and the
    map settings (picklable, sent once to every process or Dask worker)."""
    gait: dict
    gait_sha256: str
    map: dict

    @property
    def cache_key(self):
        return (self.gait_sha256, digest_json(self.map))


@cached(maxsize=4)
def _poincare_for(payload: SweepPayload) -> PoincareMap:
    """The PoincareMap of a payload: built once per process (memoised by the gait's
    digest and the options, the same key as the caller's own ``poincare_map``)."""
    gait = gait_from_dict(payload.gait)
    return poincare_map(gait.model, gait, **SweepSettings(**payload.map).map_options())


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
@dataclass
class _Arrays:
    """The sweep's result arrays, filled chunk by chunk."""
    status: np.ndarray
    max_abs: np.ndarray
    ev: np.ndarray
    A: np.ndarray

    @classmethod
    def empty(cls, n):
        return cls(np.full(n, "", dtype="<U9"), np.full(n, np.nan),
                   np.full((n, 2), np.nan + 0j), np.full((n, 2, 2), np.nan))

    def fill(self, a, b, c):
        self.status[a:b] = c["status"]
        self.max_abs[a:b] = c["max_abs"]
        self.ev[a:b] = c["eigenvalues"]
        self.A[a:b] = c["A"]


def _check_run_arguments(model, gait, executor, workers, chunk_size):
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


def _dispatch(todo, payload, P, record, scheduler, workers, executor):
    """Evaluate the chunks ``todo`` where the caller asked, calling ``record`` for each."""
    if scheduler is not None:
        _run_dask(scheduler, payload, P, todo, record)
        return
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


def run_sweep(model, gait, points, out_dir=None, chunk_size: int | None = None,
              workers: int | None = None, scheduler=None, progress: bool = True,
              settings: SweepSettings | dict | None = None,
              executor: str = "thread") -> SweepResult:
    """max|lambda| and status for every M1 in ``points``.

    Parameters
    ----------
    model : BipedModel
        The robot.
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
        Local workers (default: all cores); 1 runs chunk after chunk in this process
        (each chunk is still spread over the cores by CasADi's thread map).
    scheduler : str or dask.distributed.Client, optional
        A Dask scheduler address ('tcp://host:port') or client; the chunks then run on
        its workers.
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
    t0 = time.perf_counter()
    settings = _settings(settings)
    P = _check_points(points, model.nu)
    if chunk_size is None and out_dir is not None:
        chunk_size = _stored_chunk_size(out_dir)
    chunk_size = DEFAULT_CHUNK_SIZE if chunk_size is None else chunk_size
    _check_run_arguments(model, gait, executor, workers, chunk_size)
    workers = int(workers) if workers else _cpu_count()
    chunk_size = int(chunk_size)
    gdict = gait_to_dict(gait)
    payload = SweepPayload(gait=gdict, gait_sha256=digest_json(gdict), map=settings.to_dict())
    n = len(P)
    bounds = [(k, a, min(a + chunk_size, n)) for k, a in enumerate(range(0, n, chunk_size))]
    identity = dict(results_version=RESULTS_VERSION, code_sha256=code_digest(),
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
            if c.get("code_sha256") != identity["code_sha256"]:
                raise ValueError(
                    "a worker runs other analysis code than this process (code_sha256 "
                    f"{str(c.get('code_sha256'))[:12]} vs {identity['code_sha256'][:12]}); "
                    "install the same version of the toolkit on every Dask worker")
            arrays.fill(a, b, c)
            if store is not None:
                store.write_chunk(k, a, P[a:b], c["status"], c["max_abs"], c["A"],
                                  c["eigenvalues"])
            computed.append(k)
            bar.update(b - a)

        try:
            if todo:
                _dispatch(todo, payload, P, record, scheduler, workers, executor)
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
    st = np.concatenate([c["status"] for _, c in cols]).astype("<U9")
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


def _cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def _progress_bar(progress, total, initial):
    from tqdm.auto import tqdm
    enabled = bool(progress) and sys.stderr.isatty()
    return tqdm(total=total, initial=initial, unit="M1", desc="sweep", disable=not enabled,
                file=sys.stderr, dynamic_ncols=True)


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
    from dask.distributed import as_completed
    with dask_client(scheduler, DASK_CONNECT_TIMEOUT) as client:
        [pf] = client.scatter([payload], broadcast=True)
        futs = {}
        for k, a, b in todo:
            f = client.submit(evaluate_chunk, pf, P[a:b], pure=False,
                              key=f"sweep-{payload.gait_sha256[:8]}-{k}-{os.getpid()}-"
                                  f"{time.monotonic_ns()}")
            futs[f] = (k, a, b)
        try:
            for f in as_completed(list(futs)):
                record(*futs[f], f.result())
        except BaseException:
            client.cancel(list(futs))
            raise


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


def one_d_sweeps(model, gait, values, out_dir=None, **kw) -> OneDSweeps:
    """Fig. 2: max|lambda| against each component M1(j) with the others zero.

    Parameters
    ----------
    model : BipedModel
        The robot.
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
    nu = model.nu
    if isinstance(values, (list, tuple)) and len(values) == nu and np.ndim(values[0]) == 1:
        vals = [np.asarray(v, dtype=float).ravel() for v in values]
    else:
        vals = [np.asarray(values, dtype=float).ravel()] * nu
    P = np.concatenate([line_points(j, v, nu) for j, v in enumerate(vals)])
    r = run_sweep(model, gait, P, out_dir=out_dir, **kw)
    ends = np.cumsum([0] + [len(v) for v in vals])
    parts = [r.subset(np.arange(ends[j], ends[j + 1])) for j in range(nu)]
    return OneDSweeps(vals, parts, singular_m1_values(model, gait), r)
