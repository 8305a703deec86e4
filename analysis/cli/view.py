"""``biped view``: explore a design in the browser (the optional extra ``view``).

Checks the options, loads the gait, computes the start (the sliders' reach, the first
walk), serves the page and prints one line, ``view: http://HOST:PORT``, once it is
ready; serves until interrupted (Ctrl-C or SIGTERM: exit code 0).
"""
from __future__ import annotations

import importlib.util
import signal
import socket
import time

from analysis.view import ViewSettings, serve
from biped_casadi import Design, Gains, SimulationOptions

from .common import (Progress, UserError, add_design_arguments, add_gait_arguments,
                     add_robot, check_m1_values, load_gait, MU_HELP, parse_m1, positive,
                     rejoin_fraction)
from .simulate import MAX_STEPS, _check_perturbation, _perturbation

#: what a user without the extra is told
INSTALL = 'needs the optional extra: pip install "biped-casadi[view]"'


def cmd_view(args):
    """``biped view``: check, load, start, print the address, serve until interrupted."""
    # ---- arguments (the extra is needed only to serve)
    check_m1_values(args.m1)
    _check_numbers(args)
    _check_listen(args.host, args.port)
    say = Progress("view")
    gait = load_gait(args, say)
    model = gait.model
    M1 = None if args.m1 is None else tuple(parse_m1(args.m1, model.nu).tolist())
    gains = Gains(eps=args.eps)
    if M1 is not None and Design.tv(gait, M1, args.rejoin, gains).controller_for() \
            .singularity().singular:
        raise UserError(f"--m1: M1 = {list(M1)} makes the controller singular on the "
                        "reference step (D11 - D12 M1 vanishes, eq. 24)")
    explicit = any(v is not None for v in (args.perturb, args.perturb_q, args.perturb_dq))
    perturbation = _perturbation(args, model.nq) if explicit else None
    if importlib.util.find_spec("viser") is None:
        raise UserError(INSTALL)
    settings = ViewSettings(
        gait, args.controller, M1, args.rejoin, gains, perturbation,
        SimulationOptions(steps=args.steps, mu=args.mu, torque_limit=args.torque_limit),
        replay=tuple(_replay_options(args)))

    # ---- serve
    say("computing the start (the sliders' reach, the first walk) ...")
    app = serve(settings, args.host, args.port)
    if args.port and app.server.get_port() != args.port:       # taken since the check
        app.stop()
        raise UserError(f"--port: {args.port} is in use on {args.host}")
    # Ctrl-C and SIGTERM end the serving, also in a background job (where SIGINT starts
    # out ignored); a second one while stopping is ignored
    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, _interrupt) for s in signals}
    try:
        print(f"view: {app.url}", flush=True)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        for s in signals:
            signal.signal(s, signal.SIG_IGN)
        app.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)
    return 0


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _check_numbers(args):
    """The design's and the walks' numbers, and the address (UserError)."""
    if args.mu is not None:
        positive(args.mu, "--mu")
    positive(args.eps, "--eps")
    rejoin_fraction(args.rejoin)
    if args.torque_limit is not None:
        positive(args.torque_limit, "--torque-limit")
    _check_perturbation(args)
    if not 1 <= args.steps <= MAX_STEPS:
        raise UserError(f"--steps must be between 1 and {MAX_STEPS}, got {args.steps}")
    if not 0 <= args.port <= 65535:
        raise UserError(f"--port must be between 0 (a free port) and 65535, got {args.port}")
    if not args.host.strip():
        raise UserError("--host: empty address")


def _check_listen(host: str, port: int):
    """UserError unless a server can listen on ``host``:``port`` now."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM)[0]
    except (socket.gaierror, UnicodeError) as e:
        raise UserError(f"--host: cannot listen on {host!r} "
                        f"({getattr(e, 'strerror', None) or e})") from None
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)     # as the server does
        try:
            s.bind(address)
        except OSError as e:
            what = f"--port: {port} is in use on {host}" if port else \
                f"--host: cannot listen on {host}"
            raise UserError(f"{what} ({e.strerror or e})") from None


def _replay_options(args) -> list:
    """The options of ``biped simulate`` that name the same gait and robot."""
    out = []
    if args.gait:
        out += ["--gait", args.gait]
    if args.robot:
        out += ["--robot", args.robot]
    if args.allow_open_orbit:
        out += ["--allow-open-orbit"]
    return out


def register(sub):
    p = sub.add_parser(
        "view", help="explore a design in the browser: drag M1, see max|lambda| and the walk",
        description="Serve a page (viser, on this machine by default) with the robot walking "
                    "in 3-D and the design's controls: sliders M1[1]..M1[nu] with number "
                    "boxes, max|lambda| and the eigenvalues of the exact A^z as 'biped eig' "
                    "gives them (updated at once), 'walk this M1' to run the full-order walk "
                    "that 'biped simulate' runs with the same options (outcome and step "
                    "shown, and the command that replays it), the controller (tv or vc), the "
                    "section basin when one is kept in the cache. Prints 'view: "
                    "http://HOST:PORT' when ready; Ctrl-C stops it. Needs the optional "
                    "extra: pip install \"biped-casadi[view]\".")
    add_gait_arguments(p)
    add_robot(p)
    add_design_arguments(p, m1_zero=True, rejoin_default=0.5,
                         m1_default="the most stable point of the paper's 9^nu grid whose "
                                    "walk is valid")
    p.add_argument("--steps", type=int, default=10, metavar="N",
                   help=f"steps of every walk, 1 to {MAX_STEPS} (10)")
    p.add_argument("--perturb", nargs=2, type=float, default=None,
                   metavar=("Q_ERR", "DQ_ERR"), help="start of every walk: error on every "
                   "joint (rad) and every velocity (rad/s) (default 0.001 0.01, a tenth of "
                   "the paper's)")
    p.add_argument("--perturb-q", nargs="+", type=float, metavar="Q",
                   help="error of each joint angle q1..qn, rad (instead of --perturb)")
    p.add_argument("--perturb-dq", nargs="+", type=float, metavar="DQ",
                   help="error of each joint velocity, rad/s (instead of --perturb)")
    p.add_argument("--torque-limit", type=float, metavar="U",
                   help="a walk stops with status torque_limit where some |u_i| exceeds U, "
                        "N m (default: the robot's limit)")
    p.add_argument("--mu", type=float, help=f"friction coefficient ({MU_HELP})")
    p.add_argument("--eps", type=float, default=0.02,
                   help="epsilon of the output PD, eq. (13), with Kp = 1, Kd = 2 (0.02)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=0, metavar="P",
                   help="port to listen on (default 0: a free one, printed when ready)")
    p.set_defaults(func=cmd_view)
