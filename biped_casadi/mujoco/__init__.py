"""Walking in MuJoCo, a physics engine nobody here wrote: the MJCF of any robot the toolkit
reads, the closed loop of the exported C law with MuJoCo's contacts, and MuJoCo's own
stride map.

Importing this package does not import ``mujoco`` (a second or so): the functions that
run MuJoCo import it when called.
"""
from .contact import FACTORS, ContactCheck, check_contact
from .law import LAWS, compiled_law, control_law
from .mjcf import (CONES, CONTACTS, MIN_INERTIA, MUJOCO_DEFAULT, STIFF, ContactSettings, Layout,
                   floating_base_inertia, layout, mjcf, torque_limit_of)
from .stride import LimitCycle, StrideMap, fit_stride_map, limit_cycle, stride_map
from .timestep import (BOUNCE_TOLERANCE, DIVISORS, TimestepCheck, check_timestep,
                       strike_velocity)
from .walk import (OUTCOMES, SETTLE, STEP_STARTS, TOUCHDOWNS, MujocoLoop, MujocoStep,
                   MujocoWalk, mujoco_module, start_of, walk)

__all__ = ["mjcf", "ContactSettings", "STIFF", "MUJOCO_DEFAULT", "CONTACTS", "CONES",
           "MIN_INERTIA",
           "Layout", "layout", "floating_base_inertia", "torque_limit_of", "LAWS",
           "control_law", "compiled_law", "walk", "MujocoLoop", "MujocoWalk", "MujocoStep",
           "OUTCOMES", "STEP_STARTS", "TOUCHDOWNS", "SETTLE", "start_of", "mujoco_module",
           "stride_map", "StrideMap", "LimitCycle", "limit_cycle", "fit_stride_map",
           "check_timestep", "TimestepCheck", "strike_velocity", "DIVISORS",
           "BOUNCE_TOLERANCE", "check_contact",
           "ContactCheck", "FACTORS"]
