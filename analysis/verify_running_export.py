"""The check of an exported running controller (:mod:`biped_casadi.control.export_running`):
its compiled library against the Python law.

- states: ``biped_running_torque`` against the controller's CasADi Functions
  (``stance_law``, ``flight_law``, then ``applied``) at random states of both phases: a
  collocated state of the gait plus Gaussian errors (0.05 rad, 0.5 rad/s; the flight's
  base coordinates too), t uniform over [-0.1, 1.6] times the phase's duration (the MuJoCo
  loop lets a phase last up to twice the gait's); the largest relative difference
  max|u_C - u_Python| / max|u_Python|, and how many torques are equal bit for bit;
- MuJoCo: the same run (:class:`~biped_casadi.mujoco.running.RunningLoop`) with the law
  called from Python and from the library, stride by stride (every field of the
  records: durations, speed, landing state, peak torque, slip, ...);
- timing: the C law in the example's loop (C alone), through ctypes, and the Python law's
  Function one state at a time (:class:`~biped_casadi.numerics.FastCall`, the call the
  MuJoCo loop makes).
"""
from __future__ import annotations

import dataclasses
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biped_casadi.control.compiled import find_c_compiler
from biped_casadi.control.compiled_running import CompiledRunningLaw
from biped_casadi.control.export_running import PHASES, RUNNING_LIBRARY
from biped_casadi.mujoco.running import RunningLoop
from biped_casadi.numerics import FastCall
from biped_casadi.results import Result

from .verify_export import TORQUE_RTOL, time_example

__all__ = ["RunningStateComparison", "RunningMujocoComparison", "RunningExportVerification",
           "compare_running_states", "compare_running_mujoco", "verify_running_export",
           "STRIDE_TOL"]

#: the stride records of the two MuJoCo runs must agree to this (s, m, m/s, rad, rad/s, N m)
STRIDE_TOL = 1e-9


@dataclass
class RunningStateComparison(Result):
    """The compiled running law against the Python law at random states of both phases.

    Parameters
    ----------
    status : {'equal', 'different'}
        'equal' when ``max_torque_rel`` <= :data:`~analysis.verify_export.TORQUE_RTOL`
        and every call returned 0.
    message : str
        A summary line.
    n : int
        States compared per phase.
    max_torque_rel : dict
        Per phase, the largest max|u_C - u_Python| / max|u_Python|.
    max_torque_abs : dict
        Per phase, the largest max|u_C - u_Python|, N m.
    bitwise_equal : dict
        Per phase, how many states gave the same torques bit for bit.
    return_codes : dict
        How many calls returned each code.
    python_us, ctypes_us : float
        Time per call of the Python law's Function (FastCall) and of the library through
        ctypes, microseconds (both phases).
    """
    status: str
    message: str
    n: int
    max_torque_rel: dict
    max_torque_abs: dict
    bitwise_equal: dict
    return_codes: dict
    python_us: float
    ctypes_us: float

    SUCCESS = ("equal",)


@dataclass
class RunningMujocoComparison(Result):
    """A MuJoCo run with the compiled law against the same run with the Python law.

    Parameters
    ----------
    status : {'equal', 'different', 'nothing_compared'}
        'equal' when both runs end alike with as many strides and every number of their
        stride records agrees to :data:`STRIDE_TOL`; 'nothing_compared' when both end
        alike before their first stride is complete (no record to compare: the design
        does not run in MuJoCo); 'different' otherwise.
    message : str
        A summary line.
    python_status, compiled_status : str
        How each run ended.
    strides : int
        Strides compared.
    max_difference : float
        Largest difference of any number of the stride records (a NaN in both records
        counts as equal, in one only as inf).
    identical_strides : int
        Strides whose records are the same bit for bit.
    python_seconds, compiled_seconds : float
        Wall time of each run (the loop's own bookkeeping included).
    mujoco_steps : int
        MuJoCo steps of the compiled run.
    """
    status: str
    message: str
    python_status: str
    compiled_status: str
    strides: int
    max_difference: float
    identical_strides: int
    python_seconds: float
    compiled_seconds: float
    mujoco_steps: int

    SUCCESS = ("equal",)


