"""An exported running controller (:mod:`biped_casadi.control.export_running`) compiled and
called through ctypes: :class:`CompiledRunningLaw`, the library's
``biped_running_torque`` with the calls the MuJoCo loop makes of the Python law
(:class:`~biped_casadi.mujoco.running.RunningLoop`, its ``compiled`` argument)."""
from __future__ import annotations

import ctypes
import json
from pathlib import Path

import numpy as np

from .compiled import _load_copy, build_library
from .export_folder import file_digest
from .export_running import (PHASES, RUNNING_INFO, RUNNING_LIBRARY, exported_running_law,
                             running_info)
from .running import RunningController

__all__ = ["CompiledRunningLaw", "check_running_export"]


def check_running_export(folder, controller: RunningController) -> dict:
    """The export in ``folder`` checked to be of ``controller``.

    Its :data:`~biped_casadi.control.export_running.RUNNING_INFO` must name the same
    robot, gait (digest), law, gains, saturation and torque limit.

    Parameters
    ----------
    folder : str or Path
        A folder written by :func:`~biped_casadi.control.export_running.running_c_sources`.
    controller : RunningController
        The controller it should hold.

    Returns
    -------
    dict
        The export's information.

    Raises
    ------
    ValueError
        Naming the folder and the first thing that differs (or the missing file).
    """
    path = Path(folder) / RUNNING_INFO
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        why = e.strerror if isinstance(e, OSError) else "not JSON"
        raise ValueError(f"{folder}: not a running export ({path.name}: {why})") from None
    want = running_info(exported_running_law(controller))
    if not isinstance(info, dict) or info.get("kind") != "running":
        raise ValueError(f"{folder}: not a running export ({path.name} is not of one)")
    for key in ("robot", "gait_digest", "nq", "nu", "nqe"):
        if info.get(key) != want[key]:
            what = "gait" if key == "gait_digest" else key
            raise ValueError(f"{folder}: the export is of another {what} ({key} "
                             f"{info.get(key)!r}, this run's {want[key]!r})")
    have = info.get("controller") if isinstance(info.get("controller"), dict) else {}
    for key, v in want["controller"].items():
        got = have.get(key)
        if got != v:
            raise ValueError(f"{folder}: the export's {key} is {got!r}, this run's {v!r}")
    return info


