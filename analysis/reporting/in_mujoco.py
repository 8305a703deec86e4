"""The report's section "In MuJoCo" (from the summary's ``mujoco`` record, written by
:mod:`analysis.pipeline.mujoco`) and its figure's caption."""
from __future__ import annotations

import math

__all__ = ["mujoco_lines", "mujoco_caption", "agreement_sentence"]

#: a fit whose relative residual is above this explains less than half the variance
NOISY_FIT = 0.7
#: a max|lambda| whose bootstrap spread is above this is not determined by the rollouts
LOOSE_FIT = 0.1


def _f(x, fmt=".3g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return format(x, fmt)


def _pct(x) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{100 * x:+.1f} %"


def _ev(ev) -> str:
    out = []
    for e in ev or []:
        z = complex(*e) if isinstance(e, (list, tuple)) else complex(e)
        out.append(f"{z.real:.2f}" if abs(z.imag) < 5e-3 else f"{z.real:.2f}{z.imag:+.2f}i")
    return ", ".join(out) or "n/a"


def agreement_sentence(rows: list) -> str:
    """One sentence on what MuJoCo's eigenvalues say about the exact A^z, from the rows.

    Per contact: where MuJoCo's fit explains most of the step-to-step variance (relative
    residual at most :data:`NOISY_FIT`, bootstrap spread at most :data:`LOOSE_FIT`,
    rollouts walked), MuJoCo's max|lambda| beside the exact one and the largest gap; the designs whose map the engine's jitter or failed
    rollouts leave unresolved; how far MuJoCo's cycles lie from the gait's fixed point.

    Parameters
    ----------
    rows : list of dict
        The section's rows (``label``, ``contact``, ``max_abs``, ``exact_max_abs``,
        ``relative_residual``, ``stride_status``, ``cycle``).

    Returns
    -------
    str
    """
    parts = []
    for contact, name in (("stiff", "at the stiff settings"),
                          ("default", "at MuJoCo's default contact")):
        rs = [r for r in rows if r["contact"] == contact]
        if not rs:
            continue
        good = [r for r in rs if r.get("stride_status") == "ok"
                and (r.get("relative_residual") or math.inf) <= NOISY_FIT
                and (r.get("max_abs_spread") or math.inf) <= LOOSE_FIT]
        bad = [r["label"] for r in rs if r not in good]
        far = [abs(d[1]) for r in rs
               if (d := (r.get("cycle") or {}).get("section_distance")) and d[1] is not None]
        if good:
            gap = max(abs(r["max_abs"] - r["exact_max_abs"]) for r in good)
            text = (f"{name}, where MuJoCo's fit explains most of the step-to-step variance "
                    f"and pins max|λ| to ±{LOOSE_FIT:g}, its max|λ| is " + ", ".join(
                        f"{r['max_abs']:.2f} against the exact {r['exact_max_abs']:.2f} for "
                        f"{r['label']}" for r in good)
                    + f": the exact A^z is within {gap:.2g} of the engine's")
        else:
            text = (f"{name} no fit explains most of the step-to-step variance and pins "
                    f"max|λ| to ±{LOOSE_FIT:g}")
        if bad:
            text += (f", while for {', '.join(bad)} MuJoCo's jitter or failed rollouts leave "
                     "the map unresolved")
        if far:
            text += (f" (MuJoCo's cycles lie up to {max(far):.2g} rad/s in dq_u from the "
                     "gait's fixed point)")
        parts.append(text)
    s = "; ".join(parts)
    return (s[0].upper() + s[1:] + ".") if s else "MuJoCo's stride map could not be fitted."


def mujoco_lines(s: dict) -> list:
    """The section's lines (empty when the stage did not run).

    Parameters
    ----------
    s : dict
        The reproduction's summary.

    Returns
    -------
    list of str
    """
    m = s.get("mujoco") or {}
    rows = m.get("rows") or []
    if not rows:
        return []
    st = (m.get("settings") or {}).get("stiff", {})
    b = m.get("budget") or {}
    lines = ["## In MuJoCo", "",
             "Each design walked in MuJoCo (`biped mujoco`) with its exported C law in the "
             f"loop: {_f(b.get('steps'), 'd')} steps from the gait, {_f(b.get('scale_steps'), 'd')}"
             " from the paper's perturbation at scale 2, the largest scale of it walked for "
             f"{_f(b.get('scale_steps'), 'd')} steps (of {', '.join(str(x) for x in b.get('scales', []))}); "
             "at the stiff settings (dt "
             f"{_f(1e3 * st.get('timestep', math.nan), 'g')} ms, solref "
             f"{_f(1e3 * (st.get('solref') or math.nan), 'g')} ms, {_f(1e3 * st.get('foot_radius', math.nan), 'g')}"
             f" mm feet, mu {_f(st.get('mu'), 'g')}) and at MuJoCo's default contact (solref "
             "0.02 s).  Speed and period errors over the steps after 10, the worst pre-impact "
             "error after step 10; MuJoCo's limit cycle on the section tau = 0.75 T (its "
             "distance from the gait's fixed point and how well it repeats) and its "
             "stride-map eigenvalues fitted to rollouts (± a bootstrap spread of max|λ|, the "
             "fit's relative residual) beside the exact eigenvalues of A^z (virtual "
             "constraints: their one eigenvalue and 0).", "",
             "| design | contact | from the gait | speed, period error | worst error after "
             "step 10 (rad, rad/s) | scale 2 | largest scale | cycle - gait (dq_u, rad/s), "
             "jitter | MuJoCo's eigenvalues | exact |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        w, p, c = r["walk"], r["perturbed"], r.get("cycle") or {}
        dist = (c.get("section_distance") or [None, None])[1]
        jit = (c.get("jitter") or [None, None])[1]
        lines.append(
            f"| {r['label']} | {r['contact']} | {w['status']} {w['steps_walked']}/"
            f"{w['n_steps']} | {_pct(w['speed_error'])}, {_pct(w['period_error'])} | "
            f"{_f(w['worst_qu_error'], '.2g')}, {_f(w['worst_dqu_error'], '.2g')} | "
            f"{p['status']} {p['steps_walked']}/{p['n_steps']} | {_f(r['largest_scale'], 'g')} | "
            f"{_f(dist, '+.2g')}, {_f(jit, '.2g')} | {_ev(r['eigenvalues'])} "
            f"(±{_f(r['max_abs_spread'], '.1g')}, res. {_f(r['relative_residual'], '.2g')}"
            + ("" if r.get("stride_status") == "ok" else
               f"; {r['failed_rollouts']} of {r['directions']} rollouts failed")
            + f") | {_ev(r['exact'])} |")
    lines += ["", agreement_sentence(rows), ""]
    return lines


def mujoco_caption(s: dict) -> dict:
    """The section's figure: key -> (title, caption).

    Parameters
    ----------
    s : dict
        The reproduction's summary.

    Returns
    -------
    dict
    """
    if not (s.get("mujoco") or {}).get("rows"):
        return {}
    return {"mujoco": ("In MuJoCo: eigenvalues and errors",
                       "Left: MuJoCo's stride-map eigenvalues on the section tau = 0.75 T "
                       "(filled circles: stiff settings; open squares: MuJoCo's default "
                       "contact) beside the exact eigenvalues of A^z (crosses), one colour "
                       "per design, the unit circle grey.  Right: |dq_u - dq_u^d(T)| at each "
                       "touchdown of the walk from the gait (solid: stiff, dashed: default).")}
