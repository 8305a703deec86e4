"""An exported controller compiled and loaded as a controller: the C compiler, the build
of the library, and :class:`CompiledController`, the library called through ctypes with
the interface the simulator uses.

The library is the one ``gcc -O2 -shared -fPIC -o libbiped_controller.so DIR/*.c -lm``
builds from an export (:mod:`biped_casadi.control.export`); the controller's torques
come from its ``biped_torque`` alone, while the model, the reference and the gains of the
exported controller say what the simulator needs around it (the plant, T, the
reference's errors).
"""
from __future__ import annotations

import ctypes
import os
import shlex
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ..numerics import FastCall, as_number, as_vector, compiler_reason
from .controller import StepStart
from .export import LIBRARY, RETURN_CODES, TAU_SLACK, exported_law
from .export_folder import file_digest
from .export_urdf import LEG_ORDER, torque_matrix
from .output_law import singularity_report

__all__ = ["find_c_compiler", "build_library", "NumericLaw", "CompiledController",
           "CompiledUrdfController", "PythonTwin", "UrdfLoop", "CompilerError"]


class CompilerError(RuntimeError):
    """The C compiler is missing or failed (the message says which and why)."""


def find_c_compiler() -> list | None:
    """The C compiler to use: ``$CC`` when set (and only it), else gcc, else cc.

    Returns
    -------
    list of str or None
        The command (``$CC`` may carry flags), or None when none is found.
    """
    env = os.environ.get("CC", "").strip()
    if env:
        cmd = shlex.split(env)
        return cmd if shutil.which(cmd[0]) else None
    for name in ("gcc", "cc"):
        if shutil.which(name):
            return [name]
    return None


def build_library(folder, out=None, compiler: list | None = None,
                  flags: tuple = ("-O2",)) -> Path:
    """Compile an export's C files into a shared library, as its README says.

    Runs ``CC -O2 -shared -fPIC -o OUT FOLDER/*.c -lm``.

    Parameters
    ----------
    folder : str or Path
        The export (its ``*.c`` files: the wrapper and the generated law).
    out : str or Path, optional
        The library (default ``folder/libbiped_controller.so``).
    compiler : list of str, optional
        Default :func:`find_c_compiler`.
    flags : tuple of str
        Optimisation flags.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    CompilerError
        No compiler, or the compilation failed (with the line of its output that says
        why: :func:`~biped_casadi.numerics.compiler_reason`).
    """
    folder = Path(folder)
    cc = compiler if compiler is not None else find_c_compiler()
    if not cc:
        raise CompilerError("no C compiler found (set CC, or install gcc)")
    out = Path(out) if out is not None else folder / LIBRARY
    sources = sorted(str(p) for p in folder.glob("*.c"))
    cmd = [*cc, *flags, "-shared", "-fPIC", "-o", str(out), *sources, "-lm"]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True)
    except OSError as e:
        raise CompilerError(f"{cc[0]}: {e.strerror or e}") from None
    if r.returncode != 0:
        raise CompilerError(f"{cc[0]} failed (exit {r.returncode}): "
                            f"{compiler_reason(r.stderr)}")
    return out


def _load_copy(library: Path):
    """The library loaded from a private copy: a library rebuilt at the same path later
    loads afresh (the dynamic loader keeps one handle per path)."""
    data = library.read_bytes()
    fd, name = tempfile.mkstemp(prefix="biped_controller_", suffix=".so")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        return ctypes.CDLL(name)
    except OSError as e:               # a full temporary folder: say where the copy was
        if e.filename is None and e.errno is not None:
            e.filename = f"{name} (its private copy)"
        raise
    finally:
        os.unlink(name)