class CompiledRunningLaw:
    """A running export's library through ctypes.

    :meth:`torque` is ``biped_running_torque``; :meth:`stance` and :meth:`flight` are the
    same calls in the form of the controller's CasADi Functions ``stance_law`` and
    ``flight_law`` called through :class:`~biped_casadi.numerics.FastCall` (a list with
    the torques as an (nu, 1) array), so the MuJoCo loop takes either.  One law at a time
    per library: the C code's work arrays are static.

    Parameters
    ----------
    library : str or Path
        The shared library built from the export (:meth:`build`).
    nq, nu, nqe : int, optional
        Sizes the library must have (checked when given).

    Raises
    ------
    ValueError
        Naming ``library`` when it cannot be loaded, is not a running export's, or its
        sizes differ.
    """

    def __init__(self, library, nq: int | None = None, nu: int | None = None,
                 nqe: int | None = None):
        self.library = Path(library)
        #: the export the library was built from (set by :meth:`build`)
        self.export = None
        try:
            self.sha256 = file_digest(self.library)
            lib = self._lib = _load_copy(self.library)
            f, s = lib.biped_running_torque, lib.biped_running_sizes
        except OSError as e:
            why = e.strerror or str(e).splitlines()[0]
            raise ValueError(f"library: cannot load {self.library} ({why})") from None
        except AttributeError:
            raise ValueError(f"library: {self.library} is not a running export's (no "
                             "biped_running_torque)") from None
        f.argtypes = [ctypes.c_int, ctypes.c_double] + [ctypes.c_void_p] * 3
        f.restype = s.restype = ctypes.c_int
        s.argtypes = [ctypes.c_void_p] * 3
        sizes = [ctypes.c_int() for _ in range(3)]
        s(*(ctypes.byref(v) for v in sizes))
        self.nq, self.nu, self.nqe = (v.value for v in sizes)
        want = (nq, nu, nqe)
        if any(w is not None and w != g for w, g in zip(want, (self.nq, self.nu, self.nqe))):
            raise ValueError(f"library: {self.library} has sizes (nq, nu, nqe) = "
                             f"{(self.nq, self.nu, self.nqe)}, expected {want}")
        self._f = f
        self._q, self._dq = np.zeros(self.nqe), np.zeros(self.nqe)
        self._u = np.zeros(self.nu)
        self._ptr = (self._q.ctypes.data, self._dq.ctypes.data, self._u.ctypes.data)

    @classmethod
    def build(cls, folder, controller: RunningController, out=None, compiler=None,
              flags: tuple = ("-O2",)) -> "CompiledRunningLaw":
        """Check an export against a controller, compile it and load it.

        Parameters
        ----------
        folder : str or Path
            The export (:func:`check_running_export`).
        controller : RunningController
            The controller it must hold.
        out : str or Path, optional
            The library (default ``folder/libbiped_running.so``).
        compiler : list of str, optional
            Default :func:`~biped_casadi.control.compiled.find_c_compiler`.
        flags : tuple of str
            Optimisation flags.

        Returns
        -------
        CompiledRunningLaw

        Raises
        ------
        ValueError
            The export is of another controller.
        CompilerError
            No compiler, or the compilation failed.
        """
        check_running_export(folder, controller)
        lib = build_library(folder, Path(folder) / RUNNING_LIBRARY if out is None else out,
                            compiler, flags)
        m = controller.model
        law = cls(lib, m.nq, m.nu, controller.fl.ne)
        law.export = str(folder)
        return law

    def torque(self, phase: int, t: float, q, dq) -> tuple:
        """``biped_running_torque`` at one state.

        Parameters
        ----------
        phase : int
            0 stance (q, dq of nq each), 1 flight (qe, dqe of nqe each).
        t : float
            Time since the phase began, s.
        q, dq : array_like
            The phase's coordinates and rates.

        Returns
        -------
        tuple
            (return code, torques u (nu,), N m).
        """
        n = self.nq if phase == 0 else (self.nqe if phase == 1 else 0)   # 0: not read
        self._q[:n] = np.asarray(q, float).ravel()[:n]
        self._dq[:n] = np.asarray(dq, float).ravel()[:n]
        rc = self._f(int(phase), float(t), *self._ptr)
        return rc, self._u.copy()

    def stance(self, q, dq, t) -> list:
        """The stance torques as ``FastCall(controller.stance_law)(q, dq, t)`` gives them.

        Parameters
        ----------
        q, dq : numpy.ndarray
            (nq,) each.
        t : float
            Time since the landing, s.

        Returns
        -------
        list
            ``[u]``, u an (nu, 1) array (NaN when the library returns non-zero).
        """
        self._q[:self.nq] = q
        self._dq[:self.nq] = dq
        self._f(0, t, *self._ptr)
        return [self._u.reshape(-1, 1).copy()]

    def flight(self, qe, dqe, t) -> list:
        """The flight torques as ``FastCall(controller.flight_law)(qe, dqe, t)``.

        Parameters
        ----------
        qe, dqe : numpy.ndarray
            (nqe,) each.
        t : float
            Time since the takeoff, s.

        Returns
        -------
        list
            ``[u]``, u an (nu, 1) array.
        """
        self._q[:] = qe
        self._dq[:] = dqe
        self._f(1, t, *self._ptr)
        return [self._u.reshape(-1, 1).copy()]

    def describe(self) -> dict:
        """The library, for a run's record.

        Returns
        -------
        dict
            ``library`` and its ``sha256``, ``export`` (the folder it was built from, or
            None), ``phases``.
        """
        return dict(library=str(self.library), sha256=self.sha256, export=self.export,
                    phases=list(PHASES))
