"""The rigid running model (the exact stride map's dynamics, guards and resets) under the
running controller sampled on a time grid and held over each step, as MuJoCo's loop
applies it: the experiment that separates the hold and the phase logic from MuJoCo's
contact (used by ``benchmarks/mujoco_running_gap.py``).

:class:`HeldLoop` integrates each phase with RK4 (``sub`` steps per time step, the
torque held); the guards (the stance foot's normal force, the swing foot's height) are
located inside a step by a secant search, and a torque update that makes the normal
force negative at a grid point is a takeoff there.  The law's clock:

- 'aligned': the grid restarts at each event (the hold alone);
- 'global': one grid for the run, the law's clock from the exact event times;
- 'loop': one grid; after a takeoff the stance law is kept until ``lag`` past the first
  grid point after it and the flight clock starts at that grid point (the MuJoCo loop's
  takeoff rule with ``takeoff_clock='contact'``, without the contact).

:func:`finish` runs the rigid closed loop (law every 0.25 ms) from any state of a phase
to the next landing.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from biped_casadi.model import flight_model
from biped_casadi.numerics import FastCall


class HeldLoop:
    """The rigid model under the held law (module docstring)."""

    def __init__(self, controller, sub: int = 2):
        c = self.c = controller
        m = c.model
        fl = flight_model(m)
        self.nq, self.ne, self.sub = m.nq, fl.ne, sub
        h, u = ca.SX.sym("h"), ca.SX.sym("u", m.nu)

        def rk4(n, acc, name):
            X = ca.SX.sym("X", 2 * n)

            def f(Z):
                return ca.vertcat(Z[n:], acc(Z[:n], Z[n:], u))
            k1 = f(X)
            k2 = f(X + h / 2 * k1)
            k3 = f(X + h / 2 * k2)
            k4 = f(X + h * k3)
            return FastCall(ca.Function(name, [X, u, h], [X + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)]))
        self._st = rk4(m.nq, m.forward_dynamics, "stance_step")
        self._fl = rk4(fl.ne, fl.flight_dynamics, "flight_step")
        self.st_law, self.fl_law = FastCall(c.stance_law), FastCall(c.flight_law)
        X = ca.SX.sym("X", 2 * m.nq)
        self._fz = FastCall(ca.Function("fz", [X, u], [fl.takeoff_guard(X[:m.nq], X[m.nq:], u)[0]]))
        Y = ca.SX.sym("Y", 2 * fl.ne)
        self._zsw = FastCall(ca.Function("zsw", [Y], [fl.feet(Y[:fl.ne])[1, 1]]))
        self.takeoff, self.landing = FastCall(fl.takeoff), FastCall(fl.landing_swing)

    def step(self, phase, X, u, h):
        f = self._st if phase == 0 else self._fl
        return f(X, u, h)[0].ravel()

    def guard(self, phase, X, u):
        v = self._fz(X, u) if phase == 0 else self._zsw(X)
        return float(v[0].ravel()[0])

    def cross(self, phase, X, u, h):
        """The time in (0, h] where the phase's guard crosses zero, the state there."""
        a, b = 0.0, h
        ga, gb = self.guard(phase, X, u), self.guard(phase, self.step(phase, X, u, h), u)
        s = b
        for _ in range(60):
            s = b - gb * (b - a) / (gb - ga) if gb != ga else 0.5 * (a + b)
            if not a < s < b:
                s = 0.5 * (a + b)
            gs = self.guard(phase, self.step(phase, X, u, s), u)
            if abs(gs) < 1e-10 or b - a < 1e-13:
                break
            if (gs > 0) == (ga > 0):
                a, ga = s, gs
            else:
                b, gb = s, gs
        return s, self.step(phase, X, u, s)

    def reset(self, phase, X):
        """Takeoff (stance -> flight) or landing (flight -> the next stance state)."""
        n = self.nq if phase == 0 else self.ne
        out = (self.takeoff if phase == 0 else self.landing)(X[:n], X[n:])
        return np.r_[out[0].ravel(), out[1].ravel()]

    def law(self, law_phase, X, tau):
        """The law of ``law_phase`` at X (a stance or a flight state)."""
        n = X.size // 2
        if law_phase == 0:
            return self.st_law(X[:self.nq], X[n:n + self.nq], tau)[0].ravel()
        return self.fl_law(X[:n], X[n:], tau)[0].ravel()

    def run(self, x0, strides, dt, mode="aligned", offset=None, lag=0.006):
        """Landing states (strides + 1, 2 nq) and (stance, flight) durations."""
        g = self.c.gait
        X, phase, t = np.asarray(x0, float).copy(), 0, 0.0
        t_land, t_to, clock0, law_phase, t_first = 0.0, -1.0, 0.0, 0, None
        out, durs = [X.copy()], []
        u = self.law(0, X, 0.0)
        h_next = dt if offset is None else offset
        while len(out) <= strides and t < 1e4:
            rem, h_next = h_next, dt
            while rem > 1e-15:
                hs = min(rem, dt / self.sub)
                Xn = self.step(phase, X, u, hs)
                ready = (t - t_land > 0.25 * g.T_stance) if phase == 0 \
                    else (t - t_to > 0.25 * g.T_flight)
                if ready and self.guard(phase, Xn, u) <= 0:
                    s, Xc = (0.0, X) if self.guard(phase, X, u) <= 0 and phase == 0 \
                        else self.cross(phase, X, u, hs)
                    X, t, rem = self.reset(phase, Xc), t + s, rem - s
                    if phase == 0:
                        t_to, phase = t, 1
                        durs.append([t - t_land, np.nan])
                        if mode != "loop":
                            clock0, law_phase = t, 1
                    else:
                        t_land, phase, clock0, law_phase = t, 0, t, 0
                        durs[-1][1] = t - t_to
                        out.append(X.copy())
                    if mode == "aligned":
                        rem = 0.0
                    continue
                X, t, rem = Xn, t + hs, rem - hs
            if mode == "loop" and phase == 1 and law_phase == 0:
                t_first = t if t_first is None else t_first
                if t - t_first >= lag - 1e-12:
                    clock0, law_phase, t_first = t_first, 1, None
            u = self.law(law_phase, X, t - (t_land if law_phase == 0 else clock0))
            if not np.all(np.isfinite(X)):
                break
        return np.array(out), np.array(durs)


def finish(loop: HeldLoop, X, phase, tau, h=2.5e-4):
    """The rigid closed loop from a state of a phase (law's clock tau) to the next
    landing: the landing state (NaN when none within 1 s)."""
    X, t = np.asarray(X, float).copy(), tau
    while t < 1.0:
        u = loop.law(phase, X, t)
        if phase == 0 and loop.guard(0, X, u) <= 0:
            X, phase, t = loop.reset(0, X), 1, 0.0
            continue
        Xn = loop.step(phase, X, u, h)
        if loop.guard(phase, Xn, u) <= 0 and (phase == 0 or t > 0.02):
            Xc = loop.cross(phase, X, u, h)[1]
            if phase == 1:
                return loop.reset(1, Xc)
            X, phase, t = loop.reset(0, Xc), 1, 0.0
            continue
        X, t = Xn, t + h
    return np.full(2 * loop.nq, np.nan)