class NumericLaw:
    """A control law that is numeric only, with what the simulator needs of it.

    The exported controller's model, reference and gains, ``step_start``, :meth:`torque`
    and :meth:`outputs` with the library's return codes
    (:data:`~biped_casadi.control.export.RETURN_CODES`).

    :class:`~biped_casadi.simulation.Simulator` drives such a law through numeric calls
    (the attribute ``numeric_law``; :mod:`biped_casadi.simulation.compiled_loop`).

    Parameters
    ----------
    exported : TimeVaryingController or VirtualConstraintController
        The exported controller.
    """

    numeric_law = True
    n_ref = 0

    def __init__(self, exported):
        self.exported = exported
        self.model, self.reference = exported.model, exported.reference
        self.gains, self.T = exported.gains, exported.reference.T
        self.nq, self.nu, self.n_par = self.model.nq, self.model.nu, exported.n_par

    def step_start(self, q, dq) -> StepStart:
        """The controller state at the start of a step.

        Parameters
        ----------
        q, dq : array_like
            The state just after an impact (relabelled), rad and rad/s.

        Returns
        -------
        StepStart
            ``p`` the controller state; ``problem`` says why the step cannot start (a
            non-zero return code).
        """
        rc, p = self._start(as_vector(q, self.nq, "q"), as_vector(dq, self.nq, "dq"))
        problem = "" if rc == 0 else (f"the {self.name} law cannot start the step "
                                      f"(return code {rc}: {RETURN_CODES.get(rc, 'unknown')})")
        return StepStart(r=np.zeros(0), p=p, problem=problem)

    def bind(self, q, dq, p):
        """:meth:`torque` bound to the caller's arrays, for a loop calling it every step.

        The caller writes the state into ``q``, ``dq`` and ``p`` before each call (the
        arrays are read at the call, never copied here).  Here the bound call is
        :meth:`torque` itself; :class:`CompiledController` calls its library directly.

        Parameters
        ----------
        q, dq : numpy.ndarray
            (nq,) each, float64, C-contiguous; kept alive by the caller.
        p : numpy.ndarray
            (nstate,) the controller state, float64, C-contiguous.

        Returns
        -------
        callable
            ``call(tau) -> (return code, u)``, as :meth:`torque` at (tau, q, dq, p); ``u``
            may be a buffer the next call overwrites.
        """
        torque = self.torque
        return lambda tau: torque(tau, q, dq, p)

    def singularity(self, n: int = 1001):
        """The law's denominator sampled along the reference step.

        Parameters
        ----------
        n : int
            Samples on [0, T].

        Returns
        -------
        SingularityReport
        """
        n = int(as_number(n, "n", positive=True))
        ref = self.reference
        t = np.linspace(0.0, self.T, n)
        q, dq = ref.q(t), ref.dq(t)
        p = self.step_start(q[:, 0], dq[:, 0]).p
        return singularity_report([self.outputs(float(tk), q[:, k], dq[:, k], p)[3]
                                   for k, tk in enumerate(t)])


