"""Estimates of a Monte Carlo of walking runs: the survival curve, the per-step failure
probability with censored runs and its exact interval, and the mean first-passage time
(Byl & Tedrake, IJRR 2009)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from biped_casadi.results import Result

__all__ = ["MFPTEstimate", "mfpt_estimate"]


@dataclass
class MFPTEstimate(Result):
    """The per-step failure probability and the MFPT of runs (module docstring).

    Parameters
    ----------
    failures : int
        F, runs that failed.
    censored : int
        Runs that walked every step.
    steps_walked : int
        Valid steps walked, summed over the runs.
    steps_attempted : int
        E: steps walked plus the failing steps.
    failure_probability : float
        p = F / E.
    failure_probability_ci : list of float
        Its exact 95 % interval.
    mfpt : float
        (1 - p) / p, steps (inf when no run failed).
    mfpt_ci : list of float
        Its 95 % interval (upper inf when no run failed).
    mean_steps_walked : float
        The mean of the steps the runs walked (below the MFPT when runs are censored).
    survival : list of float
        S(k), k = 0..K: the fraction of runs that walked at least k steps.
    status : str
        'done'.
    message : str
        In words.
    """

    failures: int
    censored: int
    steps_walked: int
    steps_attempted: int
    failure_probability: float
    failure_probability_ci: list
    mfpt: float
    mfpt_ci: list
    mean_steps_walked: float
    survival: list
    status: str = "done"
    message: str = ""

    SUCCESS = ("done",)


def mfpt_estimate(walked, failed, max_steps: int, confidence: float = 0.95) -> MFPTEstimate:
    """The MFPT and the per-step failure probability of runs, with censoring.

    Parameters
    ----------
    walked : array_like of int
        (n,) valid steps each run walked.
    failed : array_like of bool
        (n,) whether it ended with a failure (else it walked ``max_steps``: censored).
    max_steps : int
        K.
    confidence : float
        Of the intervals.

    Returns
    -------
    MFPTEstimate
    """
    from scipy.special import gammaincinv      # (scipy.stats costs 0.3 s more to import)

    def chi2_quantile(q, df):                       # as scipy.stats.chi2.ppf computes it
        return float(2.0 * gammaincinv(df / 2, q))
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) \
            or max_steps < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    if isinstance(confidence, bool) or not isinstance(confidence, (int, float)) \
            or not 0 < confidence < 1:
        raise ValueError(f"confidence must be a number in (0, 1), got {confidence!r}")
    w = np.atleast_1d(np.asarray(walked))
    if w.ndim != 1 or not np.issubdtype(w.dtype, np.number) or np.any(~np.isfinite(w)) \
            or np.any(w != np.round(w)) or np.any(w < 0) or np.any(w > max_steps):
        raise ValueError(f"walked must be whole numbers of steps in [0, max_steps = "
                         f"{max_steps}], one per run")
    walked = w.astype(np.int64)
    failed = np.atleast_1d(np.asarray(failed, bool))
    if failed.shape != walked.shape:
        raise ValueError(f"failed must have one entry per run ({walked.size}), got shape "
                         f"{failed.shape}")
    F = int(failed.sum())
    W = int(walked.sum())
    E = W + F
    a = 1 - confidence
    p = F / E if E else math.nan
    p_lo = chi2_quantile(a / 2, 2 * F) / (2 * E) if F else 0.0
    p_hi = chi2_quantile(1 - a / 2, 2 * F + 2) / (2 * E) if E else 1.0
    p_hi = min(p_hi, 1.0)

    def mf(x):
        return math.inf if x <= 0 else (1 - x) / x

    mfpt = mf(p) if F else math.inf
    surv = [float(np.mean(walked >= k)) for k in range(max_steps + 1)]
    msg = (f"{F} of {walked.size} runs failed; per-step failure probability {p:.3g} "
           f"[{p_lo:.3g}, {p_hi:.3g}], MFPT {mfpt:.4g} steps [{mf(p_hi):.4g}, {mf(p_lo):.4g}]"
           if F else f"no run of {walked.size} failed in {max_steps} steps: per-step failure "
                     f"probability below {p_hi:.3g}, MFPT above {mf(p_hi):.4g} steps "
                     f"({100 * confidence:g} %)")
    return MFPTEstimate(failures=F, censored=int((~failed).sum()), steps_walked=W,
                        steps_attempted=E, failure_probability=p,
                        failure_probability_ci=[p_lo, p_hi], mfpt=mfpt,
                        mfpt_ci=[mf(p_hi), mf(p_lo)],
                        mean_steps_walked=float(walked.mean()) if walked.size else math.nan,
                        survival=surv, message=msg)


