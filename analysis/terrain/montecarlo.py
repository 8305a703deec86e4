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

import math
import time
from dataclasses import dataclass

import numpy as np

from biped_casadi import Design
from biped_casadi.caching import code_version
from biped_casadi.results import Result, internal


from ..reporting.progress import progress_bar
from ..tasks import Engine, TaskError
from .chunks import MonteCarloStore, evaluate_chunk, _Payload
from .estimates import MFPTEstimate, mfpt_estimate
from .spec import MonteCarloSettings, WalkerSpec

__all__ = ["MonteCarloResult", "monte_carlo"]


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
def monte_carlo(design, spec=None, settings: MonteCarloSettings | None = None,
                out_dir=None, scheduler=None, workers: int | None = None,
                progress: bool = False, *, plant=None, saturate: bool = False
                ) -> MonteCarloResult:
    """The Monte Carlo of a design walking on stochastic terrain (module docstring).

    ``monte_carlo(design, settings)`` with a :class:`~biped_casadi.Design` on its gait,
    or ``monte_carlo(gait, spec, settings)`` with a :class:`WalkerSpec`.

    Parameters
    ----------
    design : Design or Gait
        What walks and on which gait (a gait: ``spec`` says what walks).
    spec : WalkerSpec or MonteCarloSettings, optional
        What walks, with a gait as first argument; with a design, the settings may be
        given here.
    settings : MonteCarloSettings, optional
        Default: all defaults.
    out_dir : str or Path, optional
        Write the chunks there as they arrive and resume from what is there (a folder
        made with other settings is refused); default: nothing is written.
    scheduler : None, str or dask.distributed.Client
        Where the chunks run (:func:`analysis.tasks.resolve_scheduler`, the same meaning
        for every function): 'synchronous' (or 'inline'), this process; 'local' (the
        default outside a task), a Dask LocalCluster of ``workers`` processes (default
        the cores); an address ('tcp://host:port') or a client: that cluster.
    workers : int, optional
        Processes of the LocalCluster.
    progress : bool
        A progress bar on a terminal.
    plant : dict, optional
        With a design: the plant's robot description when it differs from the model.
    saturate : bool
        With a design: clip torques at the limit and keep walking.

    Returns
    -------
    MonteCarloResult
    """
    t0 = time.perf_counter()
    if isinstance(design, Design):
        if isinstance(spec, MonteCarloSettings) and settings is None:
            spec, settings = None, spec
        if spec is not None:
            raise ValueError("spec: with a design, give the settings (what walks is the "
                             "design)")
        gait, spec = Design.require(design).gait, WalkerSpec.of(design, plant=plant,
                                                                saturate=saturate)
    elif hasattr(design, "T") and hasattr(getattr(design, "model", None), "nq"):
        gait = design
    else:
        raise TypeError("design: a Design on its gait (or a gait with a WalkerSpec) is "
                        f"needed, got {type(design).__name__}")
    st = settings if settings is not None else MonteCarloSettings()
    if not isinstance(st, MonteCarloSettings):
        raise ValueError(f"settings must be a MonteCarloSettings, got {type(st).__name__}")
    st = st.for_model(gait.model)
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
                                              settings=st.to_dict(),
                                              code_sha256=code_version("montecarlo")))
    reused = 0
    # the chunks are tasks of an engine (kept in the folder, not in the cache); connected
    # before anything is written
    with Engine(scheduler, workers, cache=False, preload=(evaluate_chunk.__module__,)) as eng:
        if store is not None:
            store.open()
        try:
            if store is not None:
                _reuse_chunks(store, todo, results, K)
                reused = len(results)
                todo = [t for t in todo if t[0] not in results]
            bar = progress_bar(progress, N, sum(min(k * C + C, N) - k * C for k in results),
                               "run", "monte carlo")
            try:
                computed, compute_time, steps_done = _compute_chunks(eng, payload, todo,
                                                                     results, store, bar)
            finally:
                bar.close()
            if store is not None:
                store.log(dict(time=time.strftime("%Y-%m-%dT%H:%M:%S"), reused=reused,
                               computed=computed))
        finally:
            if store is not None:
                store.close()
    return _result(gait, spec, st, results, out_dir, t0, compute_time, steps_done,
                   computed, reused)


def _reuse_chunks(store, todo, results, K):
    """Read into ``results`` the chunks of ``todo`` the folder holds (a damaged file is
    logged and discarded)."""
    files = store.chunk_files()
    for k, a, b in todo:
        for path in files.get(k, []):
            try:
                results[k] = store.read_runs(path, k, a, b - a, K)
                break
            except (OSError, ValueError) as e:
                store.log(dict(chunk=k, discarded=path.name, why=str(e)))
                store.discard(path)


def _compute_chunks(eng, payload, todo, results, store, bar):
    """Compute the chunks of ``todo`` on the engine, each recorded in ``results`` (and
    the folder) as it arrives: (chunks computed, their compute time, their steps)."""
    computed, compute_time, steps_done = 0, 0.0, 0
    try:
        for (k, a, b), out in eng.each(evaluate_chunk, {t: (payload, t[1], t[2]) for t in todo}):
            if store is not None:
                store.write_runs(k, a, out)
            results[k] = out
            computed += 1
            compute_time += out["elapsed"]
            steps_done += out["scenario_steps"]
            bar.update(b - a)
    except TaskError as e:
        raise ValueError(f"scheduler: {e}") from None
    return computed, compute_time, steps_done


def _result(gait, spec, st, results, out_dir, t0, compute_time, steps_done, computed,
            reused):
    """The chunks' runs put together: the MFPT estimate, the step time's RMS deviation,
    the counts and the run's record."""
    N, K = st.runs, st.max_steps
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
        message=(f"a profile of {len(st.profile)} heights (run i walks it from its i-th "
                 f"height, wrapping round: the runs are windows of one profile, not "
                 f"independent draws, so the interval is indicative)" if st.profile else
                 f"sigma = {st.sigma:g} m") + f", {N} runs of up to {K} steps ({spec.engine}): "
                + est.message,
        walked=walked, failed=failed, duration=duration)
