"""What ``biped view`` computes for the page, without the page: the settings of a view,
and for a design (controller and M1) its exact eigenvalues, its full-order walk, the
``biped simulate`` command that replays that walk, and its section basin when one is
kept in the cache.

The walk is :func:`biped_casadi.simulate` of the design's controller from the same start
and with the same options as ``biped simulate`` (:class:`ViewSettings`), so the outcome
shown is the one that command prints.  The eigenvalues are
:func:`analysis.stability.poincare_eigenvalues` (virtual constraints:
:func:`analysis.stability.vc_eigenvalue`), written as ``biped eig`` writes them
(:mod:`analysis.reporting.text`).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import Design, Gains, Perturbation, SimulationOptions, simulate
from biped_casadi.caching import digest
from biped_casadi.control import check_M1
from biped_casadi.control.output_law import check_rejoin
from biped_casadi.control.reference import require_reference

from ..pipeline.walking import BASIN_REFINE
from ..reporting.text import eigenvalues_text, number_text, walk_text
from ..robustness import basin_to_boundary
from ..stability import poincare_eigenvalues, vc_eigenvalue
from ..tasks import ResultStore, task_key
from .poses import WalkPoses, walk_poses
from .space import SliderSpace, slider_space

__all__ = ["ViewSettings", "Explorer", "Walk", "VIEW_PERTURBATION", "BASIN_SIZES"]

#: the default start of the walks: a tenth of the paper's perturbation on every joint
#: (rad, rad/s); from the paper's own, most designs slip at the first impact in full
#: order with the friction cone checked
VIEW_PERTURBATION = (0.001, 0.01)
#: why a singular design is not walked (``biped simulate`` refuses it)
SINGULAR = ("the controller is singular on the reference step (D11 - D12 M1 vanishes, "
            "eq. 24)")
#: the basins the reproduction keeps (cells per axis of the full and the quick run, on
#: its adaptive grid: ``analysis.pipeline.walking``)
BASIN_SIZES = (101, 41)


@dataclass(frozen=True)
class ViewSettings:
    """What a view shows and how its walks are run (the options of ``biped simulate``).

    Parameters
    ----------
    gait : Reference
        The gait (it carries its robot).
    controller : str
        'tv' or 'vc': the controller shown first.
    M1 : tuple of float or None
        The time-varying design shown first; None: chosen by
        :func:`analysis.view.space.slider_space`.
    rejoin : float
        When v_c rejoins the reference, fraction of T.
    gains : Gains
        (Kp, Kd, eps) of eq. (13).
    perturbation : Perturbation or None
        The start of every walk, added to the reference's; None:
        :data:`VIEW_PERTURBATION` on every joint.
    options : SimulationOptions
        Steps and validity limits of the walks.
    replay : tuple of str
        The ``biped simulate`` options that name the same gait and robot (``--gait``,
        ``--robot``), for the replay line.
    """

    gait: object
    controller: str = "tv"
    M1: tuple | None = None
    rejoin: float = 0.5
    gains: Gains = field(default_factory=Gains)
    perturbation: Perturbation | None = None
    options: SimulationOptions = field(default_factory=SimulationOptions)
    replay: tuple = ()

    def __post_init__(self):
        nu = require_reference(self.gait).model.nu
        if self.controller not in ("tv", "vc"):
            raise ValueError(f"controller must be 'tv' or 'vc', got {self.controller!r}")
        if self.M1 is not None:
            object.__setattr__(self, "M1", tuple(check_M1(self.M1, nu).tolist()))
        object.__setattr__(self, "rejoin", check_rejoin(self.rejoin))
        for name, kind in (("gains", Gains), ("options", SimulationOptions)):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__}, got "
                                 f"{type(getattr(self, name)).__name__}")
        if self.perturbation is not None and not isinstance(self.perturbation, Perturbation):
            raise ValueError(f"perturbation must be a Perturbation or None, got "
                             f"{type(self.perturbation).__name__}")

    @property
    def start(self) -> Perturbation:
        """The perturbation every walk starts from."""
        if self.perturbation is not None:
            return self.perturbation
        return Perturbation.uniform(self.gait.model.nq, *VIEW_PERTURBATION)


@dataclass
class Walk:
    """One walk shown on the page.

    Parameters
    ----------
    controller : str
        'tv' or 'vc'.
    M1 : tuple or None
        The time-varying design walked (None for virtual constraints).
    result : SimulationResult or None
        The run (None: not walked, the controller is singular).
    text : str
        Its outcome and the design, for the ``walk`` box.
    poses : WalkPoses or None
        The robot in 3-D at every logged instant.
    """

    controller: str
    M1: tuple | None
    result: object
    text: str
    poses: WalkPoses


class Explorer:
    """The computations behind a view, callable from several threads.

    Parameters
    ----------
    settings : ViewSettings
        The view.
    cache : bool
        Keep and read the sliders' start and reach in the cache folder.
    """

    def __init__(self, settings: ViewSettings, cache: bool = True):
        self.settings = settings
        self.gait = settings.gait
        self.model = settings.gait.model
        self._eig_lock = threading.Lock()
        self._walk_lock = threading.Lock()
        #: the cells per axis of the basins the page looks for in the cache
        self.basin_sizes = BASIN_SIZES
        self.space: SliderSpace = slider_space(
            self.gait, settings.M1, settings.rejoin, walks_ok=self._walks_ok,
            walk_key=self._walk_key(), cache=cache)

    # ------------------------------------------------------------ designs
    def design(self, controller: str, M1=None) -> Design:
        """The design of ``controller`` ('tv' with ``M1``, or 'vc') on the view's gait.

        Parameters
        ----------
        controller : str
            'tv' or 'vc'.
        M1 : array_like, optional
            The outputs (time-varying only).

        Returns
        -------
        Design
        """
        s = self.settings
        if controller == "vc":
            return Design.vc(self.gait, s.gains)
        return Design.tv(self.gait, [float(v) for v in M1], s.rejoin, s.gains)

    def readout(self, controller: str, M1=None) -> str:
        """The ``max|lambda|`` box, with the digits of ``biped eig``.

        max|lambda|, the status, the eigenvalues and the design, one line each.

        Parameters
        ----------
        controller : str
            'tv' or 'vc'.
        M1 : array_like, optional
            The outputs (time-varying only).

        Returns
        -------
        str
        """
        with self._eig_lock:
            if controller == "vc":
                r = vc_eigenvalue(self.gait)
                return (f"{number_text(r.eigenvalue)}   status: {r.status}\n"
                        f"eigenvalue of the 1-D map: {number_text(r.eigenvalue)}\n"
                        "virtual constraints")
            M1 = [float(v) for v in M1]
            r = poincare_eigenvalues(self.gait, M1, rejoin=self.settings.rejoin)
        if not r.success:
            return f"{number_text(r.max_abs)}   status: {r.status}\n{r.message}\nM1 = {M1}"
        return (f"{number_text(r.max_abs)}   status: {r.status}\n"
                f"eigenvalues: {eigenvalues_text(r.eigenvalues)}\nM1 = {M1}")

    # ------------------------------------------------------------ walks
    def run(self, controller: str, M1=None):
        """The full-order walk of a design, as ``biped simulate`` runs it.

        Parameters
        ----------
        controller : str
            'tv' or 'vc'.
        M1 : array_like, optional
            The outputs (time-varying only).

        Returns
        -------
        SimulationResult
        """
        ctrl = self.design(controller, M1).controller_for()
        q0, dq0 = self.settings.start.initial_state(self.gait)
        with self._walk_lock:
            return simulate(ctrl, q0, dq0, self.settings.options)

    def walk(self, controller: str, M1=None) -> Walk:
        """The walk of a design with its text and its poses.

        Parameters
        ----------
        controller : str
            'tv' or 'vc'.
        M1 : array_like, optional
            The outputs (time-varying only).

        Returns
        -------
        Walk
        """
        M1 = None if controller == "vc" else tuple(float(v) for v in M1)
        design = "virtual constraints" if M1 is None else f"M1 = {list(M1)}"
        if M1 is not None and self.design("tv", M1).controller_for().singularity().singular:
            return Walk(controller, M1, None, f"not walked: {SINGULAR}\n{design}", None)
        res = self.run(controller, M1)
        p = self.settings.start
        text = (f"{walk_text(res)}\n{design}; {res.n_steps} steps from the reference "
                f"perturbed by {_errors(p)}")
        return Walk(controller, M1, res, text, walk_poses(res, self.model))

    def replay(self, controller: str, M1=None) -> str:
        """The ``biped simulate`` command whose run is the walk of this design.

        Parameters
        ----------
        controller : str
            'tv' or 'vc'.
        M1 : array_like, optional
            The outputs (time-varying only).

        Returns
        -------
        str
        """
        s, o = self.settings, self.settings.options
        args = ["biped", "simulate", *s.replay, "--controller", controller]
        if controller == "tv":
            args += ["--m1", *(repr(float(v)) for v in M1)]
            if s.rejoin != 0.5:
                args += ["--rejoin", repr(s.rejoin)]
        args += _perturbation_args(s.start) + ["--steps", str(o.steps)]
        if o.mu is not None:
            args += ["--mu", repr(o.mu)]
        if o.torque_limit is not None:
            args += ["--torque-limit", repr(o.torque_limit)]
        if s.gains.eps != Gains().eps:
            args += ["--eps", repr(s.gains.eps)]
        return " ".join(args)

    def _walks_ok(self, M1) -> bool:
        return self.run("tv", M1).status == "ok"

    def _walk_key(self):
        s = self.settings
        return digest(dict(start=s.start.to_dict(), options=repr(s.options),
                           gains=s.gains.to_dict()))

    # ------------------------------------------------------------ basins
    def basin(self, controller: str, M1=None, store: ResultStore | None = None,
              sizes: tuple | None = None):
        """The section basin of a design, if the cache keeps one.

        Looks for the basins the reproduction computes
        (:func:`analysis.robustness.basin_to_boundary` on ``sizes`` cells per axis, refined
        as the reproduction refines them), by their task keys; nothing is computed.

        Parameters
        ----------
        controller : str
            'tv' or 'vc'.
        M1 : array_like, optional
            The outputs (time-varying only).
        store : ResultStore, optional
            Where results are kept (default: the cache folder's).
        sizes : tuple of int, optional
            The cells per axis of the basins looked for (default :attr:`basin_sizes`).

        Returns
        -------
        BasinResult or None
        """
        store = store or ResultStore()
        d = self.design(controller, M1)
        info = basin_to_boundary.task_info
        for n in sizes or self.basin_sizes:
            key = task_key(info.name, info.version, info.code, (d, n),
                           dict(refine=BASIN_REFINE))
            rec = store.read(key)
            if isinstance(rec, dict):
                return rec["value"]
        return None


def _errors(p: Perturbation) -> str:
    q, dq = np.array(p.q), np.array(p.dq)
    if np.all(q == q[0]) and np.all(dq == dq[0]):
        return f"{q[0]:g} rad and {dq[0]:g} rad/s on every joint"
    return f"q + {q.tolist()} rad, dq + {dq.tolist()} rad/s"


def _perturbation_args(p: Perturbation) -> list:
    q, dq = np.array(p.q), np.array(p.dq)
    if np.all(q == q[0]) and np.all(dq == dq[0]):
        return ["--perturb", repr(float(q[0])), repr(float(dq[0]))]
    return (["--perturb-q", *(repr(float(v)) for v in q)]
            + ["--perturb-dq", *(repr(float(v)) for v in dq)])