@dataclass
class RunningExportVerification(Result):
    """An exported running controller checked: states, MuJoCo, time per call.

    Parameters
    ----------
    status : {'verified', 'unverified', 'different'}
        'verified' when the state comparison and the MuJoCo comparison (when run) succeed;
        'unverified' when the states agree but the MuJoCo runs compared nothing (both
        stopped in their first stride); 'different' otherwise.
    message : str
        A summary line.
    states : RunningStateComparison
    mujoco : RunningMujocoComparison or None
        None with no strides asked for.
    c_us : float
        Microseconds per ``biped_running_torque`` call in the example's loop (C alone).
    c_calls : int
        Calls in that loop.
    """
    status: str
    message: str
    states: RunningStateComparison
    mujoco: RunningMujocoComparison | None
    c_us: float
    c_calls: int

    SUCCESS = ("verified",)


def _random_states(ctrl, phase: str, n: int, rng) -> tuple:
    """(t, q, dq) of n random states of a phase near its collocated states."""
    g = ctrl.gait
    X = np.asarray(getattr(g, f"x_{phase}"), float)
    T = float(getattr(g, f"T_{phase}"))
    ne = X.shape[0] // 2
    j = rng.integers(0, X.shape[1], n)
    q = X[:ne, j] + rng.normal(0.0, 0.05, (ne, n))
    dq = X[ne:, j] + rng.normal(0.0, 0.5, (ne, n))
    return rng.uniform(-0.1, 1.6, n) * T, q, dq


def compare_running_states(compiled: CompiledRunningLaw, ctrl, n: int = 10_000,
                           seed: int = 0) -> RunningStateComparison:
    """The compiled law against the Python law at ``n`` random states of each phase.

    Parameters
    ----------
    compiled : CompiledRunningLaw
        The library.
    ctrl : RunningController
        The exported controller.
    n : int
        States per phase.
    seed : int
        Seed of the random states.

    Returns
    -------
    RunningStateComparison
    """
    rng = np.random.default_rng(seed)
    rel, absu, same, codes = {}, {}, {}, {}
    t_py = t_c = 0.0
    for k, phase in enumerate(PHASES):
        law = FastCall(getattr(ctrl, f"{phase}_law"))
        t, q, dq = _random_states(ctrl, phase, n, rng)
        r, a, s = np.zeros(n), np.zeros(n), 0
        for i in range(n):
            t0 = time.perf_counter()
            up = law(q[:, i], dq[:, i], t[i])[0].ravel()
            t1 = time.perf_counter()
            rc, uc = compiled.torque(k, float(t[i]), q[:, i], dq[:, i])
            t2 = time.perf_counter()
            t_py, t_c = t_py + t1 - t0, t_c + t2 - t1
            up = np.asarray(ctrl.applied(up), float).ravel()
            codes[rc] = codes.get(rc, 0) + 1
            a[i] = np.max(np.abs(uc - up))
            r[i] = a[i] / max(np.max(np.abs(up)), 1e-300)
            s += bool(np.array_equal(uc, up))
        rel[phase], absu[phase], same[phase] = float(r.max()), float(a.max()), s
    worst = max(rel.values())
    ok = worst <= TORQUE_RTOL and set(codes) == {0}
    return RunningStateComparison(
        status="equal" if ok else "different",
        message=(f"{n} random states per phase: torques differ by at most {worst:.3g} "
                 f"relative, {sum(same.values())} of {2 * n} equal bit for bit"
                 + ("" if ok else f" (limit {TORQUE_RTOL:g}, return codes {codes})")),
        n=int(n), max_torque_rel=rel, max_torque_abs=absu, bitwise_equal=same,
        return_codes={str(k): v for k, v in sorted(codes.items())},
        python_us=1e6 * t_py / (2 * n), ctypes_us=1e6 * t_c / (2 * n))


def _stride_numbers(s) -> np.ndarray:
    d = dataclasses.asdict(s)
    return np.hstack([np.ravel(np.asarray(v, float)) for v in d.values()])