class CompiledController(NumericLaw):
    """An exported controller's compiled library as a controller.

    ``step_start`` calls ``biped_step_start``, :meth:`torque` ``biped_torque`` and
    :meth:`outputs` ``biped_outputs``; the simulator drives its closed loop with these
    calls.  One controller at a time per library: the C code's work arrays are static.

    Parameters
    ----------
    library : str or Path
        The shared library built from the export (:func:`build_library`).
    exported : TimeVaryingController or VirtualConstraintController
        The controller that was exported: its model, reference and gains.

    Raises
    ------
    ValueError
        Naming ``library`` when it cannot be loaded or its sizes differ from the
        controller's.
    """

    name = "compiled"
    #: entries of the library's state beyond the exported controller's own
    extra_state = 0

    def __init__(self, library, exported):
        super().__init__(exported)
        self.n_par += self.extra_state
        self.library = Path(library)
        try:
            self._digest = file_digest(self.library)
            self._lib = lib = _load_copy(self.library)
        except OSError as e:
            why = e.strerror or str(e).splitlines()[0]
            where = f"{e.filename}: " if e.filename not in (None, str(self.library)) else ""
            raise ValueError(f"library: cannot load {self.library} ({where}{why})") from None
        for fn, args in (("biped_sizes", [ctypes.c_void_p] * 3),
                         ("biped_step_start", [ctypes.c_void_p] * 3),
                         ("biped_torque", [ctypes.c_double] + [ctypes.c_void_p] * 4),
                         ("biped_outputs", [ctypes.c_double] + [ctypes.c_void_p] * 6)):
            f = getattr(lib, fn)
            f.argtypes, f.restype = args, ctypes.c_int
        sizes = [ctypes.c_int() for _ in range(3)]
        lib.biped_sizes(*(ctypes.byref(s) for s in sizes))
        sizes = tuple(s.value for s in sizes)
        if sizes != (self.nq, self.nu, self.n_par):
            raise ValueError(f"library: {self.library} has sizes (nq, nu, nstate) = {sizes}, "
                             f"the controller {(self.nq, self.nu, self.n_par)}")
        # buffers the C functions read and write in place
        self._q, self._dq = np.zeros(self.nq), np.zeros(self.nq)
        self._p, self._u = np.zeros(max(self.n_par, 1)), np.zeros(self.nu)
        self._y, self._dy, self._den = np.zeros(self.nu), np.zeros(self.nu), np.zeros(1)
        self._ptr = {k: getattr(self, f"_{k}").ctypes.data
                     for k in ("q", "dq", "p", "u", "y", "dy", "den")}

    @property
    def cache_key(self):
        """What the simulator depends on: the library's bytes and the exported controller."""
        return ("compiled", self._digest, self.exported.cache_key)

    def _set(self, q, dq, p=None):
        self._q[:] = q
        self._dq[:] = dq
        if p is not None and self.n_par:
            self._p[:self.n_par] = p

    def _start(self, q, dq):
        self._set(q, dq)
        rc = self._lib.biped_step_start(self._ptr["q"], self._ptr["dq"], self._ptr["p"])
        return rc, self._p[:self.n_par].copy()

    def torque(self, tau, q, dq, p) -> tuple:
        """``biped_torque`` at one state.

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        q, dq : numpy.ndarray
            (nq,) each, rad and rad/s (float arrays; not copied or checked, for speed).
        p : numpy.ndarray
            (nstate,) the controller state.

        Returns
        -------
        tuple
            (return code, torques u (nu,), N m).
        """
        self._set(q, dq, p)
        rc = self._lib.biped_torque(tau, self._ptr["q"], self._ptr["dq"], self._ptr["p"],
                                    self._ptr["u"])
        return rc, self._u.copy()

    def bind(self, q, dq, p):
        """``biped_torque`` on the caller's arrays, its ctypes arguments made once.

        :meth:`torque` without the copies in and out: the library reads ``q``, ``dq``
        and ``p`` where they are and writes the torques into the controller's own
        buffer (the same library call on the same numbers: the same torques, bit for
        bit).

        Parameters
        ----------
        q, dq : numpy.ndarray
            (nq,) each, float64, C-contiguous; kept alive by the caller, who writes the
            state into them before each call.
        p : numpy.ndarray
            (nstate,) the controller state, float64, C-contiguous (when empty, the
            library gets the controller's own buffer, which it does not read).

        Returns
        -------
        callable
            ``call(tau) -> (return code, u)``: ``u`` (nu,) is the controller's buffer,
            overwritten by the next call of this controller.
        """
        for name, a, n in (("q", q, self.nq), ("dq", dq, self.nq), ("p", p, self.n_par)):
            if not (isinstance(a, np.ndarray) and a.dtype == np.float64 and a.size == n
                    and a.flags.c_contiguous):
                raise ValueError(f"{name} must be a C-contiguous float64 array of {n} numbers")
        f, u = self._lib.biped_torque, self._u
        a_q, a_dq, a_u = q.ctypes.data, dq.ctypes.data, self._ptr["u"]
        a_p = p.ctypes.data if p.size else self._ptr["p"]
        return lambda tau: (f(tau, a_q, a_dq, a_p, a_u), u)

    def outputs(self, tau, q, dq, p) -> tuple:
        """``biped_outputs`` at one state.

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        q, dq, p : numpy.ndarray
            As :meth:`torque`.

        Returns
        -------
        tuple
            (return code, y (nu,), dy (nu,), den).
        """
        self._set(q, dq, p)
        rc = self._lib.biped_outputs(tau, self._ptr["q"], self._ptr["dq"], self._ptr["p"],
                                     self._ptr["y"], self._ptr["dy"], self._ptr["den"])
        return rc, self._y.copy(), self._dy.copy(), float(self._den[0])

    def describe(self) -> dict:
        """What defines the controller, as a JSON-ready dict.

        Returns
        -------
        dict
            ``controller`` ('compiled'), ``library``, its ``sha256``, and ``exported``
            (the exported controller's ``describe()``).
        """
        return dict(controller="compiled", library=str(self.library), sha256=self._digest,
                    exported=self.exported.describe())


