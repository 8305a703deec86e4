"""The start screen: the co-design's first M1 chosen on the gait it runs on.

:func:`fitted_starts` draws the candidates of :mod:`.starts` (samples scaled to the gait,
the deadbeat NLP's designs, M1 that mimic the virtual constraints), walks those stable
within the eigenvalue bound from the paper's perturbation, bisects the s* of the best,
refines near them when none converges in time (:mod:`.refine`) and ranks them by the
target.
"""
from __future__ import annotations

import numpy as np

from .refine import Pool, refine_starts
from .starts import StartScreen, screen_batch, screen_binds, start_candidates

__all__ = ["fitted_starts"]


def fitted_starts(engine, gait, kept, rejoin: float, sampling, eigen_bound: float,
                  settings, extra=(), parts: int = 2, converge_by: int = 4,
                  target_only: bool = False) -> StartScreen:
    """Starts that fit the gait, screened by the walker's s* (module docstring).

    The candidates (:func:`start_candidates`), their s* in ``parts`` batches side by
    side (:func:`screen_batch`), the best ``sampling.kept`` kept and what stops the best.

    Parameters
    ----------
    engine : Engine
        Where the batches run.
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions (the paper's first).
    rejoin : float
        Rejoin time of v_c, fraction of T.
    sampling : StartSampling
        Samples, box (in units of :func:`gait_scale`), seed, starts kept, starts
        bisected and in how many rounds.
    eigen_bound : float
        The bound on max ``|lambda|``.
    settings : RobustnessSettings
        The protocol (steps, tolerance, mu, torque limit).
    extra : array_like, optional
        (k, nu) more starts (the deadbeat NLP's, the user's).
    parts : int
        Batches screened side by side.
    converge_by : int
        The target's step: starts whose paper perturbation converges by it with s* >= 1
        rank first, then those with s* >= 1 by that step, then by s*.
    target_only : bool
        Only a start that meets the target matters (the gait is given up otherwise):
        when the paper's perturbation converges from none of the stable starts, the
        screen ends there (status 'none') without bisecting them.

    Returns
    -------
    StartScreen
    """
    st, rs, nu = sampling, settings, gait.model.nu
    c = engine.submit(start_candidates, gait, rejoin, st, eigen_bound,
                      np.asarray(extra, float).reshape(-1, nu), rs).result()
    M, src = c["M1"], c["sources"]
    if not len(M):
        return StartScreen("none", f"no start of {c['candidates']} is stable with "
                           f"max|lambda| <= {eigen_bound:.3g}", np.zeros((0, nu)), np.zeros(0),
                           [], c["candidates"], 0, 0,
                           dict(binds="no stable M1 within the eigenvalue bound"), c["scale"])
    if target_only and not c["paper_converges"]:
        why = (f"the paper's perturbation converges from none of the {c['stable']} stable "
               f"starts within {rs.steps} steps (convergence)")
        return StartScreen("none", f"no start meets the target: {why}", np.zeros((0, nu)),
                           np.zeros(0), [], c["candidates"], c["stable"], 0,
                           dict(binds=why), c["scale"])
    chunks = [ch for ch in np.array_split(np.arange(len(M)), max(1, min(parts, len(M))))]
    refs = [engine.submit(screen_batch, gait, kept, M[ch], rejoin, st, rs) for ch in chunks]
    parts_ = [r.result() for r in refs]
    pool = Pool(M, np.concatenate([p[0] for p in parts_]),
                np.concatenate([p[1] for p in parts_]), [x for p in parts_ for x in p[2]],
                np.concatenate([p[3] for p in parts_]), np.concatenate([p[4] for p in parts_]),
                src)
    refined = {}
    if st.refine_rounds and pool.best_target(converge_by) < 1.0 \
            and float(pool.s_star.max()) >= st.refine_from:
        # the gait carries the scale but no screened start converges in time: search near
        # the best starts (:mod:`.refine`)
        refined = refine_starts(engine, gait, kept, rejoin, st, eigen_bound, rs, pool,
                                converge_by, parts)
    M, s_star, s_fail, cause = pool.M, pool.s_star, pool.s_fail, pool.cause
    frac, conv, src = pool.frac, pool.conv, pool.sources
    # the target first; then, of the starts with s* >= 1, those whose paper perturbation
    # converges soonest (the target's other half); then s*
    target = (conv <= converge_by) & (s_star >= 1.0)
    far = s_star >= 1.0
    order = np.lexsort((-frac, -s_star, np.where(far, conv, np.inf), ~far, ~target))
    top = order[:st.kept]
    b = int(order[0])
    best = dict(M1=M[b].tolist(), s_star=float(s_star[b]), s_fail=float(s_fail[b]),
                cause=cause[b], source=src[b],
                paper_converged_from=float(conv[b]) if np.isfinite(conv[b]) else None)
    if np.isfinite(s_fail[b]):
        best.update(engine.submit(screen_binds, gait, kept, M[b], rejoin, float(s_fail[b]),
                                  st, rs).result())
    best.setdefault("binds", "nothing within the largest scale tried")
    walks = bool(s_star[b] > 0)
    msg = (f"best of {len(M)} screened starts ({best['source']}): s* {best['s_star']:.3g}"
           + (f", stopped just above by {best['binds']}" if np.isfinite(best["s_fail"])
              else "") + (f"; refined in {refined['rounds']} round(s) ({refined['stopped']})"
                          if refined else ""))
    return StartScreen("walks" if walks else "none", msg, M[top], s_star[top],
                       [src[i] for i in top], c["candidates"], c["stable"], len(M), best,
                       c["scale"], refined)
