"""The check of an exported controller: its compiled library against the Python law.

Three comparisons (docs/howto/export.md):

- states: the torques of ``biped_torque`` against the Python law at random states near
  the orbit (tau in [0, 1.1 T], q and dq the reference's plus Gaussian errors of the
  paper's perturbation size, step constants from perturbed starts), as the largest
  relative difference max|u_C - u_Python| / max|u_Python| over the states; the
  outputs, their rates and the denominator (``biped_outputs``) too;
- simulation: a full-order run driven by the compiled library
  (:class:`~biped_casadi.control.compiled.CompiledController`) against two runs driven by
  the Python law, impact times and states (q, dq before and after every impact): the
  Python law called as the library is (:class:`~biped_casadi.control.compiled.PythonTwin`,
  the same closed loop of numeric calls: the runs agree to round-off; for an export in
  URDF angles :class:`~biped_casadi.control.urdf_twin.PythonUrdfTwin`, the export's own
  Functions through the same conversions), and ``biped
  simulate``'s run.  The latter differs by discretisation: in ``biped simulate`` the
  time-varying law's reference state r = (q_u^d, dq_u^d) is integrated with the robot in
  every RK4 stage, while the compiled law reads it from the gait's interpolant (as on a
  robot), a difference of order h^4 (16 times smaller at half the RK4 step) that grows
  with |M1|;
- timing: the C law in the example's loop (C alone), through ctypes, and the Python law
  called one state at a time.
"""
from __future__ import annotations

import os
import re
import subprocess
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from biped_casadi import Perturbation, SimulationOptions, simulate
from biped_casadi.control.export import LIBRARY
from biped_casadi.control.export_urdf import LEG_ORDER, UrdfAngleLaw
from biped_casadi.control.compiled import (CompiledController, CompiledUrdfController,
                                           CompilerError, PythonTwin, build_library,
                                           find_c_compiler)
from biped_casadi.control.saturation import clip_torques
from biped_casadi.control.urdf_twin import PythonUrdfTwin
from biped_casadi.numerics import compiler_reason
from biped_casadi.results import Result

__all__ = ["StateComparison", "SimulationComparison", "ExportVerification",
           "compare_states", "compare_urdf_states", "compare_simulations", "time_example",
           "verify_export", "TORQUE_RTOL", "SIMULATION_TOL"]

#: compiled torques must equal the Python law's to this relative difference
TORQUE_RTOL = 1e-12
#: impact times (s) and states (rad, rad/s) of the two runs must agree to this
SIMULATION_TOL = 1e-9


@dataclass
class StateComparison(Result):
    """The compiled law against the Python law at random states.

    Parameters
    ----------
    status : {'equal', 'different'}
        'equal' when ``max_torque_rel`` <= :data:`TORQUE_RTOL`.
    message : str
        A summary line.
    n : int
        States compared.
    max_torque_rel : float
        Largest max|u_C - u_Python| / max|u_Python| over the states.
    max_torque_abs : float
        Largest max|u_C - u_Python|, N m.
    max_output_abs : float
        Largest difference of the outputs y and their rates dy.
    max_den_rel : float
        Largest relative difference of the decoupling denominator.
    return_codes : dict
        How many calls returned each code (``biped_torque``).
    python_us, ctypes_us : float
        Time per call of the Python law (one state at a time) and of the library through
        ctypes, microseconds.
    stance_found : int or None
        An export in URDF angles: of the step starts (near the orbit's start) both laws
        start, how many ``biped_step_start`` gave the stance leg the state was read for
        (None otherwise).
    starts_refused : int
        Random step starts both laws refuse (the phase moving backwards, which a slow
        gait's small phase rate meets within the random errors): not compared further.
    starts_disagree : int
        Step starts one law refuses and the other starts (any makes it 'different').
    """
    status: str
    message: str
    n: int
    max_torque_rel: float
    max_torque_abs: float
    max_output_abs: float
    max_den_rel: float
    return_codes: dict
    python_us: float
    ctypes_us: float
    stance_found: int | None = None
    starts_refused: int = 0
    starts_disagree: int = 0

    SUCCESS = ("equal",)


