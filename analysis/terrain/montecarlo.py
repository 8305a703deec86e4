"""Mean first-passage time on stochastic terrain by Monte Carlo (Byl & Tedrake, IJRR 2009).

N runs walk up to K steps each from the reference's start, on ground heights i.i.d.
N(0, sigma^2) (run i's from its own stream: :func:`biped_casadi.simulation.random_heights`),
every step checked for validity; a run ends at its first invalid state (a failure) or
after K steps (censored).  From the steps each run walked:

- the survival curve S(k), the fraction of runs that walked at least k steps;
- the per-step failure probability p, by maximum likelihood for a constant hazard with
  censoring: p = F / E, F failures and E steps attempted (the failing steps included),
  with an exact 95 % interval from the Poisson law of F (chi-square quantiles); it stays
  right when few runs fail, and bounds p when none does;
- the mean first-passage time MFPT = (1 - p) / p, the mean number of steps walked
  before the first failure of the metastable walk (the same as total steps walked / F),
  with the interval of p mapped through; infinite with a finite lower bound when no
  run fails;
- the RMS deviation of the step time from the periodic walk's, over the valid steps
  from ``transient`` on (at small sigma the gait sensitivity norm predicts it,
  :mod:`analysis.terrain.gsn`).

Where runs walk.  What walks is a :class:`WalkerSpec` (the controller, its design or
gains, the plant): a time-varying controller on a perfect model runs on its batched
hybrid zero dynamics (exact for every output gain), virtual constraints on theirs
(the walker starts every step on its corrected surface, exact for the controller), and
anything with a model error or torque saturation in the full-order simulator, run by
run.  The runs are cut into chunks evaluated by a Dask cluster (a ``LocalCluster`` of
this machine's cores by default, or a scheduler's address) or in this process
(``scheduler='inline'``); each chunk is written to a Parquet file as it arrives
(:class:`MonteCarloStore`, the sweep store's layout and checks), so a rerun after an
interruption computes only the missing chunks and ends with the same numbers.
"""
from __future__ import annotations

import contextlib
import hashlib
import importlib
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from biped_casadi import (Gains, SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, robot)
from biped_casadi.caching import cached, digest
from biped_casadi.model.description import description_from_dict
from biped_casadi.results import Result, internal
from biped_casadi.simulation import (Terrain, WalkBatch, random_heights, simulator,
                                     virtual_constraint_walker, zero_dynamics_walker)
from biped_casadi.simulation.outcome import STATUSES
from gait_opt import Gait

from ..cluster import DASK_CONNECT_TIMEOUT, dask_client
from ..sweeps.storage import SweepStore

__all__ = ["WalkerSpec", "MonteCarloSettings", "MonteCarloResult", "MonteCarloStore",
           "monte_carlo", "mfpt_estimate", "MFPTEstimate", "evaluate_chunk", "MAX_RUNS",
           "MAX_STEPS"]

#: the largest number of runs and of steps per run a Monte Carlo accepts
MAX_RUNS = 1_000_000
MAX_STEPS = 100_000

#: the modules whose code decides the numbers of a Monte Carlo (part of its settings)
NUMERIC_MODULES = ("biped_casadi.model.biped", "biped_casadi.control.output_law",
                   "biped_casadi.control.zero_dynamics", "biped_casadi.control.time_varying",
                   "biped_casadi.control.virtual_constraints", "biped_casadi.simulation.kernel",
                   "biped_casadi.simulation.validity", "biped_casadi.simulation.outcome",
                   "biped_casadi.simulation.full_order", "biped_casadi.simulation.tv_walker",
                   "biped_casadi.simulation.vc_walker", "biped_casadi.simulation.terrain",
                   "analysis.terrain.montecarlo")
_CODE = None


def code_digest() -> str:
    """SHA-256 of the source of :data:`NUMERIC_MODULES`."""
    global _CODE
    if _CODE is None:
        h = hashlib.sha256()
        for name in NUMERIC_MODULES:
            h.update(name.encode())
            h.update(Path(importlib.import_module(name).__file__).read_bytes())
        _CODE = h.hexdigest()
    return _CODE


