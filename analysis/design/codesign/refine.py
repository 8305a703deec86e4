"""The start screen refined where the target is: a local search on the walker's own
measures.

The start screen (:mod:`.starts`) draws M1 in a box and bisects the s* of those whose
run from the paper's perturbation converges soonest.  On some gaits (RABBIT at 0.5 m/s
moved to the robust gait constraints, a five-link walker without rotors) the M1 whose
paper run is below the tolerance by the target's step (5) are a few in 10^4 draws and
lie in narrow pockets, so the box rarely puts one with s* >= 1 among the screened:
fast convergence and a large s* are not in conflict there, they are only rare together.

The refinement searches near the best starts instead of in the box, with the target's
own measures, round after round (:func:`refine_starts`):

1. the elite: the starts whose paper run converges by ``converge_by``, best s* first
   (when there are too few, those that converge soonest);
2. draws around them, normal with a radius per component (``refine_radius`` x the
   gait's scale of :func:`~.starts.gait_scale`, shrinking by ``refine_shrink`` each
   round), seeded (the result is a pure function of its inputs);
3. those stable with max|lambda| within the bound whose paper run converges by
   ``converge_by`` (:func:`refine_draws`, the walker of the screen);
4. their s* by the screen's bisection (:func:`~.starts.screen_batch`, side by side in
   parts); they join the pool.

It stops when a start meets the target with a margin (s* at least ``refine_stop``),
when a round draws nothing that converges in time, when a round adds no better start
twice in a row, or after ``refine_rounds`` rounds.
"""
from __future__ import annotations

import numpy as np

from biped_casadi.simulation import zero_dynamics_walker

from ...stability.poincare import poincare_map
from ...tasks import task
from .starts import gait_scale, paper_convergence, screen_batch

__all__ = ["refine_draws", "refine_starts", "Pool"]


class Pool:
    """The starts measured so far, and per start the screen's figures.

    Parameters
    ----------
    M : array_like
        (m, nu) the starts.
    s_star : array_like
        (m,) their s* (to the screen's resolution).
    s_fail : array_like
        (m,) the scale where each failed.
    cause : list of str
        (m,) why each failed there.
    frac : array_like
        (m,) the fraction of directions passing at ``s_fail``.
    conv : array_like
        (m,) the step from which the paper's perturbation stays below the tolerance
        (inf: not within the steps walked).
    sources : list of str
        (m,) where each came from ('sample', 'refined', ...).
    """

    def __init__(self, M, s_star, s_fail, cause, frac, conv, sources):
        self.M = np.asarray(M, float).reshape(len(s_star), -1)
        self.s_star, self.s_fail = np.asarray(s_star, float), np.asarray(s_fail, float)
        self.cause, self.frac = list(cause), np.asarray(frac, float)
        self.conv, self.sources = np.asarray(conv, float), list(sources)

    def add(self, M, measured, source: str):
        """Add starts and their figures.

        Parameters
        ----------
        M : array_like
            (k, nu) the starts.
        measured : tuple
            Their :func:`~.starts.screen_batch` figures (s*, s_fail, cause, fraction,
            convergence step).
        source : str
            Where they came from.
        """
        s, sf, cause, frac, conv = measured
        self.M = np.vstack([self.M, M])
        self.s_star, self.s_fail = np.r_[self.s_star, s], np.r_[self.s_fail, sf]
        self.cause += list(cause)
        self.frac, self.conv = np.r_[self.frac, frac], np.r_[self.conv, conv]
        self.sources += [source] * len(s)

    def best_target(self, by: int) -> float:
        """The best s* of the starts whose paper run converges by step ``by``.

        Parameters
        ----------
        by : int
            The step.

        Returns
        -------
        float
            That s*, 0 when none converges by then.
        """
        ok = self.conv <= by
        return float(self.s_star[ok].max()) if ok.any() else 0.0

    def elite(self, k: int, by: int) -> np.ndarray:
        """The starts to draw around.

        Parameters
        ----------
        k : int
            How many.
        by : int
            The target's step.

        Returns
        -------
        numpy.ndarray
            (k, nu): those converging by ``by``, best s* first, then those converging
            soonest.
        """
        fast = self.conv <= by
        order = np.lexsort((-self.frac, -self.s_star, np.where(fast, 0.0, self.conv), ~fast))
        return self.M[order[:k]]