@dataclass
class SimulationComparison(Result):
    """A full-order run driven by the compiled law against the Python-driven runs.

    Two Python runs: ``biped simulate``'s (the Python controller in the simulator, its
    reference state integrated with the robot) and the twin's (the Python law called as
    the library is, :class:`~biped_casadi.control.compiled.PythonTwin`, or for an export
    in URDF angles :class:`~biped_casadi.control.urdf_twin.PythonUrdfTwin`, in the same
    numeric loop).

    Parameters
    ----------
    status : {'equal', 'discretisation', 'different', 'nothing_compared'}
        'equal' when both Python runs end as the compiled one, with as many steps, and
        impact times and states agree to :data:`SIMULATION_TOL`; 'discretisation' when
        the twin's do but ``biped simulate``'s differ by more (the reference state's
        discretisation, O(h^4): see the module docstring); 'nothing_compared' when
        :func:`verify_export`'s runs end alike before an impact from the given start and
        from the orbit's (no impact compared); 'different' otherwise.
    message : str
        A summary line.
    python_status, twin_status, compiled_status : str
        How each run ended (the simulator's statuses).
    steps : int
        Impacts compared.
    max_impact_time, max_state : float
        Largest difference from ``biped simulate``'s run of the impact times (s) and of
        q, dq just before and just after the impacts.
    twin_max_impact_time, twin_max_state : float
        The same from the twin's run.
    per_step : list
        (impact time difference, state difference) from ``biped simulate``'s run, per step.
    python_seconds, twin_seconds, compiled_seconds : float
        Wall time of each run.
    start : {'given', 'orbit'}
        Where the compared runs started: the given state, or the orbit's start when the
        runs from the given state ended before an impact (nothing of the impact and the
        step start compared; see :func:`verify_export`).
    """
    status: str
    message: str
    python_status: str
    twin_status: str
    compiled_status: str
    steps: int
    max_impact_time: float
    max_state: float
    twin_max_impact_time: float
    twin_max_state: float
    per_step: list
    python_seconds: float
    twin_seconds: float
    compiled_seconds: float
    start: str = "given"

    SUCCESS = ("equal", "discretisation")


@dataclass
class ExportVerification(Result):
    """An exported controller's library built and compared with the Python law.

    Parameters
    ----------
    status : {'verified', 'unverified', 'different'}
        'verified' when the states and the simulation agree; 'unverified' when the
        states agree but the simulations compared no impact (they all ended before one);
        'different' otherwise.
    message : str
        A summary line.
    states : StateComparison
    simulation : SimulationComparison
    c_us : float
        Time per ``biped_torque`` call in the example's C loop, microseconds (NaN when
        the example could not run).
    c_calls : int
        Calls in that loop.
    """
    status: str
    message: str
    states: StateComparison
    simulation: SimulationComparison
    c_us: float
    c_calls: int

    SUCCESS = ("verified",)


# ====================================================================== states
def _random_states(ctrl, n, rng, q_err=0.01, dq_err=0.1):
    """(tau, q, dq, p) of n states near the orbit and the Python law's step constants."""
    ref, nq = ctrl.reference, ctrl.model.nq
    tau = rng.uniform(0.0, 1.1 * ref.T, n)
    q = ref.q(tau) + rng.normal(0.0, q_err, (nq, n))
    dq = ref.dq(tau) + rng.normal(0.0, dq_err, (nq, n))
    q0 = ref.q(0.0)[:, None] + rng.normal(0.0, q_err, (nq, n))
    dq0 = ref.dq(0.0)[:, None] + rng.normal(0.0, dq_err, (nq, n))
    return tau, q, dq, q0, dq0


def _starts(python_refuses, library_refuses, counts: dict) -> bool:
    """Whether a step start is compared further: not when the Python law or the library
    refuses it (a StepStart's ``problem``, a non-zero return code); ``counts`` keeps
    'refused' (both refuse) and 'disagree' (one does)."""
    if not python_refuses and not library_refuses:
        return True
    counts["refused" if python_refuses and library_refuses else "disagree"] += 1
    return False


def _starts_note(counts: dict) -> str:
    """The message's words on the step starts not compared."""
    return ((f"; {counts['refused']} step starts refused by both laws (the phase moving "
             f"backwards)" if counts["refused"] else "")
            + (f"; {counts['disagree']} step starts refused by one law only"
               if counts["disagree"] else ""))