def _stride_difference(a, b) -> float:
    """The largest difference of two stride records' numbers: equal numbers (infinite
    ones too) and a NaN in both (a field the stride has no value for, e.g. the takeoff
    guard's gap when the guard did not cross) differ by 0, a NaN in one only by inf."""
    x, y = _stride_numbers(a), _stride_numbers(b)
    with np.errstate(invalid="ignore"):
        d = np.where(x == y, 0.0, np.abs(x - y))
    d[np.isnan(x) & np.isnan(y)] = 0.0
    return float(np.nan_to_num(d, nan=np.inf).max(initial=0.0))


def compare_running_mujoco(compiled: CompiledRunningLaw, ctrl, start=None, strides: int = 30,
                           **loop_options) -> RunningMujocoComparison:
    """The same MuJoCo run with the Python law and with the compiled one.

    Parameters
    ----------
    compiled : CompiledRunningLaw
        The library.
    ctrl : RunningController
        The exported controller.
    start : array_like, optional
        The landing state to start from (default the loop's fixed point).
    strides : int
        Strides of each run.
    **loop_options
        Of :class:`~biped_casadi.mujoco.running.RunningLoop` (``settings``,
        ``fixed_point``, ...).

    Returns
    -------
    RunningMujocoComparison
    """
    runs = [RunningLoop(ctrl, compiled=law, **loop_options).run(start, strides)
            for law in (None, compiled)]
    rp, rc = runs
    diffs = [_stride_difference(a, b) for a, b in zip(rp.strides, rc.strides)]
    worst = max(diffs, default=0.0)
    same = sum(d == 0.0 for d in diffs)
    ok = (rp.status == rc.status and len(rp.strides) == len(rc.strides) and
          worst <= STRIDE_TOL)
    if ok and not diffs:
        status, message = "nothing_compared", (
            f"both MuJoCo runs stopped in stride 1 ({rc.status}): no stride to compare")
    else:
        status, message = "equal" if ok else "different", (
            f"{len(diffs)} MuJoCo strides ({rc.status} compiled, {rp.status} Python): "
            f"records differ by at most {worst:.3g}, {same} identical bit for bit")
    return RunningMujocoComparison(
        status=status, message=message,
        python_status=rp.status, compiled_status=rc.status, strides=len(diffs),
        max_difference=worst, identical_strides=int(same), python_seconds=rp.wall_time,
        compiled_seconds=rc.wall_time, mujoco_steps=rc.mujoco_steps)


def verify_running_export(folder, ctrl, compiler: list | None = None, n_states: int = 10_000,
                          strides: int = 30, seed: int = 0, calls: int = 1_000_000,
                          **loop_options) -> RunningExportVerification:
    """Build a running export's library, compare it with the Python law, time it.

    Parameters
    ----------
    folder : str or Path
        The export (checked to be of ``ctrl``).
    ctrl : RunningController
        The exported controller.
    compiler : list of str, optional
        Default :func:`~biped_casadi.control.compiled.find_c_compiler`.
    n_states : int
        Random states per phase.
    strides : int
        Strides of the MuJoCo comparison (0: none).
    seed : int
        Seed of the random states.
    calls : int
        Calls in the example's timing loop.
    **loop_options
        Of the MuJoCo loop.

    Returns
    -------
    RunningExportVerification

    Raises
    ------
    ValueError
        The export is of another controller.
    CompilerError
        No compiler, or the library or the example does not build.
    """
    cc = compiler if compiler is not None else find_c_compiler()
    with tempfile.TemporaryDirectory(prefix="biped-export-") as work:
        lib = CompiledRunningLaw.build(folder, ctrl, Path(work) / RUNNING_LIBRARY, cc)
        c_us, _ = time_example(folder, cc, calls, work, function="biped_running_torque")
    states = compare_running_states(lib, ctrl, n_states, seed)
    mj = compare_running_mujoco(lib, ctrl, None, strides, **loop_options) if strides else None
    ok = states.success and (mj is None or mj.success)
    unverified = states.success and mj is not None and mj.status == "nothing_compared"
    return RunningExportVerification(
        status="verified" if ok else "unverified" if unverified else "different",
        message="; ".join([states.message] + ([mj.message] if mj else [])
                          + [f"{c_us:.3g} us per biped_running_torque call in C"]),
        states=states, mujoco=mj, c_us=c_us, c_calls=int(calls))
