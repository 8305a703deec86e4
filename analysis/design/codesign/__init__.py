"""Robust co-design: one NLP chooses M1 and, by default, the gait itself, against
perturbation scenarios walked by the walker's own rule.

Where each part lives: :mod:`.settings` (the settings, the result and the error),
:mod:`.functions` (the compiled node, step and reference functions),
:mod:`.transcription` (one scenario-step: the walker's RK4 rule, its strike and impact,
with exact sensitivities), :mod:`.reduced` (the NLP in the design alone and its IPOPT
solve), :mod:`.problem` (one NLP as a typed value and its solve, a task), :mod:`.units`
(the other units of work), :mod:`.method` (the method below, phase by phase) and
:mod:`.api` (:func:`codesign` and :func:`codesign_tradeoff`).

The NLP.  Decision variables: the outputs M1, the
perturbation scale s (maximised) and, with the gait free, the gait's Bezier
coefficients alpha, its duration T and its unactuated start (q_u^d(0), dq_u^d(0)), under
the constraints of :mod:`gait_opt.transcription` on the gait's own nominal step.  Each
scenario starts at the gait's start plus the perturbation of its direction at scale s
(the full 10-state perturbation, as in the paper) -- the paper's own direction at the
fixed scale 1 -- and walks ``steps`` steps of the closed-loop hybrid zero dynamics with
the walker's fixed-grid RK4 and its strike; every node, strike and impact keeps the
walker's validity conditions with margins.  At the last step the paper's direction is
below ``paper_tol`` (the paper's claim: converged from step 4) and the other scenarios
below ``scenario_tol``.  With the gait fixed, max|lambda(A^z)| is bounded by the 2x2 Jury
conditions on A^z (exact in M1 by AD of the variational equation) at ``eigen_margin``
times the virtual constraints' eigenvalue; with the gait free it is verified after each
gait step.  The rejoin time of v_c is fixed per solve (``rejoin``): v_c's third
derivative jumps at t_c, which makes the walker's discrete rule kinked in t_c each time
it crosses an RK4 stage.

The method.  "Every kept direction walks" is a semi-infinite constraint; it is met by
scenario exchange (a cutting-plane method): the NLP is solved on the paper's direction
and the few directions that fail first; the design is verified on every kept direction
with the walker's bisection (:func:`analysis.robustness.robustness`); the direction that
fails just above the verified s* joins the scenarios, and the NLP is solved again from
its last design.  With the gait free, each gait step is taken inside a trust region
around the current gait, made exactly periodic (:func:`gait_opt.polish.polish`), its
kept directions re-derived (the protocol's rule: virtual constraints walk from them at
scale 1), and accepted only when the verified s* improves with max|lambda| at most the
virtual constraints' eigenvalue on the new gait.

The result is verified by the one protocol
(:func:`analysis.design.verification.verify_design`): s* (walker bisection, full-order simulator at s* and just above), the paper's perturbation
in full order, max|lambda| against virtual constraints, and sign patterns never seen
(:func:`analysis.design.verification.hidden_sign_patterns`).  Results are cached.
"""

from .api import (NoDesignFound, codesign, codesign_flow, codesign_tradeoff, given_gait_flow,
                  replay_args, tradeoff_flow)
from .functions import FAMILIES, TranscriptionSettings, compiled
from .method import Candidate, Method
from .problem import Problem, Solve, build, solve, solve_continued
from .reduced import NLPSolve, Reduced, solve_nlp
from .gait_move import GaitMove, continue_gait, gait_change, move_gait
from .settings import (FIT, FULL, QUICK, TODAY_DESIGN, CodesignError, CodesignResult,
                       CodesignSettings, IpoptLimits, MoveSettings, NoDesign, StartSampling,
                       TrustRegion, Verification)
from .screen import fitted_starts
from .starts import StartScreen
from .transcription import Transcription

# the documented surface (Transcription, Reduced, Problem and the method's parts stay
# importable: the NLP's internals, for tests and studies)
__all__ = ["codesign", "codesign_tradeoff", "codesign_flow", "given_gait_flow", "NoDesignFound",
           "tradeoff_flow", "replay_args",
           "CodesignSettings", "IpoptLimits", "StartSampling", "TrustRegion", "Verification",
           "MoveSettings", "CodesignResult", "CodesignError", "NoDesign", "QUICK", "FULL", "FIT",
           "TODAY_DESIGN", "GaitMove", "move_gait", "continue_gait", "gait_change", "StartScreen",
           "fitted_starts",
           "TranscriptionSettings", "solve_nlp", "NLPSolve", "FAMILIES", "compiled"]