def _python_law(ctrl):
    """The Python law at one state: (u, y, dy, den), timed by the caller."""
    nu = ctrl.model.nu
    if ctrl.n_ref:
        def law(tau, q, dq, p):
            return ctrl.torque(q, dq, tau, p[:nu], p[nu:])
    else:
        def law(tau, q, dq, p):
            return ctrl.evaluate(q, dq, tau, np.zeros(0), p)
    return law


def compare_states(compiled: CompiledController, ctrl, n: int = 10_000,
                   seed: int = 0, torque_limit: float | None = None) -> StateComparison:
    """The compiled law against the Python law at ``n`` random states near the orbit.

    Parameters
    ----------
    compiled : CompiledController
        The library.
    ctrl : TimeVaryingController or VirtualConstraintController
        The exported controller.
    n : int
        States.
    seed : int
        Seed of the random states.
    torque_limit : float, optional
        The export clips its torques at +-torque_limit (N m): the Python law's are
        clipped the same way before the comparison.

    Returns
    -------
    StateComparison
    """
    rng = np.random.default_rng(seed)
    tau, q, dq, q0, dq0 = _random_states(ctrl, n, rng)
    law = _python_law(ctrl)
    lim = np.inf if torque_limit is None else torque_limit
    rel = np.zeros(n)
    absu, outs, dens = np.zeros(n), np.zeros(n), np.zeros(n)
    codes: dict = {}
    starts = dict(refused=0, disagree=0)
    t_py = t_c = 0.0
    for k in range(n):
        start = ctrl.step_start(q0[:, k], dq0[:, k])
        cstart = compiled.step_start(q0[:, k], dq0[:, k])
        if not _starts(start.problem, cstart.problem, starts):
            continue
        p, pc = start.p, cstart.p
        qk, dqk, tk = q[:, k], dq[:, k], float(tau[k])
        t0 = time.perf_counter()
        out = law(tk, qk, dqk, p)
        t1 = time.perf_counter()
        rc, u = compiled.torque(tk, qk, dqk, pc)
        t2 = time.perf_counter()
        t_py, t_c = t_py + t1 - t0, t_c + t2 - t1
        codes[rc] = codes.get(rc, 0) + 1
        _, y, dy, den = compiled.outputs(tk, qk, dqk, pc)
        u_py = clip_torques(out.u, lim)
        absu[k] = np.max(np.abs(u - u_py))
        rel[k] = absu[k] / max(np.max(np.abs(u_py)), 1e-300)
        outs[k] = max(np.max(np.abs(y - out.y)), np.max(np.abs(dy - out.dy)))
        dens[k] = abs(den - out.denominator) / abs(out.denominator)
    worst = float(rel.max())
    ok = worst <= TORQUE_RTOL and not starts["disagree"]
    called = max(n - starts["refused"] - starts["disagree"], 1)
    return StateComparison(
        status="equal" if ok else "different",
        message=(f"{n} random states: torques differ by at most {worst:.3g} relative "
                 f"({absu.max():.3g} N m)" + ("" if worst <= TORQUE_RTOL else
                                               f", above {TORQUE_RTOL:g}")
                 + _starts_note(starts)),
        n=n, max_torque_rel=worst, max_torque_abs=float(absu.max()),
        max_output_abs=float(outs.max()), max_den_rel=float(dens.max()),
        return_codes={str(k): v for k, v in sorted(codes.items())},
        python_us=1e6 * t_py / called, ctypes_us=1e6 * t_c / called,
        starts_refused=starts["refused"], starts_disagree=starts["disagree"])


