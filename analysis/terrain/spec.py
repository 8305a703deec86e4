"""What a Monte Carlo walks (the controller, its design or gains, the plant, the engine)
and how (runs, steps, terrain, thresholds)."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from biped_casadi import (Gains, SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, robot)
from biped_casadi.model.description import description_from_dict
from biped_casadi.option_checks import FieldChecks
from biped_casadi.simulation import (Terrain, random_heights)
from gait_opt import leg_scale


__all__ = ["WalkerSpec", "MonteCarloSettings", "MAX_RUNS", "MAX_STEPS", "MAX_FULL_RK4_STEPS"]

#: the default standard deviation of the ground heights on RABBIT's legs (0.8 m), m;
#: scaled with the robot's leg length (:meth:`MonteCarloSettings.for_model`)
SIGMA = 0.005

#: the largest number of runs and of steps per run a Monte Carlo accepts
MAX_RUNS = 1_000_000
MAX_STEPS = 100_000

#: the most RK4 steps per T the full-order runs take to keep stiff output gains stable
#: (eps >= 1.4e-5 s with Kp = 1, Kd = 2; about a second of computing per step)
MAX_FULL_RK4_STEPS = 100_000


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

    @classmethod
    def of(cls, design, plant=None, saturate: bool = False) -> "WalkerSpec":
        """What walks, from a :class:`~biped_casadi.Design`.

        Parameters
        ----------
        design : Design
            The controller (its gait is not part of the spec).
        plant : dict, optional
            The plant's robot description when it differs from the model.
        saturate : bool
            Clip torques at the limit.

        Returns
        -------
        WalkerSpec
        """
        g = design.gains
        return cls(design.controller, () if design.M1 is None else tuple(design.M1),
                   design.rejoin, (g.Kp, g.Kd, g.eps), plant, saturate)

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
            return TimeVaryingController(gait, np.array(self.M1), g, self.rejoin)
        return VirtualConstraintController(gait, gains=g)

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
    sigma : float or None
        Standard deviation of the ground heights, m (>= 0); None (the default): 5 mm on
        RABBIT, scaled with the robot's leg length (0.00625 x leg), filled in by
        :meth:`for_model` (``monte_carlo`` does) and recorded in :meth:`to_dict`.
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
        gains need a finer step: Gains.check_step); 200 gives the verdicts of 2000 on every
        run compared (``benchmarks/bench_terrain.py``, README).
    transient : int
        Steps left out at the start of every run for the step-time RMS.
    profile : tuple of float
        A measured terrain instead of random heights (sigma then 0): run i walks the
        profile from its i-th height on, cyclically, m.
    compiled : bool
        Compile the full-order simulator to machine code (about 4 s once per controller
        and plant, kept in the cache folder; then about ten times faster than CasADi's
        virtual machine).  False pays off for a few short runs.  The results are the
        same either way, so it is not part of :meth:`to_dict` (nor of the stored runs'
        keys).
    """

    sigma: float | None = None
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
    compiled: bool = True

    def __post_init__(self):
        c = FieldChecks(self, "{}", flag="True or False", at_most=None,
                        integer="an integer between {low} and {high}")
        c.numbers(("sigma",), strict=False, none=True, phrase="a finite number >= 0 (m)")
        for name, hi in (("runs", MAX_RUNS), ("max_steps", MAX_STEPS), ("chunk", MAX_RUNS)):
            c.integers((name,), 1, hi, kinds=(int, np.integer))
        c.integers(("seed",), 0, phrase="a non-negative integer", kinds=(int, np.integer))
        SimulationOptions(mu=self.mu, torque_limit=self.torque_limit,
                          rk4_steps=self.full_rk4_steps)          # checked there
        v = self.rk4_steps
        if isinstance(v, bool) or not isinstance(v, int) or v < 8 or v % 8:
            raise ValueError(f"rk4_steps must be a positive multiple of 8, got {v!r}")
        c.integers(("vc_nodes",), 8, phrase="an integer >= 8")
        c.integers(("transient",), 0, phrase="a non-negative integer")
        c.flags(("compiled",))
        object.__setattr__(self, "profile", Terrain(tuple(self.profile)).heights)
        if self.profile and self.sigma:
            raise ValueError("sigma and profile exclude each other (a profile is the terrain)")

    def for_model(self, model) -> "MonteCarloSettings":
        """These settings with the default ``sigma`` filled in for the robot.

        5 mm scaled with its leg length (:func:`gait_opt.leg_scale`; RABBIT exactly
        0.005 m), 0 with a terrain profile.

        Parameters
        ----------
        model : BipedModel
            The robot that walks (the gait's).

        Returns
        -------
        MonteCarloSettings
        """
        if self.sigma is not None:
            return self
        return replace(self, sigma=0.0 if self.profile else SIGMA * leg_scale(model))

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
            The reference's step duration, s: the RK4 steps per T are raised until the
            gains' output dynamics are integrated stably
            (:meth:`biped_casadi.Gains.check_step`; eps >= 2 T / rk4_steps for Kp = 1,
            Kd = 2).

        Returns
        -------
        SimulationOptions

        Raises
        ------
        ValueError
            When the runs go through the full-order simulator and the gains would need
            more than :data:`MAX_FULL_RK4_STEPS` RK4 steps per T.
        """
        rk = self.full_rk4_steps
        if T is not None:
            g = Gains(*spec.gains)
            need = T / g.max_step                 # RK4 steps per T the gains need
            if need > MAX_FULL_RK4_STEPS and spec.engine == "full_order":
                raise ValueError(
                    f"gains: (Kp, Kd, eps) = ({g.Kp:g}, {g.Kd:g}, {g.eps:g}) make the closed "
                    f"loop too stiff: the full-order simulator would need {need:.3g} RK4 steps "
                    f"per step (at most {MAX_FULL_RK4_STEPS}) not to diverge; lower Kp or Kd, "
                    f"or raise eps")
            rk = max(rk, 8 * int(math.ceil(need / 8 - 1e-9)))
        return SimulationOptions(steps=self.max_steps, mu=self.mu,
                                 torque_limit=self.torque_limit, saturate=spec.saturate,
                                 rk4_steps=rk, jit=bool(self.compiled))

    def to_dict(self) -> dict:
        """The fields by name (all but ``compiled``, which does not change a result).

        Returns
        -------
        dict
        """
        d = asdict(self)
        d.pop("compiled")
        return d