@task
def refine_draws(gait, rejoin: float, elite, radius, draws: int, seed: int,
                 eigen_bound: float, settings, rk4_steps: int, converge_by: int) -> np.ndarray:
    """Draws around the elite whose design is stable within the bound and whose run from
    the paper's perturbation converges by step ``converge_by``.

    Parameters
    ----------
    gait : Gait
        The gait.
    rejoin : float
        Rejoin time of v_c, fraction of T.
    elite : array_like
        (k, nu) the starts drawn around.
    radius : array_like
        (nu,) standard deviation of the draws per component.
    draws : int
        Draws in all (split evenly among the elite).
    seed : int
        Seed of the draws.
    eigen_bound : float
        The bound on max ``|lambda|``.
    settings : RobustnessSettings
        The protocol (steps, tolerance, mu, torque limit).
    rk4_steps : int
        RK4 steps per T of the walker.
    converge_by : int
        The target's step.

    Returns
    -------
    numpy.ndarray
        (m, nu) the draws kept, soonest converging first.
    """
    elite = np.atleast_2d(np.asarray(elite, float))
    nu = elite.shape[1]
    rng = np.random.default_rng(seed)
    per = max(int(draws) // len(elite), 1)
    M = np.repeat(elite, per, 0) + rng.normal(0.0, 1.0, (len(elite) * per, nu)) * radius
    jb = poincare_map(gait, rejoin=rejoin).jacobian_batch(M)
    idx = np.flatnonzero((jb.status == "stable") & (jb.max_abs <= eigen_bound))
    if not idx.size:
        return np.zeros((0, nu))
    w = zero_dynamics_walker(gait, settings.simulation_options(), rk4_steps, jit=True)
    conv = paper_convergence(w, gait, M[idx], rejoin, settings)
    keep = np.flatnonzero(conv <= converge_by)
    return M[idx[keep[np.argsort(conv[keep], kind="stable")]]]


def refine_starts(engine, gait, kept, rejoin: float, sampling, eigen_bound: float,
                  settings, pool: Pool, converge_by: int, parts: int = 2) -> dict:
    """The pool refined by a local search (module docstring), in place.

    Parameters
    ----------
    engine : Engine
        Where the draws and the bisections run.
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions.
    rejoin : float
        Rejoin time of v_c.
    sampling : StartSampling
        The refinement's settings (``refine_*``), the screen's walker and bisection.
    eigen_bound : float
        The bound on max ``|lambda|``.
    settings : RobustnessSettings
        The protocol.
    pool : Pool
        The screened starts; the refined ones join it.
    converge_by : int
        The target's step.
    parts : int
        Bisections side by side.

    Returns
    -------
    dict
        What the refinement did: ``rounds``, ``bisected``, the best s* of the starts
        converging by ``converge_by`` before and after (``best_before``,
        ``best_after``), why it stopped (``stopped``) and, per round, the draws that
        converged in time (``converging_draws``).
    """
    st = sampling
    scale = gait_scale(gait)
    before = best = pool.best_target(converge_by)
    rounds, bisected, stale, why, found = 0, 0, 0, f"{st.refine_rounds} rounds", []
    for r in range(st.refine_rounds):
        if best >= st.refine_stop:
            why = f"s* {best:.3g} >= {st.refine_stop:g}"
            break
        radius = st.refine_radius * st.refine_shrink ** r * scale
        M = engine.submit(refine_draws, gait, rejoin, pool.elite(st.refine_elite, converge_by),
                          radius, st.refine_draws, st.seed + 1 + r, eigen_bound, settings,
                          st.screen_rk4, converge_by).result()
        rounds += 1
        found.append(len(M))
        if not len(M):
            # no draw near the best starts converges in time: the pockets are not there
            why = f"no draw converges by step {converge_by} near the best starts"
            break
        M = M[:st.refine_bisected]
        if len(M):
            chunks = np.array_split(np.arange(len(M)), max(1, min(parts, len(M))))
            refs = [engine.submit(screen_batch, gait, kept, M[ch], rejoin, st, settings)
                    for ch in chunks]
            got = [ref.result() for ref in refs]
            pool.add(M, (np.concatenate([g[0] for g in got]),
                         np.concatenate([g[1] for g in got]), [c for g in got for c in g[2]],
                         np.concatenate([g[3] for g in got]),
                         np.concatenate([g[4] for g in got])), "refined")
            bisected += len(M)
        new = pool.best_target(converge_by)
        stale = 0 if new > best else stale + 1
        best = new
        if stale >= 2:
            why = "no better start in two rounds"
            break
    else:
        if best >= st.refine_stop:
            why = f"s* {best:.3g} >= {st.refine_stop:g}"
    return dict(rounds=rounds, bisected=bisected, best_before=before, best_after=best,
                stopped=why, converging_draws=found)