def compare_urdf_states(compiled: CompiledUrdfController, ctrl, n: int = 10_000,
                        seed: int = 0, torque_limit: float | None = None) -> StateComparison:
    """An export in URDF angles against the toolkit's law at ``n`` random states.

    The states of :func:`compare_states`, each read with a random stance leg as the
    robot gives them (pitch and URDF joint angles, :meth:`UrdfMap.from_model`); the
    library is called in those coordinates (``biped_step_start_leg``, ``biped_torque``)
    and compared with :class:`~biped_casadi.control.export_urdf.UrdfAngleLaw` (numpy's
    conversion to the model's coordinates, the Python law, the torques mapped back).
    ``biped_step_start`` must find the same stance leg at every start.

    Parameters
    ----------
    compiled : CompiledUrdfController
        The library.
    ctrl : TimeVaryingController or VirtualConstraintController
        The exported controller.
    n : int
        States.
    seed : int
        Seed of the random states.
    torque_limit : float, optional
        As in :func:`compare_states` (the model's torques clipped before the mapping).

    Returns
    -------
    StateComparison
        ``success`` needs the torques to :data:`TORQUE_RTOL` and every stance leg found.
    """
    rng = np.random.default_rng(seed)
    tau, q, dq, q0, dq0 = _random_states(ctrl, n, rng)
    legs = rng.integers(0, 2, n)
    umap = compiled.urdf_map
    law = UrdfAngleLaw(ctrl, umap, compiled.motor_side, torque_limit)
    rel = np.zeros(n)
    absu, outs, dens = np.zeros(n), np.zeros(n), np.zeros(n)
    codes: dict = {}
    starts = dict(refused=0, disagree=0)
    found = 0
    t_py = t_c = 0.0
    for k in range(n):
        s = int(legs[k])
        x0, dx0 = umap.from_model(q0[:, k], dq0[:, k], LEG_ORDER[s])
        x, dx = umap.from_model(q[:, k], dq[:, k], LEG_ORDER[s])
        rc_leg, pc = compiled.start_leg(s, x0, dx0)
        if not _starts(ctrl.step_start(q0[:, k], dq0[:, k]).problem, rc_leg != 0, starts):
            continue
        p = law.step_start(x0, dx0, s)
        rc_auto, pa = compiled.start_urdf(x0, dx0)
        found += int(rc_auto == 0 and pa[0] == s)
        tk = float(tau[k])
        t0 = time.perf_counter()
        u, y, dy, den = law.evaluate(tk, x, dx, p)
        t1 = time.perf_counter()
        rc, uc = compiled.torque_urdf(tk, x, dx, pc)
        t2 = time.perf_counter()
        t_py, t_c = t_py + t1 - t0, t_c + t2 - t1
        codes[rc] = codes.get(rc, 0) + 1
        _, yc, dyc, denc = compiled.outputs_urdf(tk, x, dx, pc)
        absu[k] = np.max(np.abs(uc - u))
        rel[k] = absu[k] / max(np.max(np.abs(u)), 1e-300)
        outs[k] = max(np.max(np.abs(yc - np.ravel(y))), np.max(np.abs(dyc - np.ravel(dy))))
        dens[k] = abs(denc - den) / abs(den)
    worst = float(rel.max())
    called = n - starts["refused"] - starts["disagree"]
    ok = worst <= TORQUE_RTOL and found == called and not starts["disagree"]
    return StateComparison(
        status="equal" if ok else "different",
        message=(f"{n} random states in URDF angles: torques differ by at most {worst:.3g} "
                 f"relative ({absu.max():.3g} N m), the stance leg found at {found} of "
                 f"{called} step starts" + ("" if ok else f" (limit {TORQUE_RTOL:g}, all "
                                                          f"found)") + _starts_note(starts)),
        n=n, max_torque_rel=worst, max_torque_abs=float(absu.max()),
        max_output_abs=float(outs.max()), max_den_rel=float(dens.max()),
        return_codes={str(k): v for k, v in sorted(codes.items())},
        python_us=1e6 * t_py / max(called, 1), ctypes_us=1e6 * t_c / max(called, 1),
        stance_found=found, starts_refused=starts["refused"],
        starts_disagree=starts["disagree"])


# ================================================================== simulation
def _step_differences(a, b) -> list:
    out = []
    for sa, sb in zip(a.steps, b.steps):
        ds = max(float(np.max(np.abs(getattr(sa, f) - getattr(sb, f))))
                 for f in ("q_minus", "dq_minus", "q_plus", "dq_plus"))
        out.append((abs(sa.t_impact - sb.t_impact), ds))
    return out


def _timed(ctrl, q0, dq0, options):
    t0 = time.perf_counter()
    r = simulate(ctrl, q0, dq0, options)
    return r, time.perf_counter() - t0


def _agree(a, b):
    """(alike, largest impact-time difference, largest state difference, per step)."""
    diffs = _step_differences(a, b)
    dt = max((d[0] for d in diffs), default=0.0)
    ds = max((d[1] for d in diffs), default=0.0)
    alike = a.status == b.status and len(a.steps) == len(b.steps)
    return alike and dt <= SIMULATION_TOL and ds <= SIMULATION_TOL, dt, ds, diffs


