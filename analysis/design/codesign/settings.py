"""The co-design's settings, result and error (:func:`analysis.design.codesign.codesign`)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass, field

from biped_casadi.control.output_law import check_rejoin
from biped_casadi.numerics import as_number
from biped_casadi.results import Result
from gait_opt import LegScaled, gait_fields

from ..settings_checks import check_fields, check_gait_fields

from ...robustness.s_star import RobustnessSettings
from ..robust_search import robust_gait
from .functions import TranscriptionSettings
from .scales import physical_scales

#: the sampling search's shipped design on :data:`ROBUST_GAIT` (M1; v_c rejoining at
#: 0.75 T): s* 0.969, the co-design's first warm start
TODAY_DESIGN = (-8.2618, 2.5374, 0.0034, 8.5090)

#: the margin a moved gait keeps above the clearance on RABBIT's legs (0.8 m), m; scaled
#: with the robot's leg length (:meth:`MoveSettings.for_model`)
CLEARANCE_MARGIN = 0.002
#: the torque a moved gait keeps below the limit on RABBIT (limit 150 N m), N m; scaled
#: with the robot's torque limit (:meth:`MoveSettings.for_model`)
MOVE_TORQUE_MARGIN = 0.5

#: what the co-design does with a gait it is given (:class:`CodesignSettings`)
GIVEN_GAIT = ("fixed", "free", "auto")



@dataclass(frozen=True)
class IpoptLimits:
    """When one IPOPT solve of the co-design stops.

    An iteration count and a count of NLP evaluations (each walks every scenario, so its
    cost is nearly constant), never a wall time: a solve's result depends on its inputs
    alone.

    Parameters
    ----------
    max_iter : int
        IPOPT iterations.
    max_evaluations : int
        Evaluations of the NLP (constraints and their Jacobian).
    """

    max_iter: int = 100
    max_evaluations: int = 150

    def __post_init__(self):
        check_fields(self, ("max_iter", "max_evaluations"))


@dataclass(frozen=True)
class StartSampling:
    """The starting M1 of the co-design.

    Parameters
    ----------
    samples : int
        Random M1 drawn in [-box, box]^nu (0: none).
    box : float
        Their box.
    kept : int
        Sampled M1 kept as starts: the first drawn with max ``|lambda|`` within the
        eigenvalue bound from which the walker walks the paper's perturbation at scale 1.
    seed : int
        Seed of the samples.
    extra : tuple
        Starting M1s besides the sampled ones.
    s_start : float
        Perturbation scale of the first solves' starting point.
    fit_gait : bool
        Starts that fit the gait (:mod:`analysis.design.codesign.starts`): the box in
        units of the gait's joint ranges per radian of q_u, the deadbeat NLP's and the
        virtual constraints' designs besides the samples, every start screened by the
        walker's s* (the best kept, each solved from its own s*) instead of the paper's
        perturbation at scale 1.
    screened : int
        With ``fit_gait``: starts bisected at most.
    screen_rounds : int
        With ``fit_gait``: bisection rounds of the screen (resolution 2^(1 - rounds)
        x 2).
    screen_rk4 : int
        With ``fit_gait``: RK4 steps per T of the screen's walker.
    deadbeat : bool
        With ``fit_gait``: the deadbeat M1 NLP's design among the starts.
    refine_rounds : int
        With ``fit_gait``: rounds of the local search near the best starts when no
        screened start converges from the paper's perturbation by the target's step with
        s* >= 1 (:mod:`analysis.design.codesign.refine`; 0: none).
    refine_from : float
        Refine only when the screen's best s* (converging in time or not) is at least
        this: the gait carries the scale.
    refine_draws, refine_bisected, refine_elite : int
        Per round: draws, of them bisected at most, starts drawn around.
    refine_radius, refine_shrink : float
        The draws' standard deviation in units of the gait's scale, and its factor per
        round.
    refine_stop : float
        The search stops once a start converging in time reaches this s*.
    """

    samples: int = 2000
    box: float = 1.0
    kept: int = 5
    seed: int = 0
    extra: tuple = ()
    s_start: float = 0.9
    fit_gait: bool = False
    screened: int = 150
    screen_rounds: int = 6
    screen_rk4: int = 200
    deadbeat: bool = True
    refine_rounds: int = 0
    refine_from: float = 0.9
    refine_draws: int = 3200
    refine_bisected: int = 120
    refine_elite: int = 8
    refine_radius: float = 0.15
    refine_shrink: float = 0.7
    refine_stop: float = 1.0625

    def __post_init__(self):
        check_fields(self, ("samples", "kept", "screened", "screen_rounds", "refine_draws",
                            "refine_bisected", "refine_elite"),
                     ("box", "s_start", "refine_from", "refine_radius", "refine_shrink",
                      "refine_stop"))
        check_fields(self, ("seed", "refine_rounds"), low=0)
        check_fields(self, ("screen_rk4",), low=8)


@dataclass(frozen=True)
class TrustRegion:
    """The trust region of a gait step (halved after a rejected step).

    Parameters
    ----------
    alpha : float
        Bezier coefficients, rad.
    T : float
        Step time, s.
    x0 : float
        The unactuated start, rad and rad/s.
    """

    alpha: float = 0.05
    T: float = 0.025
    x0: float = 0.25

    def __post_init__(self):
        check_fields(self, numbers=("alpha", "T", "x0"))


@dataclass(frozen=True)
class Verification:
    """How every candidate and the result are measured (the robust designs' protocol).

    Parameters
    ----------
    mu : float
        Friction coefficient.
    torque_limit : float, optional
        Torque bound on every joint, N m (None: the robot's own, each joint's where its
        joints' limits differ).
    directions : int
        Kept perturbation directions.
    walk_steps : int
        Steps every run must walk.
    tol : float
        Convergence threshold at the last step.
    hidden : bool
        Check the result on hidden sign patterns (at scales 1 and 1.25).
    basin : bool
        Compute the 101 x 101 basin of the result.
    """

    mu: float = 0.6
    torque_limit: float | None = None
    directions: int = 16
    walk_steps: int = 10
    tol: float = 1e-3
    hidden: bool = True
    basin: bool = False

    def __post_init__(self):
        check_fields(self, ("directions", "walk_steps"), ("mu", "torque_limit", "tol"))


@dataclass(frozen=True)
class MoveSettings:
    """How the user's gait is moved to the robust gait constraints (module docstring).

    Parameters
    ----------
    steps : int
        Continuation steps from the gait's own values to the targets (1: straight to
        them; a step that fails is halved, so the targets are reached by continuation
        when they must be).
    halvings : int
        Times a failed step is halved before the move ends.
    scale : tuple of float
        (alpha rad, T s, r0) the units of the distance to the user's gait.
    impulse_margin : float
        The impulse ratio is solved this much below each step's bound (between the
        nodes the polished gait may exceed the nodes' values).
    clearance_margin : float or None
        m: the clearance likewise, above; None (the default): 0.0025 x the robot's leg
        length (RABBIT: 0.002 m), filled in by :meth:`for_model` (the co-design records
        the value used in its settings).
    friction_margin : float
        The path's friction ratio likewise, below mu.
    torque_margin : float or None
        N m: the torques likewise, below the limit; None (the default): 1/300 of the
        robot's own torque limit (RABBIT: 0.5 N m; a robot without one: RABBIT's
        0.5 N m times its weight x leg length over RABBIT's; a robot whose joints' limits
        differ: 1/300 of the smallest, kept below every joint's limit), filled in by
        :meth:`for_model`.
    max_iter : int
        IPOPT iterations per step.
    effort : float
        Weight of the nominal step's effort int u'u ds, relative to the user's gait's,
        beside the distance (0: the nearest gait).
    path_mu : float
        The friction ratio the moved gait keeps in single support (the verification's
        mu is 0.6: the margin is room for perturbations).
    torque_fraction : float
        The moved gait's torques stay within this fraction of the torque limit (of
        each joint's, where the joints' limits differ).
    efforts : tuple of float
        The effort weights the co-design tries in turn (:meth:`.method.Method.setup`):
        the gait nearest the given one first, then smoother ones farther away; inf: the
        toolkit's optimal gait under the robust gait options at the given gait's speed, in
        the toolkit's Bezier degree.
    """

    steps: int = 1
    halvings: int = 4
    scale: tuple = (0.05, 0.025, 0.25)
    impulse_margin: float = 0.005
    clearance_margin: float | None = None
    friction_margin: float = 1e-4
    torque_margin: float | None = None
    max_iter: int = 200
    effort: float = 300.0
    path_mu: float = 0.45
    torque_fraction: float = 0.8
    efforts: tuple = (0.0, 300.0, 3000.0, math.inf)

    def __post_init__(self):
        for name in ("clearance_margin", "torque_margin"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, as_number(getattr(self, name), name,
                                                         nonnegative=True))

    def for_model(self, model) -> "MoveSettings":
        """These settings with the robot's margins filled in.

        ``clearance_margin`` and ``torque_margin``, each when none is given: :data:`CLEARANCE_MARGIN` scaled with its leg length
        (RABBIT exactly 0.002 m), :data:`MOVE_TORQUE_MARGIN` with its torque limit
        (:func:`~analysis.design.codesign.scales.physical_scales`; RABBIT exactly 0.5 N m).

        Parameters
        ----------
        model : BipedModel
            The robot whose gait is moved.

        Returns
        -------
        MoveSettings
        """
        k = physical_scales(model)
        fill = {name: value * k[kind] for name, kind, value in (
            ("clearance_margin", "length", CLEARANCE_MARGIN),
            ("torque_margin", "torque", MOVE_TORQUE_MARGIN)) if getattr(self, name) is None}
        return dataclasses.replace(self, **fill) if fill else self


def _check_transcription(fields) -> None:
    """ValueError naming a ``transcription`` field the co-design cannot take: one
    :class:`~analysis.design.codesign.functions.TranscriptionSettings` does not have,
    ``mu`` / ``torque_limit``, which the verification sets, or a value it refuses."""
    if not isinstance(fields, dict):
        raise ValueError(f"transcription must be a dict of TranscriptionSettings fields, got "
                         f"{type(fields).__name__}")
    known = {f.name for f in dataclasses.fields(TranscriptionSettings)}
    unknown = sorted(set(fields) - known)
    if unknown:
        raise ValueError(f"transcription: no field {unknown[0]!r} (TranscriptionSettings has "
                         f"{', '.join(sorted(known - {'mu', 'torque_limit'}))})")
    for name in ("mu", "torque_limit"):
        if name in fields:
            raise ValueError(f"transcription: {name} is the verification's "
                             f"(Verification({name}=...)): the transcription keeps it equal")
    try:
        TranscriptionSettings(**fields)                  # its values' own checks
    except ValueError as e:
        raise ValueError(f"transcription: {e}") from None


@dataclass(frozen=True)
class CodesignSettings:
    """The co-design of :func:`codesign` (module docstring); all have defaults.

    Parameters
    ----------
    gait : dict
        GaitOptions fields of the gait to start from (and whose constraints the free
        gait keeps); default :func:`~analysis.design.robust_gait` (:data:`ROBUST_GAIT`,
        its clearance scaled with the robot's leg length; a plain dict is used as given).
    free_gait : bool
        Co-design the gait (else only M1 moves, on the given or start gait).
    rejoin : float
        Rejoin time of v_c of the first solves, fraction of T.
    rejoin_choices : tuple
        Rejoin times (fractions of T, in [1/2, 3/4]) the gait-fixed NLP is solved at from
        the best design; the best verified one is kept (a discrete decision: the walker's
        rule is kinked in the rejoin time).  Empty: ``rejoin`` only.
    steps : int
        Steps per NLP scenario.
    paper_tol : float
        Error bound at the last NLP steps of the paper's direction at scale 1.
    scenario_tol : float
        Error bound at the last NLP step of the other scenarios (at scale s).
    initial_active : int
        Kept directions in the first NLP besides the paper's: those that fail first for
        the starting design.
    max_active : int
        Largest number of kept directions in the NLP.
    exchange_rounds : int
        NLP solves with the gait fixed (each followed by the walker's verification).
    gait_rounds : int
        Gait steps (free gait only).
    repair : bool
        After a gait step that raises s* but leaves max ``|lambda|`` above the virtual
        constraints' (the free-gait NLP does not bound it), solve for M1 alone on the new
        gait under the Jury bound.
    eigen_margin : float
        max ``|lambda|`` is kept at most this fraction of the virtual constraints'
        eigenvalue in the gait-fixed NLP.
    gait_eigen_margin : float
        In a gait step, max ``|lambda|`` of the current gait's A^z(M1) is kept at most this
        fraction of the virtual constraints' eigenvalue (the new gait's is verified).
    paper_steps : int
        Continuation solves that bring the paper's error bound down from the start's.
    starts : StartSampling
        The starting M1.
    trust : TrustRegion
        The gait steps' trust region.
    solve, screen, gait_step : IpoptLimits
        IPOPT's limits for the exchange and rejoin solves, the first solve from each
        start (the start whose solve reaches the largest s continues), and a gait step
        (a free-gait evaluation costs about four times a fixed-gait one).
    transcription : dict
        :class:`~analysis.design.codesign.functions.TranscriptionSettings` fields (rule and
        margins).
    verification : Verification
        How candidates and the result are measured.
    steps_after_target : bool
        Take the gait steps even when the design meets the target already (else the
        gait stays as near the start gait as the target allows).
    converge_by : int
        The target's step by which the paper's perturbation is below the tolerance for
        good (the paper: 4).
    given_gait : {'fixed', 'free', 'auto'}
        With a gait given: 'fixed' (only M1 moves), 'free' (the gait is moved to the
        robust gait constraints of ``gait``, :mod:`analysis.design.codesign.gait_move`,
        then co-designed from there), 'auto' (fixed, then free when the fixed gait's
        design misses the target).
    move : MoveSettings
        How a given gait is moved.
    """

    gait: dict = field(default_factory=robust_gait)
    free_gait: bool = True
    rejoin: float = 0.75
    rejoin_choices: tuple = (0.5, 0.625, 0.75)
    steps: int = 4
    paper_tol: float = 8e-4
    scenario_tol: float = 0.5
    initial_active: int = 2
    max_active: int = 8
    exchange_rounds: int = 1
    gait_rounds: int = 2
    repair: bool = True
    eigen_margin: float = 0.98
    gait_eigen_margin: float = 0.9
    paper_steps: int = 3
    starts: StartSampling = field(default_factory=StartSampling)
    trust: TrustRegion = field(default_factory=TrustRegion)
    solve: IpoptLimits = field(default_factory=IpoptLimits)
    screen: IpoptLimits = field(default_factory=lambda: IpoptLimits(30, 40))
    gait_step: IpoptLimits = field(default_factory=lambda: IpoptLimits(40, 45))
    transcription: dict = field(default_factory=dict)
    verification: Verification = field(default_factory=Verification)
    steps_after_target: bool = True
    converge_by: int = 4
    given_gait: str = "fixed"
    move: MoveSettings = field(default_factory=MoveSettings)

    def __post_init__(self):
        check_gait_fields(self.gait)
        object.__setattr__(self, "rejoin", check_rejoin(self.rejoin))
        object.__setattr__(self, "rejoin_choices", tuple(
            check_rejoin(r, "rejoin_choices") for r in self.rejoin_choices))
        check_fields(self, ("steps",))
        for name, kind in (("starts", StartSampling), ("trust", TrustRegion),
                           ("solve", IpoptLimits), ("screen", IpoptLimits),
                           ("gait_step", IpoptLimits), ("verification", Verification),
                           ("move", MoveSettings)):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__}, got "
                                 f"{type(getattr(self, name)).__name__}")
        if self.given_gait not in GIVEN_GAIT:
            raise ValueError(f"given_gait must be one of {GIVEN_GAIT}, got "
                             f"{self.given_gait!r}")
        _check_transcription(self.transcription)

    def for_model(self, model) -> "CodesignSettings":
        """These settings with the robot's defaults filled in.

        :meth:`MoveSettings.for_model`, and the gait fields as used on the robot
        (:func:`gait_opt.gait_fields`: a :class:`~gait_opt.LegScaled` default's clearance
        scaled with the leg length, a plain dict as given), so that the co-design records
        the clearance it used (RABBIT: :data:`ROBUST_GAIT`'s numbers exactly).

        Parameters
        ----------
        model : BipedModel
            The robot co-designed.

        Returns
        -------
        CodesignSettings
        """
        move = self.move.for_model(model)
        fill = {} if move is self.move else dict(move=move)
        if isinstance(self.gait, LegScaled):
            fill["gait"] = gait_fields(self.gait, model)
        return dataclasses.replace(self, **fill) if fill else self

    def robustness_settings(self, rounds: int = 8) -> RobustnessSettings:
        """The protocol's settings (400 RK4 steps per T, ``rounds`` bisection rounds).

        Parameters
        ----------
        rounds : int
            Bisection rounds.

        Returns
        -------
        RobustnessSettings
        """
        v = self.verification
        return RobustnessSettings(directions=v.directions, steps=v.walk_steps, tol=v.tol,
                                  mu=v.mu, torque_limit=v.torque_limit, rounds=rounds)

    def replace(self, **changes) -> "CodesignSettings":
        """A copy with some fields changed, the groups' fields given directly.

        ``samples=``, ``seed=``, ``mu=`` and the other fields of the start sampling and
        of the verification may be given as they are.

        Parameters
        ----------
        **changes
            Fields of this class or of :class:`StartSampling` (``samples``, ``box``,
            ``seed``, ``kept``) and :class:`Verification` (``mu``, ``torque_limit``,
            ``hidden``, ``basin``, ...).

        Returns
        -------
        CodesignSettings
        """
        top = {k: v for k, v in changes.items() if k in self.__dataclass_fields__}
        for group in ("starts", "verification"):
            cur = getattr(self, group)
            sub = {k: v for k, v in changes.items() if k in cur.__dataclass_fields__
                   and k not in self.__dataclass_fields__}
            if sub:
                top[group] = dataclasses.replace(top.get(group, cur), **sub)
        unknown = set(changes) - set(top) - {k for g in ("starts", "verification")
                                             for k in getattr(self, g).__dataclass_fields__}
        if unknown:
            raise ValueError(f"CodesignSettings has no field {sorted(unknown)[0]!r}")
        return dataclasses.replace(self, **top)

    def to_dict(self) -> dict:
        """The settings as a dictionary.

        Returns
        -------
        dict
        """
        d = asdict(self)
        d["starts"]["extra"] = [list(map(float, s)) for s in self.starts.extra]
        return d


#: the settings of a quick reproduction: the gait fixed, v_c rejoining at 0.75 T, no hidden
#: patterns, each start screened on 25 NLP evaluations (20 iterations) instead of 40 (30):
#: on RABBIT the same start wins and the design is the same to the last digit, in 2/3 of
#: the time (measured)
QUICK = CodesignSettings(free_gait=False, rejoin_choices=(), screen=IpoptLimits(20, 25),
                         verification=Verification(hidden=False))
#: the settings of a full reproduction: those of ``biped m1 --robust`` (one cache for both)
FULL = CodesignSettings()
#: the settings of ``biped m1 --robust --gait FILE``: starts that fit the gait (20000
#: samples in the gait's units, the deadbeat NLP's and the virtual constraints' designs,
#: screened by the walker's s*; the best three solved when the best alone misses the
#: target), v_c rejoining at 0.75 T only, the gait fixed first and moved from when that
#: misses the target (s* >= 1, max|lambda| within virtual constraints', the paper's
#: perturbation below 1e-3 by step 5), the gait steps only while the target is missed
FIT = CodesignSettings(starts=StartSampling(samples=20000, kept=3, fit_gait=True,
                                            refine_rounds=5),
                       rejoin_choices=(), given_gait="auto", converge_by=5,
                       steps_after_target=False)


@dataclass
class CodesignResult(Result):
    """The co-designed controller (and gait) and its check by the verification protocol.

    ``success`` means the co-design ran to its verification; whether the targets are met
    is ``status``.  The check's figures (``s_star``, ``max_abs``, ``vc_eigenvalue``,
    ``steps_to_converge``, ``paper_errors``, ``peak_torque``, ...) are also attributes of
    the result and keys of ``to_dict()``.

    Parameters
    ----------
    status : str
        'target_met' (s* >= 1, max ``|lambda|`` <= the virtual constraints' eigenvalue,
        the paper's perturbation converged by step ``converge_by`` of the settings, 4
        by default) or 'target_not_met'.
    message : str
        The result in words.
    design : Design
        M1, the rejoin time and the gait (``design.gait``).
    check : DesignCheck
        The design measured by :func:`~analysis.design.verification.verify_design`.
    gait_free : bool
        Whether the gait was co-designed.
    gait_change : dict
        T before and after, the largest change of a Bezier coefficient (rad).
    hidden : dict
        The hidden sign patterns (:class:`~analysis.design.verification.HiddenPatterns`), or {}.
    basin : dict
        The basin's fractions, or {}.
    nlp_s : float
        The best NLP's own s (over its scenarios).
    active_constraints : list of dict
        The constraints with the largest multipliers at the best solve, in words.
    ipopt : dict
        The solves: status, iterations and evaluations of each and what walked its
        nodes (``node``: 'kernel', or 'scalar' where a process could not build the
        four-lane kernel), and their totals.
    rounds : list of dict
        Every solve and verification (s of the NLP, verified s*, scenarios).
    directions_kept : int
        Kept directions on the final gait.
    directions_tried : int
        Candidates tried to keep them.
    settings : dict
        :meth:`CodesignSettings.to_dict`.
    gait_file : str
        Where the gait is saved ('' until :func:`codesign` saves it).
    simulate_args : list of str
        ``biped simulate`` arguments that replay the design from the paper's
        perturbation (empty until the gait is saved).
    elapsed : float
        Wall time of the computation, s (0 when every part was kept).
    cached : bool
        Read from the cache.
    vc_s_star : float
        Virtual constraints' s* on the design's gait by the same protocol as ``s_star``
        (``settings['verification']``: ``walk_steps`` steps, below ``tol``), NaN when not
        measured.  On a gait whose virtual-constraint rate needs more steps than that
        (:func:`~analysis.robustness.steps_short`; the message and the printed lines then
        say "over the same N steps") both measure how fast each converges, and theirs is
        often 0: ``biped robust --controller vc --steps auto`` measures it over enough
        steps (0.89 against 0.047 over 10 on RABBIT's 0.3 m/s gait, rate 0.76).
    given_gait : str
        What was done with a given gait ('fixed', 'free'; '' when none was given).
    start_screen : dict
        The starts screened by the walker's s* (:class:`~.starts.StartScreen`), when
        the starts fit the gait.
    gait_move : dict
        How the given gait was moved (:class:`~.gait_move.GaitMove`), with the gait
        free from a given gait.
    binds : dict
        With starts that fit the gait: what stops the design just above its s* (the
        failing run's ``status``, ``step`` and ``binds``, the constraint in words).
    alternative : dict
        With ``given_gait`` 'auto': the other design tried (on the gait as given, or
        moved from it) in a few figures, or why there was none.
    """

    status: str
    message: str
    design: object
    check: object
    gait_free: bool
    gait_change: dict
    hidden: dict
    basin: dict
    nlp_s: float
    active_constraints: list
    ipopt: dict
    rounds: list
    directions_kept: int
    directions_tried: int
    settings: dict
    gait_file: str = ""
    simulate_args: list = field(default_factory=list)
    elapsed: float = 0.0
    cached: bool = False
    vc_s_star: float = math.nan
    given_gait: str = ""
    start_screen: dict = field(default_factory=dict)
    gait_move: dict = field(default_factory=dict)
    binds: dict = field(default_factory=dict)
    alternative: dict = field(default_factory=dict)

    SUCCESS = ("target_met", "target_not_met")

    #: the check's figures, read through the result
    CHECK = ("s_star", "s_fail", "failure", "verified", "max_abs", "vc_eigenvalue",
             "steps_to_converge", "paper_errors", "peak_torque")

    def __getattr__(self, name):
        if name in CodesignResult.CHECK:
            return getattr(self.__dict__["check"], name)
        raise AttributeError(name)

    @property
    def gait(self):
        """The gait the design runs on."""
        return self.design.gait

    def to_dict(self) -> dict:
        """The result in plain JSON types (what ``biped m1 --robust --json`` prints).

        Returns
        -------
        dict
            Every field, the check's figures at the top level, ``gait_options`` and
            ``success``.
        """
        out = super().to_dict()
        chk = out.pop("check")
        for k in self.CHECK:
            out[k] = chk.get(k)
        out["gait_options"] = self.gait.options.to_dict()
        return out


class CodesignError(ValueError):
    """IPOPT failed on the co-design NLP, or the request is infeasible.

    The message says which solver, its status and what to try.
    """


class NoDesign(CodesignError):
    """No design on the gait: the message says why in one line, naming what binds.

    Parameters
    ----------
    message : str
        The line.
    details : dict
        What the line says, as values (the start screen's best scale and what stops
        it, virtual constraints' s*, the gait's move).
    """

    def __init__(self, message: str, details: dict | None = None):
        super().__init__(message)
        self.details = dict(details or {})

    def to_dict(self) -> dict:
        """The failure as one JSON object (what ``biped m1 --robust --json`` prints).

        Returns
        -------
        dict
            ``status`` 'no_design', ``success`` False, ``message`` and the details.
        """
        return dict(status="no_design", success=False, message=str(self), **self.details)