class PythonTwin(NumericLaw):
    """The Python law called as the compiled library is.

    One state at a time, the reference state read from the reference at tau, the
    library's return codes.

    The law is the controller's own CasADi Function with r = ``reference.state(tau)``
    (for the time-varying law exactly :meth:`TimeVaryingController.torque`); driven by
    the simulator's numeric loop it is the run the compiled library's must repeat to
    round-off.

    Parameters
    ----------
    exported : TimeVaryingController or VirtualConstraintController
        The exported controller.
    law : ExportedLaw, optional
        Its export (the range of tau and the singularity limit); default
        :func:`~biped_casadi.control.export.exported_law` of it.
    """

    name = "python"

    def __init__(self, exported, law=None):
        super().__init__(exported)
        self.law_info = law if law is not None else exported_law(exported)
        self._law = FastCall(exported.law)
        self._start_fn = FastCall(self.law_info.start)
        self._recent: dict = {}

    @property
    def cache_key(self):
        """What the simulator of this law depends on: the exported controller."""
        return ("python-twin", self.exported.cache_key)

    def _start(self, q, dq):
        p, go = self._start_fn(q, dq)
        p = p.ravel()
        if not (np.all(np.isfinite(p))):
            return 3, p
        return (0 if go[0, 0] > 0 else 2), p

    def _state(self, tau):
        """reference.state(tau), the last few kept (a RK4 step asks twice for each)."""
        if not self.exported.n_ref:
            return np.zeros(0)
        r = self._recent.get(tau)
        if r is None:
            if len(self._recent) >= 4:
                self._recent.pop(next(iter(self._recent)))
            r = self._recent[tau] = self.reference.states([tau])[:, 0]
        return r

    def _evaluate(self, tau, q, dq, p):
        li = self.law_info
        if not (0.0 <= tau <= li.tau_max + TAU_SLACK):
            return 2, None
        r = self._state(tau)
        u, y, dy, den, _, inr = self._law(q, dq, tau, r, p)
        den = float(den[0, 0])
        if not inr[0, 0] > 0:
            rc = 2
        elif not (np.isfinite(den) and np.all(np.isfinite(u))):
            rc = 3
        else:
            rc = 0 if den * li.den_sign > li.singular_fraction * li.den_scale else 1
        return rc, (u.ravel(), y.ravel(), dy.ravel(), den)

    def torque(self, tau, q, dq, p) -> tuple:
        """The Python law's torques at one state.

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        q, dq, p : numpy.ndarray
            Configuration, velocity, controller state.

        Returns
        -------
        tuple
            (return code, torques u (nu,), N m; NaN out of range).
        """
        rc, out = self._evaluate(tau, q, dq, p)
        return rc, (np.full(self.nu, np.nan) if out is None else out[0])

    def outputs(self, tau, q, dq, p) -> tuple:
        """The Python law's outputs at one state.

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        q, dq, p : numpy.ndarray
            Configuration, velocity, controller state.

        Returns
        -------
        tuple
            (return code, y (nu,), dy (nu,), den).
        """
        rc, out = self._evaluate(tau, q, dq, p)
        if out is None:
            nan = np.full(self.nu, np.nan)
            return rc, nan, nan, np.nan
        return (rc,) + out[1:]

    def describe(self) -> dict:
        """What defines the law, as a JSON-ready dict.

        Returns
        -------
        dict
            ``controller`` ('python'), ``exported`` (the controller's ``describe()``).
        """
        return dict(controller="python", exported=self.exported.describe())


class UrdfLoop:
    """A law in URDF angles as a controller of the model, the robot's loop around it.

    The class it is mixed into provides the law's calls ``start_urdf``, ``start_leg``,
    ``torque_urdf`` and ``outputs_urdf`` (URDF coordinates in and out).

    At every step start the joint angles are read with one physical leg in stance (the
    two legs in turn), the law finds the stance leg (``biped_step_start``: the foot in
    front), and a step whose stance leg the law takes wrongly cannot start; afterwards
    ``state[0]`` says which leg the angles are read for.
    """

    def _urdf_loop(self, urdf_map, motor_side: bool) -> None:
        self.urdf_map, self.motor_side = urdf_map, bool(motor_side)
        self._to_model = {leg: np.linalg.inv(torque_matrix(urdf_map, leg, motor_side))
                          for leg in LEG_ORDER}
        self._starts = 0

    def _urdf(self, q, dq, leg):
        return self.urdf_map.from_model(q, dq, leg)

    def _start(self, q, dq):
        leg = LEG_ORDER[self._starts % 2]
        self._starts += 1
        rc, p = self.start_urdf(*self._urdf(q, dq, leg))
        if rc == 0 and p[0] != LEG_ORDER.index(leg):
            rc = 2                        # the library would read the angles wrongly
        return rc, p

    def torque(self, tau, q, dq, p) -> tuple:
        """The library's torques as the model's u (the stance leg of ``p[0]``).

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        q, dq : numpy.ndarray
            The model's state.
        p : numpy.ndarray
            The state of :meth:`step_start`.

        Returns
        -------
        tuple
            (return code, u (nu,), N m).
        """
        leg = LEG_ORDER[int(p[0])]
        rc, tau_urdf = self.torque_urdf(tau, *self._urdf(q, dq, leg), p)
        return rc, self._to_model[leg] @ tau_urdf

    def outputs(self, tau, q, dq, p) -> tuple:
        """The library's outputs at the model's state.

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        q, dq, p : numpy.ndarray
            As :meth:`torque`.

        Returns
        -------
        tuple
            (return code, y, dy, den).
        """
        return self.outputs_urdf(tau, *self._urdf(q, dq, LEG_ORDER[int(p[0])]), p)