def apart_reason(n_ref: int) -> str:
    """Why ``biped simulate``'s run differs from the Python law's in the library's loop.

    Parameters
    ----------
    n_ref : int
        The controller's reference state's size (0: the law does not read one).

    Returns
    -------
    str
        The time-varying law's reference state, integrated with the robot there: O(h^4);
        without one, round-off, which the closed loop grows.
    """
    if n_ref:
        return ("its integration of the reference state, O(h^4): 16 times smaller at half "
                "the RK4 step")
    return ("round-off: there the law and the robot are one CasADi expression per RK4 step, "
            "evaluated in another order, and the closed loop grows the difference")


def compare_simulations(compiled: CompiledController, ctrl, q0, dq0,
                        options: SimulationOptions | None = None,
                        law=None) -> SimulationComparison:
    """A full-order run driven by the compiled law against the Python-driven runs.

    Parameters
    ----------
    compiled : CompiledController
        The library.
    ctrl : TimeVaryingController or VirtualConstraintController
        The exported controller.
    q0, dq0 : array_like
        The initial state (the start of a step).
    options : SimulationOptions, optional
        The runs' options (default ``SimulationOptions()``: 10 steps).
    law : ExportedLaw, optional
        The export; one in URDF angles is driven in Python the way the library is
        (:class:`~biped_casadi.control.urdf_twin.PythonUrdfTwin`: through the same
        conversions), else the toolkit's law is (:class:`PythonTwin`).

    Returns
    -------
    SimulationComparison
    """
    options = options if options is not None else SimulationOptions()
    a, ta = _timed(ctrl, q0, dq0, options)
    urdf = law is not None and law.angles == "urdf"
    twin = PythonUrdfTwin(ctrl, law) if urdf else PythonTwin(ctrl)
    tw, tt = _timed(twin, q0, dq0, options)
    b, tb = _timed(compiled, q0, dq0, options)
    ok, dt, ds, diffs = _agree(a, b)
    ok_twin, dt_twin, ds_twin, _ = _agree(tw, b)
    status = "equal" if ok and ok_twin else ("discretisation" if ok_twin else "different")
    msg = (f"{len(diffs)} impact(s): times differ from biped simulate's run by at most "
           f"{dt:.3g} s, states by {ds:.3g}; from the Python law's in the same loop by "
           f"{dt_twin:.3g} s and {ds_twin:.3g}; runs {a.status} (biped simulate), "
           f"{tw.status} (Python law), {b.status} (compiled)")
    if status == "discretisation":
        msg += (f" (the difference from biped simulate's run, above {SIMULATION_TOL:g}, is "
                f"{apart_reason(ctrl.n_ref)})")
    return SimulationComparison(
        status=status, message=msg, python_status=a.status, twin_status=tw.status,
        compiled_status=b.status, steps=len(diffs), max_impact_time=dt, max_state=ds,
        twin_max_impact_time=dt_twin, twin_max_state=ds_twin,
        per_step=[list(d) for d in diffs], python_seconds=ta, twin_seconds=tt,
        compiled_seconds=tb)


# ====================================================================== timing
def time_example(folder, compiler: list, calls: int = 1_000_000, work=None,
                 function: str = "biped_torque") -> tuple:
    """Build and run the export's example (``example/main.c``): the C time per call.

    Parameters
    ----------
    folder : str or Path
        The export.
    compiler : list of str
        The C compiler command.
    calls : int
        Calls of ``biped_torque`` in the loop.
    work : str or Path, optional
        Where the executable goes (default the system's temporary folder); it is removed
        after the run.
    function : str
        The function the example times (its line ``FUNCTION: X us per call``):
        ``biped_running_torque`` for a running export.

    Returns
    -------
    tuple
        (microseconds per call, the example's output line).

    Raises
    ------
    CompilerError
        When the example does not build or run.
    """
    folder = Path(folder)
    exe = Path(work if work is not None else tempfile.gettempdir()) / \
        f"biped_export_example_{os.getpid()}"
    cmd = [*compiler, "-O2", "-o", str(exe), str(folder / "example" / "main.c"),
           *sorted(str(p) for p in folder.glob("*.c")), "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise CompilerError(f"{compiler[0]} failed on the example: "
                            f"{compiler_reason(r.stderr)}")
    try:
        run = subprocess.run([str(exe), str(int(calls))], capture_output=True, text=True,
                             timeout=600)
    finally:
        exe.unlink(missing_ok=True)
    m = re.search(rf"{re.escape(function)}: ([0-9.eE+-]+) us per call", run.stdout)
    if run.returncode != 0 or m is None:
        raise CompilerError(f"the example failed (exit {run.returncode}): "
                            f"{(run.stdout + run.stderr).strip()[:200]}")
    return float(m.group(1)), run.stdout.strip()