# ------------------------------------------------------------------ what walks
@dataclass(frozen=True)
class WalkerSpec:
    """What walks: the controller, its design and gains, and the plant (picklable).

    Parameters
    ----------
    controller : {'tv', 'vc'}
        Time-varying outputs or virtual constraints.
    M1 : tuple of float
        The time-varying outputs (ignored for 'vc').
    rejoin : float
        Rejoin time of v_c, fraction of T ('tv').
    gains : tuple of float
        (Kp, Kd, eps) of eq. (13); they matter only with a model error or saturation.
    plant : dict, optional
        The plant's robot description (``RobotDescription.to_dict()``) when it differs
        from the controller's model.
    saturate : bool
        Clip torques at the limit and keep walking (full-order simulator).
    """

    controller: str = "tv"
    M1: tuple = ()
    rejoin: float = 0.5
    gains: tuple = (1.0, 2.0, 0.02)
    plant: dict | None = None
    saturate: bool = False

    def __post_init__(self):
        if self.controller not in ("tv", "vc"):
            raise ValueError(f"controller must be 'tv' or 'vc', got {self.controller!r}")
        object.__setattr__(self, "M1", tuple(float(v) for v in self.M1))
        object.__setattr__(self, "gains", tuple(float(v) for v in self.gains))
        Gains(*self.gains)                             # checked
        if self.controller == "tv" and not self.M1:
            raise ValueError("M1: the time-varying controller needs its outputs")

    @property
    def engine(self) -> str:
        """'zero_dynamics', 'virtual_constraints' (the batched walkers) or 'full_order'."""
        if self.plant is not None or self.saturate:
            return "full_order"
        return "zero_dynamics" if self.controller == "tv" else "virtual_constraints"

    def controller_for(self, gait):
        """The controller on a gait.

        Parameters
        ----------
        gait : Gait
            The reference.

        Returns
        -------
        TimeVaryingController or VirtualConstraintController
        """
        g = Gains(*self.gains)
        if self.controller == "tv":
            return TimeVaryingController(gait.model, gait, np.array(self.M1), g, self.rejoin)
        return VirtualConstraintController(gait.model, gait, gains=g)

    def plant_model(self):
        """The plant's model (None: the controller's).

        Returns
        -------
        BipedModel or None
        """
        return None if self.plant is None else robot(description_from_dict(
            self.plant, where="plant"))

    def to_dict(self) -> dict:
        """The fields in JSON types.

        Returns
        -------
        dict
        """
        d = asdict(self)
        d["M1"], d["gains"] = list(self.M1), list(self.gains)
        d["engine"] = self.engine
        return d