class CompiledUrdfController(UrdfLoop, CompiledController):
    """An export in URDF angles (``biped export --angles urdf``) as a model's controller.

    The simulator's (q, dq) go to the library as the robot's URDF coordinates, the
    library's torques per URDF joint come back as the model's u.

    The library's own calls are :meth:`start_urdf`, :meth:`start_leg`,
    :meth:`torque_urdf` and :meth:`outputs_urdf` (URDF coordinates in and out).  As a
    controller of the model it plays the robot's loop: at every step start it reads the
    joint angles with one physical leg in stance (the two legs in turn), lets the library
    find the stance leg (``biped_step_start``: the foot in front) and reports a step
    that cannot start when the library takes the other leg; afterwards the state's
    ``state[0]`` says which leg the angles are read for.

    Parameters
    ----------
    library : str or Path
        The shared library built from the export.
    exported : TimeVaryingController or VirtualConstraintController
        The controller that was exported.
    urdf_map : UrdfMap
        The robot's joint map (the export's).
    motor_side : bool
        Whether the export's torques are on the motor side.
    """

    name = "compiled-urdf"
    extra_state = 1

    def __init__(self, library, exported, urdf_map, motor_side: bool = False):
        super().__init__(library, exported)
        lib = self._lib
        try:
            f = lib.biped_step_start_leg
        except AttributeError:
            raise ValueError(f"library: {self.library} is not an export in URDF angles (no "
                             f"biped_step_start_leg)") from None
        f.argtypes, f.restype = [ctypes.c_int] + [ctypes.c_void_p] * 3, ctypes.c_int
        self._urdf_loop(urdf_map, motor_side)

    # ---------------------------------------------------- the library's own calls
    def start_urdf(self, x, dx) -> tuple:
        """``biped_step_start``: the library finds the stance leg.

        Parameters
        ----------
        x, dx : numpy.ndarray
            Pitch and URDF joint angles, and rates.

        Returns
        -------
        tuple
            (return code, state: ``state[0]`` the stance leg 0 or 1).
        """
        return CompiledController._start(self, x, dx)

    def start_leg(self, stance: int, x, dx) -> tuple:
        """``biped_step_start_leg``: the stance leg given (0 or 1).

        Parameters
        ----------
        stance : int
            0 for the map's leg 1, 1 for leg 2.
        x, dx : numpy.ndarray
            Pitch and URDF joint angles, and rates.

        Returns
        -------
        tuple
            (return code, state).
        """
        self._set(x, dx)
        rc = self._lib.biped_step_start_leg(int(stance), self._ptr["q"], self._ptr["dq"],
                                            self._ptr["p"])
        return rc, self._p[:self.n_par].copy()

    def torque_urdf(self, tau, x, dx, state) -> tuple:
        """``biped_torque`` in URDF coordinates: (return code, torque per URDF joint).

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        x, dx, state : numpy.ndarray
            Pitch and URDF joint angles, rates, the state of a step start.

        Returns
        -------
        tuple
        """
        return CompiledController.torque(self, tau, x, dx, state)

    def outputs_urdf(self, tau, x, dx, state) -> tuple:
        """``biped_outputs`` in URDF coordinates: (return code, y, dy, den).

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        x, dx, state : numpy.ndarray
            As :meth:`torque_urdf`.

        Returns
        -------
        tuple
        """
        return CompiledController.outputs(self, tau, x, dx, state)
