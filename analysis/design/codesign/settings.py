"""The co-design's settings, result and error (:func:`analysis.design.codesign.codesign`)."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

from biped_casadi.caching import DiskCache
from biped_casadi.results import Result, internal

from ...robustness.s_star import RobustnessSettings
from ..robust_search import ROBUST_GAIT

#: the sampling search's shipped design on :data:`ROBUST_GAIT` (M1; v_c rejoining at
#: 0.75 T): s* 0.969, the co-design's first warm start
TODAY_DESIGN = (-8.2618, 2.5374, 0.0034, 8.5090)

#: the co-designs kept between sessions
CODESIGNS = DiskCache("codesign", version=1)


@dataclass(frozen=True)
class CodesignSettings:
    """The co-design of :func:`codesign` (module docstring); all have defaults.

    Parameters
    ----------
    gait : dict
        GaitOptions fields of the gait to start from (and whose constraints the free
        gait keeps); default :data:`ROBUST_GAIT`.
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
        Error bound at the last NLP step of the paper's direction at scale 1.
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
    trust_alpha, trust_T, trust_x0 : float
        Trust region of a gait step: rad on every Bezier coefficient, s on T, and
        rad, rad/s on the unactuated start.
    starts : tuple
        Starting M1s besides the sampled ones (:data:`FULL` adds today's search design;
        from it the NLP ends in the region of large M1, s* 0.4-0.9, measured).
    samples : int
        Random M1 drawn in [-box, box]^nu for the sampled starts (0: none).
    box : float
        Their box.
    sampled_starts : int
        Sampled M1 kept as starts: the first drawn with max ``|lambda|`` within the bound
        from which the walker walks the paper's perturbation at scale 1.
    seed : int
        Seed of the samples.
    s_start : float
        Scale of the first NLP's starting point.
    eigen_margin : float
        max ``|lambda|`` is kept at most this fraction of the virtual constraints'
        eigenvalue in the NLP.
    max_iter : int
        IPOPT iterations per solve.
    screen_iter, screen_time, screen_evaluations : int, float, int
        IPOPT iterations, wall time (s) and NLP evaluations of the first solve from each
        start; the start whose solve reaches the largest s continues.  The evaluation
        budget binds (an evaluation walks every scenario: its cost is nearly constant,
        an iteration's is not), so that a result does not depend on the machine's
        load; the wall times are a safety net.
    paper_steps : int
        Continuation solves that bring the paper's error bound down from the start's.
    max_solve_time, max_evaluations : float, int
        Wall time (s) and NLP evaluations of every other solve.
    gait_iter, gait_solve_time, gait_evaluations : int, float, int
        The same for a gait step's solve (a free-gait evaluation costs about four
        times a fixed-gait one).
    gait_eigen_margin : float
        In a gait step, max ``|lambda|`` of the current gait's A^z(M1) is kept at most this
        fraction of the virtual constraints' eigenvalue (the new gait's is verified).
    transcription : dict
        :class:`~analysis.design.codesign.functions.TranscriptionSettings` fields (rule and
        margins).
    mu, torque_limit, directions, walk_steps, tol : as :class:`RobustnessSettings`
        Friction coefficient, torque bound (N m, None: the robot's), kept directions,
        steps walked and convergence threshold of every verification.
    hidden : bool
        Check the design on hidden sign patterns (at 1 and 1.25).
    basin : bool
        Compute the 101 x 101 basin of the result.
    """

    gait: dict = field(default_factory=lambda: dict(ROBUST_GAIT))
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
    trust_alpha: float = 0.05
    trust_T: float = 0.025
    trust_x0: float = 0.25
    starts: tuple = ()
    samples: int = 2000
    box: float = 1.0
    sampled_starts: int = 5
    seed: int = 0
    s_start: float = 0.9
    eigen_margin: float = 0.98
    max_iter: int = 100
    screen_iter: int = 30
    screen_time: float = 60.0
    screen_evaluations: int = 40
    paper_steps: int = 3
    max_solve_time: float = 60.0
    max_evaluations: int = 150
    gait_solve_time: float = 60.0
    gait_iter: int = 40
    gait_evaluations: int = 45
    gait_eigen_margin: float = 0.9
    transcription: dict = field(default_factory=dict)
    mu: float = 0.6
    torque_limit: float | None = None
    directions: int = 16
    walk_steps: int = 10
    tol: float = 1e-3
    hidden: bool = True
    basin: bool = False

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
        return RobustnessSettings(directions=self.directions, steps=self.walk_steps,
                                  tol=self.tol, mu=self.mu, torque_limit=self.torque_limit,
                                  rounds=rounds)

    def to_dict(self) -> dict:
        """The settings as a dictionary (part of the cache key).

        Returns
        -------
        dict
        """
        d = asdict(self)
        d["starts"] = [list(map(float, s)) for s in self.starts]
        return d


#: the settings of a quick reproduction: the gait fixed, v_c rejoining at 0.75 T, no hidden
#: patterns, each start screened on 25 NLP evaluations (20 iterations) instead of 40 (30):
#: on RABBIT the same start wins and the design is the same to the last digit, in 2/3 of
#: the time (measured)
QUICK = CodesignSettings(free_gait=False, hidden=False, rejoin_choices=(),
                         screen_evaluations=25, screen_iter=20)
#: the settings of a full reproduction: those of ``biped m1 --robust`` (one cache for both)
FULL = CodesignSettings()


@dataclass
class CodesignResult(Result):
    """The co-designed controller (and gait), verified.

    ``success`` means the co-design ran to its verification; whether the targets are met
    is ``status``.

    Parameters
    ----------
    status : str
        'target_met' (s* >= 1, max ``|lambda|`` <= the virtual constraints' eigenvalue,
        the paper's perturbation converged by step 4) or 'target_not_met'.
    message : str
        The result in words.
    design : dict
        ``M1`` (list) and ``rejoin`` (fraction of T).
    gait_file : str
        The gait the design runs on.
    gait_options : dict
        Its GaitOptions.
    gait_free : bool
        Whether the gait was co-designed.
    gait_change : dict
        T before and after, the largest change of a Bezier coefficient (rad).
    s_star, s_fail : float
        The protocol's s* and the scale just above where a kept direction fails.
    failure : str
        That failure in words.
    verified : dict
        Full-order runs at s* and s_fail (:class:`~analysis.design.verification.DesignCheck`).
    max_abs : float
        max ``|lambda|`` of A^z (full AD).
    vc_eigenvalue : float
        Virtual constraints' ``|eigenvalue|`` on the same gait.
    steps_to_converge : int or None
        The paper's perturbation, full order: the step from which the error stays below
        ``tol``.
    paper_errors : list of float
        The error at every step of that run.
    peak_torque : float
        Its largest ``|u|``, N m.
    hidden : dict
        The hidden sign patterns (:class:`~analysis.design.verification.HiddenPatterns`), or {}.
    basin : dict
        The basin's fractions, or {}.
    nlp_s : float
        The best NLP's own s (over its scenarios).
    active_constraints : list of dict
        The constraints with the largest multipliers at the last solve, in words.
    ipopt : dict
        The solves: status, iterations and time of each, and their totals.
    rounds : list of dict
        Every solve and verification (s of the NLP, verified s*, scenarios).
    directions_kept : int
        Kept directions on the final gait.
    directions_tried : int
        Candidates tried to keep them.
    simulate_args : list of str
        ``biped simulate`` arguments that replay the design from the paper's perturbation.
    stages : dict
        Time per stage, s.
    elapsed : float
        Wall time, s.
    settings : dict
        :meth:`CodesignSettings.to_dict`.
    cached : bool
        Read from the cache.
    gait : Gait
        The gait (left out of ``to_dict()``).
    """

    status: str
    message: str
    design: dict
    gait_file: str
    gait_options: dict
    gait_free: bool
    gait_change: dict
    s_star: float
    s_fail: float
    failure: str
    verified: dict
    max_abs: float
    vc_eigenvalue: float
    steps_to_converge: int | None
    paper_errors: list
    peak_torque: float
    hidden: dict
    basin: dict
    nlp_s: float
    active_constraints: list
    ipopt: dict
    rounds: list
    directions_kept: int
    directions_tried: int
    simulate_args: list
    stages: dict
    elapsed: float
    settings: dict
    cached: bool = False
    gait: object = internal(default=None)

    SUCCESS = ("target_met", "target_not_met")


class CodesignError(ValueError):
    """IPOPT failed on the co-design NLP, or the request is infeasible.

    The message says which solver, its status and what to try.
    """