@dataclass(frozen=True)
class MonteCarloSettings:
    """How the Monte Carlo runs (module docstring); all have defaults.

    Parameters
    ----------
    sigma : float
        Standard deviation of the ground heights, m (>= 0).
    runs : int
        N runs.
    max_steps : int
        K steps at most per run.
    seed : int
        Seed of the terrain.
    chunk : int
        Runs per chunk (one task, one file).
    mu : float
        Friction coefficient.
    torque_limit : float, optional
        Bound on ``|u_i|``, N m (default the robot's).
    rk4_steps : int
        RK4 steps per T of the zero-dynamics walker.
    vc_nodes : int
        RK4 nodes per step of the virtual-constraint walker.
    full_rk4_steps : int
        RK4 steps per T of the full-order simulator, at least (raised where the output
        gains' eps needs a finer step, eps >= 2 h); 200 gives the verdicts of 2000 on every
        run compared (``benchmarks/bench_terrain.py``, README).
    transient : int
        Steps left out at the start of every run for the step-time RMS.
    profile : tuple of float
        A measured terrain instead of random heights (sigma then 0): run i walks the
        profile from its i-th height on, cyclically, m.
    """

    sigma: float = 0.005
    runs: int = 200
    max_steps: int = 50
    seed: int = 0
    chunk: int = 50
    mu: float = 0.6
    torque_limit: float | None = None
    rk4_steps: int = 128
    vc_nodes: int = 100
    full_rk4_steps: int = 200
    transient: int = 5
    profile: tuple = ()

    def __post_init__(self):
        s = self.sigma
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not math.isfinite(s) \
                or s < 0:
            raise ValueError(f"sigma must be a finite number >= 0 (m), got {s!r}")
        for name, hi in (("runs", MAX_RUNS), ("max_steps", MAX_STEPS), ("chunk", MAX_RUNS)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= hi:
                raise ValueError(f"{name} must be an integer between 1 and {hi}, got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        SimulationOptions(mu=self.mu, torque_limit=self.torque_limit,
                          rk4_steps=self.full_rk4_steps)          # checked there
        v = self.rk4_steps
        if isinstance(v, bool) or not isinstance(v, int) or v < 8 or v % 8:
            raise ValueError(f"rk4_steps must be a positive multiple of 8, got {v!r}")
        v = self.vc_nodes
        if isinstance(v, bool) or not isinstance(v, int) or v < 8:
            raise ValueError(f"vc_nodes must be an integer >= 8, got {v!r}")
        if isinstance(self.transient, bool) or not isinstance(self.transient, int) \
                or self.transient < 0:
            raise ValueError(f"transient must be a non-negative integer, got "
                             f"{self.transient!r}")
        object.__setattr__(self, "profile", Terrain(tuple(self.profile)).heights)
        if self.profile and self.sigma:
            raise ValueError("sigma and profile exclude each other (a profile is the terrain)")

    def heights(self, runs) -> np.ndarray:
        """The ground heights of runs (module docstring), (len(runs), max_steps), m.

        Parameters
        ----------
        runs : array_like of int
            Run indices.

        Returns
        -------
        numpy.ndarray
        """
        runs = np.atleast_1d(np.asarray(runs, np.int64))
        if self.profile:
            P = np.asarray(self.profile, float)
            return P[(runs[:, None] + np.arange(self.max_steps)[None, :]) % P.size]
        return random_heights(self.sigma, self.max_steps, self.seed, runs)

    def options(self, spec: WalkerSpec, T: float = None) -> SimulationOptions:
        """The simulation options of the runs.

        Parameters
        ----------
        spec : WalkerSpec
            What walks (its saturation and its gains).
        T : float, optional
            The reference's step duration, s: the RK4 steps per T are raised to keep
            eps >= 2 T / rk4_steps.

        Returns
        -------
        SimulationOptions
        """
        rk = self.full_rk4_steps
        if T is not None:
            need = 2.0 * T / spec.gains[2]
            rk = max(rk, 8 * int(math.ceil(need / 8 - 1e-9)))
        return SimulationOptions(steps=self.max_steps, mu=self.mu,
                                 torque_limit=self.torque_limit, saturate=spec.saturate,
                                 rk4_steps=rk, jit=True)

    def to_dict(self) -> dict:
        """The fields by name.

        Returns
        -------
        dict
        """
        return asdict(self)


# -------------------------------------------------------------------- workers
@dataclass(frozen=True)
class _Payload:
    """What a worker needs: the gait's dictionary and digest, what walks, the settings."""
    gait: dict
    gait_sha256: str
    spec: WalkerSpec
    settings: MonteCarloSettings

    @property
    def cache_key(self):
        return (self.gait_sha256, digest(self.spec.to_dict()), digest(self.settings.to_dict()))


@cached(maxsize=4)
def _gait_for(gait_sha256: str, gait: dict) -> Gait:
    return Gait.from_dict(gait)


@cached(maxsize=8)
def _engine(payload: _Payload):
    """The walker or simulator of a payload (built once per process)."""
    gait = _gait_for(payload.gait_sha256, payload.gait)
    spec, st = payload.spec, payload.settings
    opts = st.options(spec, gait.T)
    model = gait.model
    # the walkers' options hold only validity thresholds: those of the basins and of
    # robustness runs with the same thresholds, so a process shares one compiled walker
    wopts = SimulationOptions(mu=st.mu, torque_limit=st.torque_limit)
    if spec.engine == "zero_dynamics":
        return gait, zero_dynamics_walker(model, gait, wopts, st.rk4_steps, jit=True)
    if spec.engine == "virtual_constraints":
        return gait, virtual_constraint_walker(model, gait, wopts, st.vc_nodes, jit=True)
    return gait, simulator(spec.controller_for(gait), opts, spec.plant_model())


def evaluate_chunk(payload, start: int, stop: int) -> dict:
    """Walk runs ``start:stop`` (on a Dask worker, or in this process).

    Parameters
    ----------
    payload : _Payload
        The gait, what walks and the settings.
    start, stop : int
        Run indices.

    Returns
    -------
    dict
        ``status`` (n,), ``fail_step`` (n,), ``duration`` (n, K) s, ``peak_torque``,
        ``saturated_time`` (n,), ``scenario_steps``, ``elapsed`` (s, walking),
        ``build`` (s, building the walker or simulator when this process had not yet)
        and ``code_sha256``.
    """
    t0 = time.perf_counter()
    gait, eng = _engine(payload)                 # built (and compiled) once per process
    built = time.perf_counter()
    spec, st = payload.spec, payload.settings
    runs = np.arange(start, stop)
    n, K = runs.size, st.max_steps
    H = st.heights(runs)
    q0, dq0 = np.tile(gait.q(0.0), (n, 1)), np.tile(gait.dq(0.0), (n, 1))
    if spec.engine == "zero_dynamics":
        b = eng.walk(q0, dq0, np.array(spec.M1), spec.rejoin, steps=K, terrain=H)
    elif spec.engine == "virtual_constraints":
        b = eng.walk_from_states(q0, dq0, steps=K, terrain=H)
    else:
        b = WalkBatch.concat([eng.run(q0[i], dq0[i], K, H[i]) for i in range(n)])
    return dict(status=np.asarray(b.status).astype(str), fail_step=np.asarray(b.fail_step),
                duration=np.asarray(b.duration, float), peak_torque=np.asarray(b.peak_torque),
                saturated_time=np.asarray(b.saturated_time, float),
                scenario_steps=int(b.scenario_steps), elapsed=time.perf_counter() - built,
                build=built - t0, code_sha256=code_digest())


# -------------------------------------------------------------------- storage
def _content_digest(index, code, fail_step, duration, peak, sat) -> str:
    h = hashlib.sha256()
    for a in (np.asarray(index, "<i8"), np.asarray(code, "u1"), np.asarray(fail_step, "<i8"),
              np.asarray(duration, "<f8"), np.asarray(peak, "<f8"), np.asarray(sat, "<f8")):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


class MonteCarloStore(SweepStore):
    """A Monte Carlo's output folder: ``montecarlo.json`` (the settings and their digest),
    ``chunks/part-NNNNNN.<sha>.parquet`` (runs ``[k chunk, ...)``: index, status,
    fail_step, peak_torque, saturated_time and the step times duration_1..K), a run log
    and a lock; written and checked like a sweep's (:class:`~analysis.sweeps.SweepStore`).

    Parameters
    ----------
    root : str or Path
        The folder.
    settings : dict
        Everything the numbers depend on (a folder with other settings is refused).
    """

    FORMAT, FORMAT_VERSION, META, KV_KEY, KIND = ("biped-casadi-montecarlo", 1,
                                                  "montecarlo.json", b"biped_montecarlo",
                                                  "Monte Carlo")

    def write_runs(self, k: int, start: int, out: dict):
        """Write chunk ``k`` (runs from ``start``) of an :func:`evaluate_chunk` result.

        Parameters
        ----------
        k : int
            The chunk.
        start : int
            Its first run.
        out : dict
            From :func:`evaluate_chunk`.

        Returns
        -------
        Path
        """
        n = len(out["status"])
        index = np.arange(start, start + n, dtype=np.int64)
        code = np.array([STATUSES.index(s) for s in out["status"]], dtype=np.uint8)
        dur = np.asarray(out["duration"], float)
        cols = dict(index=index, status=np.asarray(out["status"]).astype(str),
                    fail_step=np.asarray(out["fail_step"], np.int64),
                    peak_torque=np.asarray(out["peak_torque"], float),
                    saturated_time=np.asarray(out["saturated_time"], float))
        cols.update({f"duration_{j + 1}": dur[:, j] for j in range(dur.shape[1])})
        return self.write_table(k, start, start + n, cols, _content_digest(
            index, code, cols["fail_step"], dur, cols["peak_torque"], cols["saturated_time"]))

    def read_runs(self, path, k: int, start: int, n: int, steps: int) -> dict:
        """Read and check chunk ``k`` (``n`` runs from ``start``, ``steps`` step times).

        Parameters
        ----------
        path : Path
            The chunk's file.
        k, start, n, steps : int
            What it must hold.

        Returns
        -------
        dict
            As :func:`evaluate_chunk` (without timings).

        Raises
        ------
        ValueError
            Saying what is wrong with the file.
        """
        table, info = self.read_table(path, k, start, n)
        try:
            col = {name: table.column(name).to_numpy(zero_copy_only=False)
                   for name in table.column_names}
            index = col["index"].astype(np.int64)
            status = np.array(col["status"], dtype=object).astype(str)
            code = np.array([STATUSES.index(s) for s in status], dtype=np.uint8)
            fail = col["fail_step"].astype(np.int64)
            peak = col["peak_torque"].astype(float)
            sat = col["saturated_time"].astype(float)
            dur = np.stack([col[f"duration_{j + 1}"] for j in range(steps)], axis=1).astype(float)
        except (KeyError, ValueError) as e:
            raise ValueError(f"missing or bad columns ({e})") from None
        if not np.array_equal(index, np.arange(start, start + n)):
            raise ValueError("run indices are not the expected ones")
        if _content_digest(index, code, fail, dur, peak, sat) != info.get("content_sha256"):
            raise ValueError("content checksum mismatch")
        return dict(status=status, fail_step=fail, duration=dur, peak_torque=peak,
                    saturated_time=sat)


# ------------------------------------------------------------------ estimates
@dataclass
class MFPTEstimate(Result):
    """The per-step failure probability and the MFPT of runs (module docstring).

    Parameters
    ----------
    failures : int
        F, runs that failed.
    censored : int
        Runs that walked every step.
    steps_walked : int
        Valid steps walked, summed over the runs.
    steps_attempted : int
        E: steps walked plus the failing steps.
    failure_probability : float
        p = F / E.
    failure_probability_ci : list of float
        Its exact 95 % interval.
    mfpt : float
        (1 - p) / p, steps (inf when no run failed).
    mfpt_ci : list of float
        Its 95 % interval (upper inf when no run failed).
    mean_steps_walked : float
        The mean of the steps the runs walked (below the MFPT when runs are censored).
    survival : list of float
        S(k), k = 0..K: the fraction of runs that walked at least k steps.
    status : str
        'done'.
    message : str
        In words.
    """

    failures: int
    censored: int
    steps_walked: int
    steps_attempted: int
    failure_probability: float
    failure_probability_ci: list
    mfpt: float
    mfpt_ci: list
    mean_steps_walked: float
    survival: list
    status: str = "done"
    message: str = ""

    SUCCESS = ("done",)


def mfpt_estimate(walked, failed, max_steps: int, confidence: float = 0.95) -> MFPTEstimate:
    """The MFPT and the per-step failure probability of runs, with censoring.

    Parameters
    ----------
    walked : array_like of int
        (n,) valid steps each run walked.
    failed : array_like of bool
        (n,) whether it ended with a failure (else it walked ``max_steps``: censored).
    max_steps : int
        K.
    confidence : float
        Of the intervals.

    Returns
    -------
    MFPTEstimate
    """
    from scipy.stats import chi2
    walked = np.asarray(walked, np.int64)
    failed = np.asarray(failed, bool)
    F = int(failed.sum())
    W = int(walked.sum())
    E = W + F
    a = 1 - confidence
    p = F / E if E else math.nan
    p_lo = chi2.ppf(a / 2, 2 * F) / (2 * E) if F else 0.0
    p_hi = chi2.ppf(1 - a / 2, 2 * F + 2) / (2 * E) if E else 1.0
    p_hi = min(p_hi, 1.0)

    def mf(x):
        return math.inf if x <= 0 else (1 - x) / x

    mfpt = mf(p) if F else math.inf
    surv = [float(np.mean(walked >= k)) for k in range(max_steps + 1)]
    msg = (f"{F} of {walked.size} runs failed; per-step failure probability {p:.3g} "
           f"[{p_lo:.3g}, {p_hi:.3g}], MFPT {mfpt:.4g} steps [{mf(p_hi):.4g}, {mf(p_lo):.4g}]"
           if F else f"no run of {walked.size} failed in {max_steps} steps: per-step failure "
                     f"probability below {p_hi:.3g}, MFPT above {mf(p_hi):.4g} steps "
                     f"({100 * confidence:g} %)")
    return MFPTEstimate(failures=F, censored=int((~failed).sum()), steps_walked=W,
                        steps_attempted=E, failure_probability=p,
                        failure_probability_ci=[p_lo, p_hi], mfpt=mfpt,
                        mfpt_ci=[mf(p_hi), mf(p_lo)],
                        mean_steps_walked=float(walked.mean()) if walked.size else math.nan,
                        survival=surv, message=msg)


@dataclass
class MonteCarloResult(Result):
    """A Monte Carlo on stochastic terrain (module docstring).

    ``success`` means every chunk was walked; ``status`` 'done'.

    Parameters
    ----------
    spec : dict
        What walked (:meth:`WalkerSpec.to_dict`).
    settings : dict
        :class:`MonteCarloSettings` fields.
    estimate : MFPTEstimate
        MFPT, failure probability, survival.
    status_counts : dict
        How the runs ended.
    step_time : float
        The periodic walk's step time the deviations are measured from, s.
    step_time_rms : float
        RMS of (step time - ``step_time``) over the valid steps from ``transient`` on, s.
    step_time_samples : int
        How many steps that RMS is over.
    scenario_steps : int
        Steps walked (the failing ones included), over all runs.
    elapsed : float
        Wall time, s.
    compute_time : float
        Time the chunks took walking where they were walked (builds excluded), summed
        over the processes, s.
    steps_computed : int
        Steps walked by the chunks this call computed.
    chunks_computed, chunks_reused : int
        Chunks walked by this call, and read back from the output folder.
    folder : str
        The output folder ('' without one).
    status, message : str
        'done'; in words.
    walked, failed, duration : numpy.ndarray
        Per run: steps walked, failed or not, step times (left out of ``to_dict()``).
    """

    spec: dict
    settings: dict
    estimate: MFPTEstimate
    status_counts: dict
    step_time: float
    step_time_rms: float
    step_time_samples: int
    scenario_steps: int
    elapsed: float
    compute_time: float
    steps_computed: int
    chunks_computed: int
    chunks_reused: int
    folder: str = ""
    status: str = "done"
    message: str = ""
    walked: np.ndarray = internal(default=None)
    failed: np.ndarray = internal(default=None)
    duration: np.ndarray = internal(default=None)

    SUCCESS = ("done",)

    @property
    def mfpt(self) -> float:
        """The MFPT, steps."""
        return self.estimate.mfpt

    @property
    def steps_per_second(self) -> float:
        """Steps walked per second of wall time (start-up, builds and storage included)."""
        return self.scenario_steps / self.elapsed if self.elapsed > 0 else math.nan

    @property
    def steps_per_process_second(self) -> float:
        """Steps walked per second of one process's walking (builds excluded)."""
        return self.steps_computed / self.compute_time if self.compute_time > 0 else math.nan


# ------------------------------------------------------------------- dispatch
def _local_cluster(workers: int | None):
    from dask.distributed import LocalCluster
    n = workers or max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                       else (os.cpu_count() or 1))
    return LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                        dashboard_address=":0", env={"BIPED_THREADS": "1"})


