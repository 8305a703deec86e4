"""Options of the reference-gait problem (docs: theory §2 defaults)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from biped_casadi.option_checks import FieldChecks

__all__ = ["GaitOptions", "REFERENCE_LEG_LENGTH", "REFERENCE_SPEED", "leg_scale",
           "reference_speed", "default_step_length_bounds", "guess_step_length", "LegScaled",
           "gait_fields", "SMOOTH_CONTINUATION_MAX"]

#: hip-to-foot length of a straight leg, m, of the robot the length-valued defaults were
#: set on (RABBIT); on another robot they scale with its leg length over this one
REFERENCE_LEG_LENGTH = 0.8
#: length-valued gait defaults on RABBIT's legs, m (scaled by :func:`leg_scale`)
STEP_LENGTH_BOUNDS = (0.2, 0.8)
CLEARANCE = 0.03
#: RABBIT's default speed, m/s, the speed the step-length defaults were set at: on another
#: robot the speed of the same Froude number v^2 / (g leg) (:func:`reference_speed`)
REFERENCE_SPEED = 0.75
#: the built-in guess's step length at :data:`REFERENCE_SPEED` on RABBIT's legs, m
#: (scaled by :func:`leg_scale`; at other speeds times sqrt(speed / reference speed))
GUESS_STEP_LENGTH = 0.45


def leg_scale(model) -> float:
    """The factor on the length-valued defaults: the robot's leg length over RABBIT's.

    RABBIT's is :data:`REFERENCE_LEG_LENGTH`.

    Parameters
    ----------
    model : BipedModel or RobotDescription
        The robot (a model, or its description).

    Returns
    -------
    float
        ``leg_length / 0.8``; exactly 1.0 for RABBIT (its legs are 0.4 + 0.4 m), so that
        its scaled defaults equal the constants bit for bit.
    """
    d = getattr(model, "description", model)
    return float(d.leg_length) / REFERENCE_LEG_LENGTH


def reference_speed(model) -> float:
    """RABBIT's default speed carried to the robot at the same Froude number.

    Geometrically similar walkers at equal v^2 / (g leg) take equal steps relative to
    their legs; the step-length defaults were set on RABBIT at 0.75 m/s.

    Parameters
    ----------
    model : BipedModel or RobotDescription
        The robot (a model, or its description).

    Returns
    -------
    float
        ``0.75 * sqrt(leg_scale * g / 9.81)`` m/s; exactly 0.75 for RABBIT.
    """
    d = getattr(model, "description", model)
    return REFERENCE_SPEED * math.sqrt(leg_scale(model) * (float(d.gravity) / 9.81))


def default_step_length_bounds(model, speed: float) -> tuple:
    """The default ``step_length_bounds`` for the robot at ``speed``, m.

    (0.25, 1.0) leg lengths (RABBIT: (0.2, 0.8) m) at and above :func:`reference_speed`;
    below it the lower bound shrinks in proportion to the speed (a bound on the step
    time, 0.25 leg / reference speed, no longer on the length): the factor 0.25 was
    set on RABBIT's speeds, where its optimal steps are longer, and a slow walker's
    optimal step can be shorter (the three-link biped at 0.3 m/s: 0.19 leg lengths).

    Parameters
    ----------
    model : BipedModel or RobotDescription
        The robot.
    speed : float
        The gait's average speed, m/s.

    Returns
    -------
    tuple of float
        (low, high); RABBIT at 0.75 m/s and faster exactly (0.2, 0.8).
    """
    lo, hi = LegScaled(step_length_bounds=STEP_LENGTH_BOUNDS).for_model(model)[
        "step_length_bounds"]
    slow = min(1.0, float(speed) / reference_speed(model))
    return (lo * slow, hi)


def guess_step_length(model, speed: float) -> float:
    """The step length of the built-in initial guess, before it is clipped to the bounds.

    :data:`GUESS_STEP_LENGTH` x :func:`leg_scale` x sqrt(speed / reference speed), m
    (RABBIT: 0.45 sqrt(speed / 0.75) m).

    Parameters
    ----------
    model : BipedModel or RobotDescription
        The robot.
    speed : float
        The gait's average speed, m/s.

    Returns
    -------
    float
    """
    return GUESS_STEP_LENGTH * leg_scale(model) * math.sqrt(float(speed) / reference_speed(model))


def _per_torque(values) -> tuple:
    """Per-torque bounds as a tuple of floats, each a positive finite number."""
    if not values or any(isinstance(v, bool) or not isinstance(v, (int, float))
                         or not math.isfinite(v) or not v > 0 for v in values):
        raise ValueError(f"gait option 'torque_limit' must be a positive number, None, or "
                         f"one positive finite number per torque, got {list(values)!r}")
    return tuple(float(v) for v in values)


class LegScaled(dict):
    """GaitOptions fields given for RABBIT's legs, their lengths scaled to a robot's.

    :meth:`for_model` scales the length-valued ones (``step_length_bounds``,
    ``clearance``) with the robot's leg length (:func:`leg_scale`).  A plain dict of
    fields is taken as it is (a user's explicit values)."""

    def for_model(self, model) -> dict:
        """The fields for ``model``.

        Parameters
        ----------
        model : BipedModel or RobotDescription
            The robot.

        Returns
        -------
        dict
            A plain dict, the lengths scaled by :func:`leg_scale`.
        """
        k = leg_scale(model)
        out = dict(self)
        if "clearance" in out:
            out["clearance"] = out["clearance"] * k
        if "step_length_bounds" in out:
            out["step_length_bounds"] = tuple(v * k for v in out["step_length_bounds"])
        return out


def gait_fields(fields: dict, model) -> dict:
    """GaitOptions fields for ``model``.

    Parameters
    ----------
    fields : dict
        A :class:`LegScaled` mapping (scaled to the robot's legs) or any other mapping
        (taken as given).
    model : BipedModel or RobotDescription
        The robot.

    Returns
    -------
    dict
    """
    return fields.for_model(model) if isinstance(fields, LegScaled) else dict(fields)


def require_model(model):
    """``model`` checked to be a robot model: a TypeError naming ``model`` otherwise (a
    robot's name, a path, a gait)."""
    if not hasattr(model, "description") or not hasattr(model, "params"):
        raise TypeError(f"model: a robot model is needed (biped_casadi.rabbit() or "
                        f"biped_casadi.robot(NAME_OR_PATH)), got {type(model).__name__} "
                        f"{model!r:.60}")
    return model

COSTS = ("torque_squared_per_length", "torque_squared")
SCHEMES = ("legendre", "radau")
DERIVATIVES = ("structured", "casadi")
CONTINUATIONS = ("ramp", "smooth")
#: the longest decay time of the 'smooth' continuation, in T: its closed form cancels
#: terms of order (c T)^3, so that its round-off grows as c^3 (T 0.69 s, unit acceleration
#: and jerk at T: 1e-12 rad at c = 10, 1e-9 at 100, 1e-3 at 1e4; inf and nan from about
#: 1e100), and past a few T the acceleration barely decays within a step anyway
SMOOTH_CONTINUATION_MAX = 10.0
#: collocation points per interval: CasADi's collocation schemes stop at 9
MAX_DEGREE = 9
#: collocation intervals: 2000 already take about 1 GB and 15 s per IPOPT iteration, and a
#: number read from a file without a bound exhausts the memory
MAX_N_INTERVALS = 5000
#: what ``torso_lean_max`` must be (a lean is an angle in [-pi, pi))
LEAN_PHRASE = "None or a number of rad between 0 and pi (both excluded)"


@dataclass(frozen=True)
class GaitOptions:
    """Everything that defines the reference-gait problem (docs: theory §2); all have defaults.

    Parameters
    ----------
    speed : float
        Average forward speed (step length / T), m/s.
    step_length_bounds : tuple of float or None
        (low, high) bounds on the step length chosen by the optimiser, m; None (the
        default): (0.25, 1.0) x the robot's leg length (RABBIT: (0.2, 0.8)), the lower
        bound shrinking in proportion to the speed below 0.75 m/s x sqrt(leg / 0.8 m)
        (:func:`default_step_length_bounds`), filled in by :meth:`for_model` at
        ``speed`` and recorded in the gait's options.
    step_time_bounds : tuple of float
        (low, high) bounds on the step duration T, s.
    mu : float
        Friction coefficient for the stance foot and the impact impulse.
    impact_mu : float or None
        A separate (design) bound on the impact impulse ratio ``|F_x| / F_z``, or None
        for ``mu``: a gait whose nominal impulse sits well inside the cone leaves room
        for the impact to move under perturbations.
    torque_limit : float, tuple of float or None
        Bound on every ``|u_i|``, N m, or one bound per torque (nu numbers, u1 .. u_nu);
        None (the default): the robot's own (its description's ``torque_bound``: RABBIT's
        150 N m, the joints' limits for a robot whose joints' limits differ), filled in by
        :meth:`for_model` when a gait is solved; inf for a robot without one (recorded
        with imported gaits; solving a gait needs a finite bound).
    min_normal_force : float
        Lower bound of the stance normal force, N.
    clearance : float or None
        None (the default): 0.0375 x the robot's leg length (RABBIT: 0.03 m), filled in
        by :meth:`for_model`.  Swing-foot height bound inside the step, m:
        z_sw >= clearance * 4 s (1 - s) with s = t / T (a parabola: 0 at both ends, ``clearance`` mid-step).  Legs
        without knees (``model.scuffing_ignored``): z_sw >= clearance * 4 s (1 - s) *
        (x_sw - scuff_zone) / leg length, above the ground beyond the model's scuff
        zone in front of the stance foot, grazing at most that deep nearer.
    min_liftoff_speed, min_strike_speed : float
        The swing foot leaves the ground upward after the impact and strikes it
        downward with at least these vertical speeds, m/s.
    torso_lean_max : float or None
        Bound on the torso's lean from upright (``model.torso_angle`` less the robot's
        ``torso_upright``), rad, 0 < torso_lean_max < pi, imposed at every interval
        boundary and collocation point as the running problem's
        (:attr:`gait_opt.RunningOptions.torso_lean_max`); None (the default): no bound.
        Unbounded, RABBIT's optimum leans the torso past the simulator's fall bound
        (pi/2) from about 1.2 m/s on.
    stance_knee_max, swing_knee_min : float
        No hyperextension, rad: every stance knee (RABBIT: q2) <= ``stance_knee_max``
        and every swing knee (RABBIT: q5) >= ``swing_knee_min`` over the whole step
        (enforced on the Bezier coefficients, hence exactly, not only at nodes); legs
        without knees have none.
    n_intervals, degree : int
        Direct collocation of the unactuated row: intervals and collocation points per
        interval.
    scheme : {'legendre', 'radau'}
        Collocation points.
    bezier_degree : int
        Degree of the actuated-joint polynomials q_a^d(s), s = t / T.
    continuation : float or None
        How the reference continues past T (an impact can come late): None, the
        Bezier polynomials evaluated past s = 1 (their accelerations grow fast: on the
        default gait the reference loses ground contact about 0.1 T after T); a number
        c, the acceleration at T ramps linearly to zero over c T, then the velocity
        stays constant (``math.inf``: constant acceleration).  C^2 at T either way: it
        changes neither the optimisation nor A^z, only walking after a late impact.
    continuation_shape : {'ramp', 'smooth'}
        With a number ``continuation`` = c: 'ramp' (default) as above, C^2 at T with
        jerk jumps at T and (1 + c) T; 'smooth', the acceleration decays as
        (a_T + k sigma) exp(-sigma / (c T)), sigma = t - T, with k matching the jerk at
        T: C^3 at T and smooth after it (no kink where late impacts land, which an NLP
        over the impact time needs), the velocity tending to a constant; c at most
        :data:`SMOOTH_CONTINUATION_MAX`.
    cost : {'torque_squared_per_length', 'torque_squared'}
        The integral of u'u over the step divided by the step length, or the integral
        alone.
    polish_steps : int
        RK4 steps per step for the exact unactuated trajectory.
    ipopt : dict
        Extra IPOPT options (name -> value), e.g. ``{'max_iter': 500}``.
    expand : bool
        Expand the NLP to SX before solving (faster iterations, slower build).
    derivatives : {'structured', 'casadi'}
        How IPOPT's exact derivatives (constraint Jacobian, objective gradient,
        Hessian of the Lagrangian, all by AD) are built: 'structured' (per-point and
        boundary SX derivatives scattered into the global sparsity; see
        ``gait_opt/optimize.py``) or 'casadi' (CasADi differentiates the whole MX
        graph: the slow baseline).
    """

    speed: float = 0.75
    step_length_bounds: tuple | None = None
    step_time_bounds: tuple = (0.2, 1.5)
    mu: float = 0.6
    impact_mu: float | None = None
    torque_limit: float | None = None
    min_normal_force: float = 0.0
    clearance: float | None = None
    min_liftoff_speed: float = 0.02
    min_strike_speed: float = 0.02
    torso_lean_max: float | None = None
    stance_knee_max: float = 0.0
    swing_knee_min: float = 0.0
    n_intervals: int = 30
    degree: int = 3
    scheme: str = "legendre"
    bezier_degree: int = 6
    continuation: float | None = None
    continuation_shape: str = "ramp"
    cost: str = "torque_squared_per_length"
    polish_steps: int = 2000
    ipopt: dict = field(default_factory=dict)
    expand: bool = False
    derivatives: str = "structured"

    def __post_init__(self):
        c = FieldChecks(self, "gait option {!r}")
        c.numbers(("speed", "mu"))
        if isinstance(self.torque_limit, (list, tuple)):    # per torque: finite numbers
            object.__setattr__(self, "torque_limit", _per_torque(self.torque_limit))
        else:
            c.numbers(("torque_limit",), none=True, inf=True)   # inf: the robot has none
        c.numbers(("impact_mu",), none=True)
        c.numbers(("continuation",), none=True, inf=True,
                  phrase="None or a positive number (inf allowed)")
        c.choice("continuation_shape", CONTINUATIONS)
        if self.continuation_shape == "smooth" and not (
                self.continuation is not None
                and self.continuation <= SMOOTH_CONTINUATION_MAX):
            raise ValueError("gait option 'continuation_shape' 'smooth' needs a "
                             f"'continuation' of at most {SMOOTH_CONTINUATION_MAX:g} (its "
                             f"decay time, in T), got {self.continuation!r}")
        c.numbers(("min_normal_force", "min_liftoff_speed", "min_strike_speed"), strict=False)
        c.numbers(("clearance",), strict=False, none=True)
        c.numbers(("torso_lean_max",), none=True, phrase=LEAN_PHRASE)
        if self.torso_lean_max is not None and not self.torso_lean_max < math.pi:
            c.fail("torso_lean_max", LEAN_PHRASE, self.torso_lean_max)
        c.pairs(("step_length_bounds",), none=True, to_float=True)   # None: for_model's
        c.pairs(("step_time_bounds",), to_float=True)
        for n, lo, hi in (("n_intervals", 4, MAX_N_INTERVALS), ("degree", 1, MAX_DEGREE),
                          ("bezier_degree", 4, None), ("polish_steps", 100, None)):
            c.integers((n,), lo, hi)
        c.flags(("expand",))
        c.choice("scheme", SCHEMES)
        c.choice("derivatives", DERIVATIVES)
        c.choice("cost", COSTS)
        if not isinstance(self.ipopt, dict):
            c.fail("ipopt", "a dict of IPOPT options", got=False)

    def to_dict(self) -> dict:
        """The options by name, as recorded in gait files (and cache keys).

        Returns
        -------
        dict
            Field name -> value; bounds as lists, ``impact_mu``, ``continuation`` and
            ``torso_lean_max`` left out when unset (so files and cache keys are those
            written before the options existed).
        """
        d = dataclasses.asdict(self)
        # unset: files and cache keys as before
        for name in ("impact_mu", "continuation", "torso_lean_max"):
            if d[name] is None:
                del d[name]
        if d["continuation_shape"] == "ramp":
            del d["continuation_shape"]
        if isinstance(self.torque_limit, tuple):
            d["torque_limit"] = list(self.torque_limit)
        if self.step_length_bounds is not None:
            d["step_length_bounds"] = list(self.step_length_bounds)
        d["step_time_bounds"] = list(self.step_time_bounds)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "GaitOptions":
        """Options from a mapping such as :meth:`to_dict` wrote.

        Parameters
        ----------
        d : dict
            Field name -> value; absent fields keep their defaults.

        Returns
        -------
        GaitOptions

        Raises
        ------
        ValueError
            An unknown field or an invalid value.
        """
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown gait option(s): {', '.join(sorted(unknown))}")
        d = dict(d)
        for n in ("step_length_bounds", "step_time_bounds"):
            if d.get(n) is not None:
                d[n] = tuple(d[n])
        return cls(**d)

    @property
    def impulse_mu(self) -> float:
        """The bound on the impact impulse ratio: ``impact_mu``, else ``mu``."""
        return self.mu if self.impact_mu is None else self.impact_mu

    def replace(self, **changes) -> "GaitOptions":
        """A copy with some fields changed (validated like the constructor).

        Parameters
        ----------
        **changes
            Field name -> new value.

        Returns
        -------
        GaitOptions
        """
        return dataclasses.replace(self, **changes)

    def with_lengths(self, model) -> "GaitOptions":
        """These options with the length-valued defaults filled in for the robot.

        ``step_length_bounds`` and ``clearance``, when none is given: RABBIT's scaled by
        :func:`leg_scale`, the lower step-length bound also with ``speed`` below the
        reference speed (:func:`default_step_length_bounds`; RABBIT itself from 0.75 m/s
        on: exactly (0.2, 0.8) m, and 0.03 m).

        Parameters
        ----------
        model : BipedModel
            The robot the gait is solved for.

        Returns
        -------
        GaitOptions
        """
        fill = {}
        if self.step_length_bounds is None:
            fill["step_length_bounds"] = default_step_length_bounds(model, self.speed)
        if self.clearance is None:
            fill.update(LegScaled(clearance=CLEARANCE).for_model(model))
        return self.replace(**fill) if fill else self

    def for_model(self, model) -> "GaitOptions":
        """These options with the robot's torque limit and length defaults filled in.

        Each only when none is given (the lengths: :meth:`with_lengths`).

        Parameters
        ----------
        model : BipedModel
            The robot the gait is solved for.

        Returns
        -------
        GaitOptions
            ``torque_limit``, ``step_length_bounds`` and ``clearance`` numbers.
        """
        opts = self.with_lengths(model)
        if opts.torque_limit is None:
            bound = model.description.torque_bound
            return opts.replace(torque_limit=bound if isinstance(bound, tuple) else float(bound))
        if isinstance(opts.torque_limit, tuple) and len(opts.torque_limit) != model.nu:
            raise ValueError(f"gait option 'torque_limit' has {len(opts.torque_limit)} "
                             f"bounds, the robot {model.params.name} {model.nu} torques")
        return opts
