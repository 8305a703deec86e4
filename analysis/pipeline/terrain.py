"""The terrain stage of ``biped reproduce``: the mean first-passage time on stochastic
terrain against sigma, the exact gait sensitivity norm checked against the Monte Carlo
at small sigma, and the MFPT with a wrong torso mass for two gain sets."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from biped_casadi import SimulationOptions

from ..terrain import MonteCarloSettings, WalkerSpec, gait_sensitivity, monte_carlo, predicted_rms
from ..tasks import task
from .options import Resolution
from .paper import StageResult

__all__ = ["TerrainStage", "stage_terrain", "TERRAIN_GAINS", "mc_run", "sensitivity"]

#: the two gain sets of the model-error table (Kp, Kd, eps of eq. 13)
TERRAIN_GAINS = ((1.0, 2.0, 0.02), (1.0, 2.0, 0.2))


@dataclass
class TerrainStage(StageResult):
    """The MFPT curves, the survival runs at the largest sigma and their labels."""

    curves: dict = field(default_factory=dict)
    survival: list = field(default_factory=list)
    sigma: float = 0.0


@task
def mc_run(gait, spec: WalkerSpec, settings: MonteCarloSettings):
    """One Monte Carlo in one process (a task).

    Parameters
    ----------
    gait : Gait
        The gait.
    spec : WalkerSpec
        What walks.
    settings : MonteCarloSettings
        Runs, steps, terrain.

    Returns
    -------
    MonteCarloResult
    """
    return monte_carlo(gait, spec, settings, scheduler="inline")


@task
def sensitivity(gait, spec: WalkerSpec):
    """The exact gait sensitivity norm of a design on its gait (a task).

    Parameters
    ----------
    gait : Gait
        The gait.
    spec : WalkerSpec
        What walks.

    Returns
    -------
    GaitSensitivity
    """
    return gait_sensitivity(spec.controller_for(gait), SimulationOptions(rk4_steps=400))


def _candidates(g, m1, rb) -> list:
    """(label, gait, spec): virtual constraints and the co-design on its gait, the
    deadbeat M1 on the default gait."""
    d = rb.design
    cands = [("virtual constraints (robust gait)", rb.gait, WalkerSpec("vc")),
             ("robust design", rb.gait, WalkerSpec("tv", tuple(d.M1), d.rejoin))]
    if "group1" in m1.results:
        cands.append(("deadbeat M1 (default gait)", g,
                      WalkerSpec("tv", tuple(m1.results["group1"]))))
    return cands


@task
def stage_terrain(engine, gait_stage, m1_stage, robust_stage, res: Resolution) -> TerrainStage:
    """Beyond the initial push: the MFPT against sigma for virtual constraints and the
    co-design (on its gait) and the deadbeat M1 (default gait); the exact GSN and its
    check against the Monte Carlo's step-time RMS at sigma = 0.5 mm; the MFPT with the
    torso 20 % heavier than the controller's model for two gain sets."""
    g, m1, rb = gait_stage.result().gait, m1_stage.result(), robust_stage.result().result
    cands = _candidates(g, m1, rb)
    sigmas, runs, steps = tuple(res.terrain_sigmas), res.terrain_runs, res.terrain_steps
    mfpt_st = {sig: MonteCarloSettings(sigma=sig, runs=runs, max_steps=steps, chunk=runs)
               for sig in sigmas}
    tv = [c for c in cands if c[2].controller == "tv"]
    gsn_cands = tv if res.gsn_every_design else tv[-1:]
    gsn_st = MonteCarloSettings(sigma=5e-4, runs=runs, max_steps=steps, chunk=runs)
    # the torso 20 % heavier at the largest sigma and twice as heavy at 4 mm, two gain
    # sets (the full-order simulator on CasADi's virtual machine: for a few short runs
    # compiling a simulator per plant takes longer); without an error the gains change
    # nothing
    err_label, err_gait, err_spec = cands[1]
    err_runs = res.terrain_error_runs
    errors = ((0.0, sigmas[-1]), (0.2, sigmas[-1]), (1.0, 0.004))
    err_specs = []
    for gains in TERRAIN_GAINS:
        for scale, sig in errors:
            pl = None if scale == 0 else \
                g.model.description.scaled(torso_mass=1 + scale).to_dict()
            err_specs.append((gains, scale, WalkerSpec(
                err_spec.controller, err_spec.M1, err_spec.rejoin, gains, pl),
                MonteCarloSettings(sigma=sig, runs=err_runs, max_steps=steps,
                                   chunk=err_runs, compiled=False)))
    # everything submitted at once, then read in order
    mc = {(label, sig): engine.submit(mc_run, gg, spec, st)
          for label, gg, spec in cands for sig, st in mfpt_st.items()}
    gs = [(label, engine.submit(sensitivity, gg, spec), engine.submit(mc_run, gg, spec, gsn_st))
          for label, gg, spec in gsn_cands]
    er = [(gains, scale, sp, est, engine.submit(mc_run, err_gait, sp, est))
          for gains, scale, sp, est in err_specs]
    curves, rows, survival = _mfpt_rows(engine, cands, mfpt_st, mc, runs, steps, sigmas)
    gsn = []
    for label, s_ref, m_ref in gs:
        s, m = s_ref.result(), m_ref.result()
        pred = predicted_rms(s.linearisation, gsn_st.sigma, steps, gsn_st.transient)
        gsn.append(dict(label=label, gsn=s.gsn, spectral_radius=s.spectral_radius,
                        sigma=gsn_st.sigma, predicted_rms=pred, monte_carlo_rms=m.step_time_rms,
                        relative_difference=abs(m.step_time_rms - pred) / pred))
        engine.say(f"   {label}: GSN (ground, step time) "
                   f"{s.gsn['ground_height']['step_time']:.4g} s/m; step-time RMS at 0.5 mm: "
                   f"predicted {pred:.3g} s, Monte Carlo {m.step_time_rms:.3g} s")
    err = []
    for gains, scale, sp, est, ref in er:
        r = ref.result()
        e = r.estimate
        err.append(dict(design=err_label, gains=list(gains), torso_mass_error=scale,
                        sigma=est.sigma, mfpt=e.mfpt, mfpt_ci=e.mfpt_ci, failures=e.failures,
                        runs=est.runs, max_steps=steps, engine=sp.engine,
                        status_counts=r.status_counts, step_time_rms=r.step_time_rms,
                        failed_runs=np.flatnonzero(r.failed).tolist(),
                        steps_walked=np.asarray(r.walked).astype(int).tolist()))
    engine.say("model error: " + "; ".join(
        f"torso +{100 * r['torso_mass_error']:g} %, gains {r['gains']}: MFPT {r['mfpt']:.3g}, "
        f"step-time RMS {r['step_time_rms']:.3g} s" for r in err if r["torso_mass_error"]))
    return TerrainStage(dict(terrain=dict(sigmas=list(sigmas), runs=runs, max_steps=steps,
                                          mfpt=rows, gsn=gsn, model_error=err)),
                        curves=curves, survival=survival, sigma=sigmas[-1])


def _mfpt_rows(engine, cands, mfpt_st, mc, runs, steps, sigmas):
    curves, rows, survival = {}, [], []
    for label, _, _ in cands:
        pts = []
        for sig in mfpt_st:
            r = mc[(label, sig)].result()
            e = r.estimate
            pts.append((sig, e.mfpt, *e.mfpt_ci))
            rows.append(dict(label=label, sigma=sig, mfpt=e.mfpt, mfpt_ci=e.mfpt_ci,
                             failure_probability=e.failure_probability, failures=e.failures,
                             runs=runs, max_steps=steps, status_counts=r.status_counts))
            if sig == sigmas[-1]:
                survival.append((r, label))
        curves[label] = pts
        engine.say(f"   {label}: MFPT " + ", ".join(
            f"{p[1]:.3g}" if np.isfinite(p[1]) else f">{p[2]:.3g}" for p in pts)
            + f" steps at sigma = {', '.join(f'{1000 * v:g}' for v in sigmas)} mm")
    return curves, rows, survival