@contextlib.contextmanager
def _client(scheduler, workers):
    """A Dask client: the given one, a scheduler address, or a LocalCluster's."""
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


def _progress_bar(progress, total, initial):
    from tqdm.auto import tqdm
    return tqdm(total=total, initial=initial, unit="run", desc="monte carlo",
                disable=not (progress and sys.stderr.isatty()), file=sys.stderr,
                dynamic_ncols=True)


def monte_carlo(gait, spec: WalkerSpec, settings: MonteCarloSettings | None = None,
                out_dir=None, scheduler=None, workers: int | None = None,
                progress: bool = False) -> MonteCarloResult:
    """The Monte Carlo of ``spec`` walking on ``gait`` (module docstring).

    Parameters
    ----------
    gait : Gait
        The reference (and, through it, the controller's robot).
    spec : WalkerSpec
        What walks.
    settings : MonteCarloSettings, optional
        Default: all defaults.
    out_dir : str or Path, optional
        Write the chunks there as they arrive and resume from what is there (a folder
        made with other settings is refused); default: nothing is written.
    scheduler : None, 'local', 'inline', str or dask.distributed.Client
        None or 'local': a Dask LocalCluster of ``workers`` processes (default the
        cores); 'inline': this process, no Dask; an address ('tcp://host:port') or a
        client: that cluster.
    workers : int, optional
        Processes of the LocalCluster.
    progress : bool
        A progress bar on a terminal.

    Returns
    -------
    MonteCarloResult
    """
    t0 = time.perf_counter()
    st = settings or MonteCarloSettings()
    if not isinstance(spec, WalkerSpec):
        raise ValueError("spec must be a WalkerSpec")
    if spec.controller == "tv" and len(spec.M1) != gait.model.nu:
        raise ValueError(f"M1 must have {gait.model.nu} components, got {len(spec.M1)}")
    gdef = gait.definition()
    payload = _Payload(gdef, gait.cache_key, spec, st)
    N, C, K = st.runs, st.chunk, st.max_steps
    todo = [(k, a, min(a + C, N)) for k, a in enumerate(range(0, N, C))]
    results: dict = {}
    store = None
    if out_dir is not None:
        store = MonteCarloStore(out_dir, dict(gait_sha256=gait.cache_key, spec=spec.to_dict(),
                                              settings=st.to_dict(), code_sha256=code_digest()))
    reused = 0
    stack = contextlib.ExitStack()
    client = None
    if scheduler not in (None, "local", "inline"):
        client = stack.enter_context(_client(scheduler, workers))   # before anything is written
    try:
        if store is not None:
            store.open()
            files = store.chunk_files()
            for k, a, b in todo:
                for path in files.get(k, []):
                    try:
                        results[k] = store.read_runs(path, k, a, b - a, K)
                        break
                    except (OSError, ValueError) as e:
                        store.log(dict(chunk=k, discarded=path.name, why=str(e)))
                        store.discard(path)
            reused = len(results)
            todo = [t for t in todo if t[0] not in results]
        bar = _progress_bar(progress, N, sum(b - a for k, a, b in
                                            [(k, k * C, min(k * C + C, N)) for k in results]))
        computed, compute_time, steps_done = 0, 0.0, 0

        def record(k, a, b, out):
            nonlocal computed, compute_time, steps_done
            if out["code_sha256"] != code_digest():
                raise ValueError("scheduler: a worker runs other code than this process "
                                 "(install the same version of the toolkit on every worker)")
            if store is not None:
                store.write_runs(k, a, out)
            results[k] = out
            computed += 1
            compute_time += out["elapsed"]
            steps_done += out["scenario_steps"]
            bar.update(b - a)

        try:
            if todo and scheduler == "inline":
                for k, a, b in todo:
                    record(k, a, b, evaluate_chunk(payload, a, b))
            elif todo:
                if client is None:
                    client = stack.enter_context(_client(scheduler, workers))
                from dask.distributed import as_completed
                [pf] = client.scatter([payload], broadcast=True)
                futs = {client.submit(evaluate_chunk, pf, a, b, pure=False,
                                      key=f"mc-{gait.cache_key[:8]}-{k}-{os.getpid()}-"
                                          f"{time.monotonic_ns()}"): (k, a, b)
                        for k, a, b in todo}
                try:
                    for f in as_completed(list(futs)):
                        record(*futs[f], f.result())
                except BaseException:
                    client.cancel(list(futs))
                    raise
        finally:
            bar.close()
        if store is not None:
            store.log(dict(time=time.strftime("%Y-%m-%dT%H:%M:%S"), reused=reused,
                           computed=computed))
    finally:
        if store is not None:
            store.close()
        stack.close()
    parts = [results[k] for k in sorted(results)]
    status = np.concatenate([p["status"] for p in parts])
    fail_step = np.concatenate([p["fail_step"] for p in parts])
    duration = np.concatenate([p["duration"] for p in parts])
    failed = status != "ok"
    walked = np.where(failed, fail_step, K)
    est = mfpt_estimate(walked, failed, K)
    T = float(gait.T)
    dev = duration[:, st.transient:] - T
    dev = dev[np.isfinite(dev)]
    rms = float(np.sqrt(np.mean(dev**2))) if dev.size else math.nan
    counts = {s: int(c) for s, c in zip(*np.unique(status, return_counts=True))}
    scen = int(np.sum(np.minimum(walked + failed, K)))
    el = time.perf_counter() - t0
    return MonteCarloResult(
        spec=spec.to_dict(), settings=st.to_dict(), estimate=est, status_counts=counts,
        step_time=T, step_time_rms=rms, step_time_samples=int(dev.size), scenario_steps=scen,
        elapsed=el, compute_time=compute_time, steps_computed=steps_done,
        chunks_computed=computed, chunks_reused=reused,
        folder=str(out_dir) if out_dir is not None else "",
        message=(f"a profile of {len(st.profile)} heights" if st.profile else
                 f"sigma = {st.sigma:g} m") + f", {N} runs of up to {K} steps ({spec.engine}): "
                + est.message,
        walked=walked, failed=failed, duration=duration)
