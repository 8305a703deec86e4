"""Why the exact stride map of the running controller predicts MuJoCo only partly: the
measured decomposition of docs/howto/running.md ("Where MuJoCo departs from the exact
map").

RABBIT at 1.5 m/s, PD Kp 400, Kd 30, M1 = (0, 0.95, 0.95, 0), stiff contact (solref
4 ms), at dt 2 and 1 ms, with both takeoff clocks of the loop ('contact': MuJoCo's first
zero-force state, the earlier rule; 'guard': the rigid model's takeoff guard on MuJoCo's
states, the default):

- the fit (d): MuJoCo's stride map fitted on a long run (``fit_running_map``) and the
  same fit on runs of the exact map driven by its residuals (``reference``); the exact
  map's one-stride prediction from each MuJoCo landing state against MuJoCo's next
  landing state (constraints not checked: MuJoCo's states leave them);
- where the stride-to-stride variation and the offset enter: the rigid closed loop
  (``running_rigid_hold.finish``) from MuJoCo's state at instants of each stride to the
  next landing, against MuJoCo's landing state;
- the takeoff (b): the model's guard against MuJoCo's first zero-force state
  (``takeoff_guard_gap``); the soft landing (c): penetration, the time the landing foot
  takes to stop, its slip, and MuJoCo's joint velocities 5 and 20 ms after the touchdown
  against the rigid landing map and closed loop from the same pre-touchdown state;
- the hold (a): the rigid model under the law sampled and held on MuJoCo's time grid
  (``running_rigid_hold.HeldLoop``: grid restarted at each event, one grid, the loop's
  old takeoff rule).

Run: ``python benchmarks/mujoco_running_gap.py [--out DIR] [--strides N]``; writes
``DIR/mujoco_running_gap.png`` (default docs/_static) and prints one JSON object
(20 to 40 minutes).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _results import in_checkout  # noqa: E402
from running_rigid_hold import HeldLoop, finish  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
KP, KD, STABLE = 400.0, 30.0, (0.0, 0.95, 0.95, 0.0)
TIMESTEPS = (0.002, 0.001)
CLOCKS = ("contact", "guard")
STARTS = (("landing", 0, 0.0), ("10 ms after landing", 0, 0.010),
          ("25 ms after landing", 0, 0.025), ("mid-stance", 0, 0.5),
          ("10 ms before takeoff", 1, -0.010), ("4 ms before takeoff", 1, -0.004),
          ("2 ms into flight", 1, 0.002), ("10 ms into flight", 1, 0.010),
          ("mid-flight", 1, 0.05))


def _setup():
    from biped_casadi import rabbit
    from biped_casadi.control.running import RunningController
    from gait_opt.running import RunningOptions, optimize_running
    from analysis.stability.running_cycle import running_cycle, running_stability
    m = rabbit()
    gait = optimize_running(m, RunningOptions(speed=1.5), cache=True)
    c = RunningController(m, gait, KP, KD, M1=STABLE)
    st = running_stability(running_cycle(c))
    return m, gait, c, st, running_cycle(c, tolerance=1e12)


def _spread(X, xs):
    tail = X[len(X) // 3:]
    return dict(offset=float(np.max(np.abs(tail.mean(0) - xs))),
                spread=float(np.max(tail.std(0))))


def _exact_prediction(lenient, X):
    """The exact map from each landing state against the next (d)."""
    P = []
    for x in X[1:-1]:
        try:
            P.append(lenient.stride(x).next_state)
        except Exception:                       # a state the map cannot run at all
            P.append(np.full(x.size, np.nan))
    P = np.array(P)
    ok = np.all(np.isfinite(P), axis=1)
    nxt = X[2:][ok]
    e = nxt - P[ok]
    share = e.var(0) / nxt.var(0)
    return dict(pairs=int(ok.sum()), share_unexplained_max=float(share.max()),
                share_unexplained_median=float(np.median(share)),
                error_bias_max=float(np.max(np.abs(e.mean(0)))),
                error_std_max=float(np.max(e.std(0))), next_std_max=float(np.max(nxt.std(0))))


def _state(loop, r, k, leg, flight_origin=None):
    A = loop.layout.A[leg]
    if flight_origin is None:
        return np.r_[A @ r.qpos[k][2:], A @ r.qvel[k][2:]]
    qe, dqe = loop._extended(r.qpos[k], r.qvel[k], leg, flight_origin)
    return np.r_[qe, dqe]


def _decomposition(loop, r, held, T_stance):
    """Rigid-model prediction error of the next landing from instants of each stride."""
    dt, T = loop.settings.timestep, r.t
    E = {name: [] for name, _, _ in STARTS}
    for j in range(2, len(r.strides) - 1):
        prev, s = r.strides[j - 1], r.strides[j]
        t_land, t_off = s.t_landing, s.t_landing + s.stance
        nxt = np.asarray(s.landing_state)
        for name, ref, off in STARTS:
            if name == "landing":
                X0, ph, tau = np.asarray(prev.landing_state), 0, 0.0
            else:
                tt = t_land + (off * T_stance if name == "mid-stance" else off) if ref == 0 \
                    else t_off + off
                k = int(np.ceil((tt - T[0]) / dt - 1e-9))
                leg = int(r.stance_leg[k])
                if ref == 1 and off > 0:
                    k0 = int(np.floor((t_off - T[0]) / dt))
                    origin = loop._foot(r.qpos[k0], r.qvel[k0], leg)[0]
                    X0, ph, tau = _state(loop, r, k, leg, origin), 1, T[k] - t_off
                else:
                    X0, ph, tau = _state(loop, r, k, leg), 0, T[k] - t_land
            E[name].append(nxt - finish(held, X0, ph, tau))
    out = {}
    for name, v in E.items():
        v = np.array(v)
        v = v[np.all(np.isfinite(v), axis=1)]
        out[name] = dict(n=len(v), bias_norm=float(np.linalg.norm(v.mean(0))),
                         bias_max=float(np.max(np.abs(v.mean(0)))),
                         rms=float(np.sqrt(v.var(0).sum())), std_max=float(np.max(v.std(0))))
    return out


def _impact(loop, r, held, taus=(0.005, 0.02)):
    """The soft landing against the rigid map from the same pre-touchdown state (c)."""
    dt, T, nq, rad = loop.settings.timestep, r.t, loop.model.nq, loop.settings.foot_radius
    idx = np.flatnonzero(np.diff(r.stance_leg) != 0) + 1
    rows = []
    for j, i in enumerate(idx[2:-1], start=2):
        s, leg = r.strides[j], int(r.stance_leg[i])
        t_td = s.t_landing + s.stance + s.flight
        win = range(i, min(i + int(0.05 / dt), len(T)))
        P = np.array([loop._foot(r.qpos[k], r.qvel[k], leg)[0] for k in win])
        V = np.array([loop._foot(r.qpos[k], r.qvel[k], leg)[1] for k in win])
        v0 = np.hypot(*loop._foot(r.qpos[i - 1], r.qvel[i - 1], leg)[1])
        stop = np.flatnonzero(np.hypot(V[:, 0], V[:, 1]) < 0.05 * v0)
        X, tt, gaps = np.asarray(s.landing_state), 0.0, []
        for tau in taus:
            while tt < tau - 1e-12:
                X, tt = held.step(0, X, held.law(0, X, tt), 1e-4), tt + 1e-4
            k0 = int(np.floor((t_td + tau - T[0]) / dt))
            w = (t_td + tau - T[k0]) / dt
            xm = (1 - w) * _state(loop, r, k0, leg) + w * _state(loop, r, k0 + 1, leg)
            gaps.append(xm[nq:] - X[nq:])
        rows.append((stop[0] * dt + T[i] - t_td if stop.size else np.nan, rad - P[:, 1].min(),
                     abs(P[stop[0] if stop.size else -1, 0] - P[0, 0]), gaps))
    t_stop, pen, slip = (np.array([x[k] for x in rows]) for k in range(3))
    out = dict(impact_ms=[1e3 * np.nanmedian(t_stop), 1e3 * np.nanmax(t_stop)],
               penetration_mm=[1e3 * np.median(pen), 1e3 * pen.max()],
               slip_mm=[1e3 * np.median(slip), 1e3 * slip.max()])
    for n, tau in enumerate(taus):
        G = np.array([x[3][n] for x in rows])
        out[f"dq_gap_{1e3 * tau:g}ms"] = dict(mean_max=float(np.max(np.abs(G.mean(0)))),
                                              std_max=float(np.max(G.std(0))),
                                              mean=G.mean(0).round(3).tolist())
    return out


def _mujoco(dt, strides, decomp):
    """MuJoCo at one time step, both clocks: fits, predictions, decomposition."""
    from biped_casadi.mujoco import ContactSettings
    from biped_casadi.mujoco.running import RunningLoop, fit_running_map
    m, gait, c, st, lenient = _setup()
    held, xs, out = HeldLoop(c), st.fixed_point, {}
    for clock in CLOCKS:
        loop = RunningLoop(c, ContactSettings(timestep=dt), xs, takeoff_clock=clock)
        r = loop.run(None, strides)
        f = fit_running_map(r, reference=st.A)
        late = r.strides[len(r.strides) // 3:]
        gaps = np.array([s.takeoff_guard_gap for s in r.strides])
        o = dict(status=r.status, strides=len(r.strides), fit=f.to_dict(),
                 speed=float(np.mean([s.speed for s in late])),
                 speed_range=[min(s.speed for s in late), max(s.speed for s in late)],
                 stance=float(np.mean([s.stance for s in late])),
                 flight=float(np.mean([s.flight for s in late])),
                 **_spread(r.landing_states, xs),
                 exact_prediction=_exact_prediction(lenient, r.landing_states))
        if clock == "guard":
            o["takeoff_guard_gap_ms"] = [1e3 * float(np.nanmean(gaps)), 1e3 * float(np.nanstd(gaps))]
        short = loop.run(None, decomp, log=True)
        o["decomposition"] = _decomposition(loop, short, held, gait.T_stance)
        if clock == "contact":
            o["impact"] = _impact(loop, short, held)
        out[clock] = o
    return dt, out


def _held(dt, strides):
    """The rigid model under the held law (a)."""
    from biped_casadi.mujoco.running_records import _lstsq_map, _radius
    m, gait, c, st, _ = _setup()
    held, xs, out = HeldLoop(c), st.fixed_point, {}
    for mode in ("aligned", "global", "loop"):
        X, D = held.run(xs, strides, dt, mode, offset=0.37 * dt)
        o = dict(strides=len(X) - 1, stance=float(np.mean(D[:, 0])),
                 flight=float(np.nanmean(D[:, 1])), **_spread(X, xs))
        if mode != "aligned":
            o["fit_max_abs"] = _radius(_lstsq_map(X[1:-1], X[2:])[1])
        out[mode] = o
    return dt, out


def _figure(res, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from analysis.reporting.plots import save_figure
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.8))
    names = [n for n, _, _ in STARTS]
    x = np.arange(len(names))
    for dt, style in zip(TIMESTEPS, ("-", "--")):
        for clock, col in zip(CLOCKS, ("C3", "C0")):
            d = res["mujoco"][f"{dt:g}"][clock]["decomposition"]
            lab = f"dt {1e3 * dt:g} ms, takeoff clock '{clock}'"
            ax[0].plot(x, [d[n]["rms"] for n in names], style, color=col, marker="o", ms=3, label=lab)
            ax[1].plot(x, [d[n]["bias_norm"] for n in names], style, color=col, marker="o", ms=3,
                       label=lab)
    for a, t in zip(ax[:2], ("spread: RMS over strides of the error\n(root of the summed variances)",
                             "offset: norm of the mean error")):
        a.set_xticks(x, ["landing (rigid map)" if n == "landing" else n for n in names],
                     rotation=40, ha="right", fontsize=8)
        a.set_ylabel("MuJoCo's next landing state less the rigid model's\n"
                     "(rad, rad/s: 10 components)")
        a.set_xlabel("the rigid closed loop starts from MuJoCo's state at")
        a.set_title(t, fontsize=10)
        a.grid(True, alpha=0.3)
        a.legend(fontsize=7)
    labels, fits, refs, sds = [], [], [], []
    for dt in TIMESTEPS:
        for clock in CLOCKS:
            f = res["mujoco"][f"{dt:g}"][clock]["fit"]
            labels.append(f"{1e3 * dt:g} ms\n'{clock}'")
            fits.append(f["max_abs"])
            refs.append(f["reference_max_abs"])
            sds.append((f["max_abs_spread"], f["reference_max_abs_spread"]))
    k = np.arange(len(labels))
    ax[2].bar(k - 0.2, fits, 0.4, yerr=[s[0] for s in sds], label="fitted on MuJoCo's landing states")
    ax[2].bar(k + 0.2, refs, 0.4, yerr=[s[1] for s in sds],
              label="same fit on the exact map + MuJoCo's residuals")
    ax[2].axhline(res["exact_radius"], color="k", ls=":", label=f"exact map {res['exact_radius']:.3f}")
    ax[2].set_xticks(k, labels, fontsize=8)
    ax[2].set_ylabel("max |lambda| of the fitted stride map")
    ax[2].set_title(f"least-squares stride map, {res['strides']} strides (+- bootstrap / replicas)",
                    fontsize=10)
    ax[2].set_ylim(0, 1)
    ax[2].legend(fontsize=7, loc="upper left")
    fig.suptitle("RABBIT running 1.5 m/s in MuJoCo (solref 4 ms) against the exact stride map: "
                 "where the difference enters, and what the fit reports", fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "_static"))
    ap.add_argument("--strides", type=int, default=300, help="strides of the fitted runs")
    ap.add_argument("--decomp", type=int, default=40, help="strides of the decomposition")
    ap.add_argument("--held", type=int, default=200, help="strides of the held rigid runs")
    ap.add_argument("--replot", metavar="JSON", help="draw the figure from a saved output")
    args = ap.parse_args(argv)
    if args.replot:
        res = json.loads(Path(args.replot).read_text())
        print(_figure(res, Path(args.out) / "mujoco_running_gap.png"))
        return
    t0 = time.perf_counter()
    st = _setup()[3]
    res = dict(exact_radius=st.spectral_radius, strides=args.strides, mujoco={}, held={})
    with ProcessPoolExecutor(2) as ex:
        jobs = [ex.submit(_mujoco, dt, args.strides, args.decomp) for dt in TIMESTEPS]
        jobs += [ex.submit(_held, dt, args.held) for dt in TIMESTEPS]
        for j in jobs[:2]:
            dt, o = j.result()
            res["mujoco"][f"{dt:g}"] = o
        for j in jobs[2:]:
            dt, o = j.result()
            res["held"][f"{dt:g}"] = o
    Path(args.out).mkdir(parents=True, exist_ok=True)
    res["figure"] = [in_checkout(f) for f in
                     _figure(res, Path(args.out) / "mujoco_running_gap.png")]
    res["wall_time"] = time.perf_counter() - t0
    from biped_casadi.results import json_safe
    print(json.dumps(json_safe(res), indent=1))


if __name__ == "__main__":
    main()
