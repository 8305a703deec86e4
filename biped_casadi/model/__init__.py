"""The robot: its description (a TOML file or a built-in name), the legacy flat
parameters, and the symbolic model built from them as named CasADi Functions (mass
matrix, Coriolis and gravity terms, kinematics, the impact map with relabelling, ground
reaction, energies), and the flight domain with its takeoff and landing edges."""
from .biped import (B_INPUT, E_RELABEL, RABBIT_DESCRIPTION, BipedModel, absolute_angles,
                    rabbit, relabelling, resolve_robot, robot)
from .description import (BUILTIN, Link, RobotDescription, builtin_path, description_from_dict,
                          find_description, load_description)
from .flight import FlightModel, flight_model
from .params import RABBIT, RobotParams, load_params

__all__ = ["BipedModel", "rabbit", "robot", "resolve_robot", "E_RELABEL", "B_INPUT",
           "absolute_angles", "relabelling", "RABBIT_DESCRIPTION", "Link", "RobotDescription",
           "load_description", "find_description", "description_from_dict", "BUILTIN",
           "builtin_path", "RobotParams", "RABBIT", "load_params", "FlightModel", "flight_model"]