def verify_export(folder, ctrl, q0, dq0, options: SimulationOptions | None = None,
                  compiler: list | None = None, n_states: int = 10_000,
                  seed: int = 0, calls: int = 1_000_000, law=None) -> ExportVerification:
    """Build an export's library, compare it with the Python law, time it.

    Parameters
    ----------
    folder : str or Path
        The export (:func:`biped_casadi.control.export.write_export` or a folder with
        the same files).
    ctrl : TimeVaryingController or VirtualConstraintController
        The exported controller.
    q0, dq0 : array_like
        Initial state of the simulations (the paper's perturbation of the reference).
    options : SimulationOptions, optional
        The simulations' options (default 10 steps).
    compiler : list of str, optional
        The C compiler (default :func:`~biped_casadi.control.compiled.find_c_compiler`).
    n_states : int
        Random states compared.
    seed : int
        Their seed.
    calls : int
        Calls in the example's timing loop.
    law : ExportedLaw, optional
        The export's law; one in URDF angles is compared in those coordinates
        (:func:`compare_urdf_states`, and the simulation driven through
        :class:`~biped_casadi.control.compiled.CompiledUrdfController`); one that clips
        its torques (``law.torque_limit``) against the Python law clipped the same way,
        and simulated with ``options`` saturating at that limit.

    Returns
    -------
    ExportVerification

    Raises
    ------
    CompilerError
        No compiler, or the library or the example does not build.
    """
    cc = compiler if compiler is not None else find_c_compiler()
    with tempfile.TemporaryDirectory(prefix="biped-export-") as work:
        lib = build_library(folder, Path(work) / LIBRARY, compiler=cc)
        urdf = law is not None and law.angles == "urdf"
        compiled = (CompiledUrdfController(lib, ctrl, law.urdf, law.motor_side) if urdf
                    else CompiledController(lib, ctrl))     # loaded: the file may go
        c_us, _ = time_example(folder, cc, calls, work)
    limit = None if law is None else law.torque_limit
    if limit is not None:             # the robot receives what the law gives, clipped alike
        # per-joint bounds (a float in the options) are the robot's own: None takes them
        options = replace(options or SimulationOptions(), saturate=True,
                          torque_limit=limit if np.ndim(limit) == 0 else None)
    states = (compare_urdf_states if urdf else compare_states)(compiled, ctrl, n_states, seed,
                                                               limit)
    sim = compare_simulations(compiled, ctrl, q0, dq0, options, law)
    if sim.steps == 0 and (options is None or options.steps > 0):
        # the runs from the given start ended before an impact (a heavy robot out of its
        # torque limit, say): the impact map and the step start of the library would go
        # unchecked, so compare the runs from the orbit's own start as well
        first = sim
        q_orbit, dq_orbit = Perturbation.uniform(ctrl.gait.model.nq, 0.0, 0.0).initial_state(
            ctrl.gait)
        sim = compare_simulations(compiled, ctrl, q_orbit, dq_orbit, options, law)
        sim.start = "orbit"
        sim.message = (f"from the given start the runs ended before an impact ("
                       f"{first.compiled_status} compiled, {first.python_status} biped "
                       f"simulate, {first.status}); from the orbit's start: {sim.message}")
        if first.status not in SimulationComparison.SUCCESS:
            sim.status = first.status
        elif sim.steps == 0 and sim.success:
            sim.status = "nothing_compared"
            sim.message += "; from neither start an impact to compare"
    ok = states.success and sim.success
    unverified = states.success and sim.status == "nothing_compared"
    return ExportVerification(
        status="verified" if ok else "unverified" if unverified else "different",
        message=f"{states.message}; {sim.message}; {c_us:.3g} us per biped_torque call in C",
        states=states, simulation=sim, c_us=c_us, c_calls=int(calls))

