"""The MuJoCo settings every command that runs MuJoCo takes: contact, time step, feet,
friction."""
from __future__ import annotations

import argparse

from biped_casadi.mujoco import CONES, CONTACTS, ContactSettings
from biped_casadi.simulation.options import friction_of

from .common import MU_HELP, UserError

__all__ = ["add_mujoco_settings", "mujoco_settings", "settings_error", "AUTO", "cone_text"]


#: the value of ``--timestep`` that lets ``biped mujoco`` choose it
AUTO = "auto"


def _timestep(text: str):
    """A time step in seconds, or :data:`AUTO`."""
    if text == AUTO:
        return AUTO
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a time step in seconds or '{AUTO}', got "
                                         f"{text!r}") from None


def _solref(text: str):
    """A contact time constant in seconds, or :data:`AUTO`."""
    if text == AUTO:
        return AUTO
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a time constant in seconds or '{AUTO}', got "
                                         f"{text!r}") from None


def add_mujoco_settings(p, mu: bool = True, auto: bool = False, gait: bool = True):
    """``--contact``, ``--timestep``, ``--solref``, ``--foot-radius`` (and ``--mu``, by
    default the gait's when the command walks one, see :func:`gait_settings`); with
    ``auto``, ``--timestep auto`` and ``--solref auto`` too."""
    p.add_argument("--contact", choices=CONTACTS, default="stiff",
                   help="stiff: solref 4 ms, time step 2 ms (recommended); default: MuJoCo's "
                        "contact (solref 0.02 s) (both with 5 mm feet, mu 0.6)")
    if auto:
        p.add_argument("--timestep", type=_timestep, metavar="S",
                       help="MuJoCo's time step, s, 1e-05 to 0.05 (default 0.002); 'auto': "
                            "0.002, and when the walk fails there, or its landings bounce "
                            "(move the new stance foot more than 1 %% of the step), but it "
                            "walks at a half or a quarter of it, that time step (the first "
                            "whose landings stay within 1 %%, else the finest that walks)")
    else:
        p.add_argument("--timestep", type=float, metavar="S",
                       help="MuJoCo's time step, s, 1e-05 to 0.05 (default 0.002)")
    solref = ("the contact's time constant, s, two time steps to 1 (default 0.004 with "
              "--contact stiff, MuJoCo's 0.02 with default)")
    if auto:
        p.add_argument("--solref", type=_solref, metavar="S",
                       help=solref + "; 'auto': that default (raised to two time steps "
                            "when --timestep is coarser), and when the walk fails there "
                            "but walks with a contact 1.5 or 2 times softer at the same time "
                            "step, that contact (after --timestep auto's finer time step, "
                            "when both are auto)")
    else:
        p.add_argument("--solref", type=float, metavar="S", help=solref)
    p.add_argument("--foot-radius", type=float, metavar="M",
                   help="radius of the sphere feet, m (default 0.005)")
    p.add_argument("--integrator", choices=("Euler", "implicitfast", "implicit", "RK4"),
                   help="MuJoCo's integrator (default MuJoCo's, Euler)")
    p.add_argument("--cone", choices=CONES,
                   help="MuJoCo's friction cone (default MuJoCo's, pyramidal, whose contact's "
                        "softness depends on mu; elliptic: independent of mu)")
    if mu:
        p.add_argument("--mu", type=float, metavar="MU",
                       help=f"friction coefficient of feet and floor ({MU_HELP})" if gait
                       else "friction coefficient of feet and floor (default 0.6)")


#: the fields of the settings, each set by the option of its name
_FIELDS = ("contact", "timestep", "solref", "foot_radius", "mu", "integrator", "cone")


def cone_text(settings: dict) -> str:
    """', elliptic cone' for the status line of settings with MuJoCo's elliptic cone, ''
    with its default pyramidal one."""
    return ", elliptic cone" if settings.get("cone") == "elliptic" else ""


def settings_error(e: ValueError) -> UserError:
    """A ValueError about a setting ('foot_radius must ...') as the option that set it
    ('--foot-radius must ...'); any other as it is."""
    name, _, rest = str(e).partition(" ")
    if name in _FIELDS:
        return UserError(f"--{name.replace('_', '-')} {rest}")
    return UserError(str(e))


def gait_settings(args, settings: ContactSettings, gait) -> ContactSettings:
    """``settings`` with the floor's friction the one ``gait`` was optimised for when
    ``--mu`` is not given (else 0.6), as the simulators judge it."""
    if args.mu is not None:
        return settings
    args.mu = friction_of(gait)
    return mujoco_settings(args)


def mujoco_settings(args) -> ContactSettings:
    """The settings of the options (UserError naming the option MuJoCo would reject);
    ``--timestep auto`` and ``--solref auto`` start from the defaults (``--solref auto``
    from the contact's default raised to two of the time steps asked for, the stiffest
    contact MuJoCo takes as given)."""
    timestep = None if args.timestep == AUTO else args.timestep
    solref = None if args.solref == AUTO else args.solref
    if args.solref == AUTO and isinstance(timestep, (int, float)) and timestep > 0:
        default = ContactSettings.of(args.contact).solref
        if default is not None and default < 2 * timestep:
            solref = float(f"{2 * timestep:.12g}")
    try:
        return ContactSettings.of(args.contact, timestep=timestep, solref=solref,
                                  foot_radius=args.foot_radius,
                                  mu=getattr(args, "mu", None), integrator=args.integrator,
                                  cone=args.cone)
    except ValueError as e:
        raise settings_error(e) from None
