"""The chunks of a Monte Carlo: what a worker evaluates (a slice of the runs, walked by
the walker or simulator of the spec, built once per process) and how finished chunks are
stored (Parquet files in the sweep store's layout, checked on reading)."""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np

from biped_casadi import (SimulationOptions)
from biped_casadi.caching import cached, digest
from biped_casadi.simulation import (WalkBatch, simulator,
                                     virtual_constraint_walker, zero_dynamics_walker)
from biped_casadi.simulation.outcome import STATUSES
from gait_opt import Gait

from ..sweeps.storage import SweepStore
from ..tasks import task

from .spec import MonteCarloSettings, WalkerSpec

__all__ = ["MonteCarloStore", "evaluate_chunk"]


@dataclass(frozen=True)
class _Payload:
    """What a worker needs: the gait's dictionary and digest, what walks, the settings."""
    gait: dict
    gait_sha256: str
    spec: WalkerSpec
    settings: MonteCarloSettings

    @property
    def cache_key(self):
        return (self.gait_sha256, digest(self.spec.to_dict()), digest(self.settings.to_dict()),
                self.settings.compiled)


@cached(maxsize=4)
def _gait_for(gait_sha256: str, gait: dict) -> Gait:
    return Gait.from_dict(gait)


@cached(maxsize=8)
def _engine(payload: _Payload):
    """The walker or simulator of a payload (built once per process)."""
    gait = _gait_for(payload.gait_sha256, payload.gait)
    spec, st = payload.spec, payload.settings
    opts = st.options(spec, gait.T)
    # the walkers' options hold only validity thresholds: those of the basins and of
    # robustness runs with the same thresholds, so a process shares one compiled walker
    wopts = SimulationOptions(mu=st.mu, torque_limit=st.torque_limit)
    if spec.engine == "zero_dynamics":
        return gait, zero_dynamics_walker(gait, wopts, st.rk4_steps, jit=True)
    if spec.engine == "virtual_constraints":
        return gait, virtual_constraint_walker(gait, wopts, st.vc_nodes, jit=True)
    return gait, simulator(spec.controller_for(gait), opts, spec.plant_model())


@task(code="montecarlo")
def evaluate_chunk(payload, start: int, stop: int) -> dict:
    """Walk runs ``start:stop`` (a task: on a Dask worker, or in this process).

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
        and ``build`` (s, building the walker or simulator when this process had not
        yet).
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
                build=built - t0)



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


