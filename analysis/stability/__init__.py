"""Stability: the restricted Poincaré map of the hybrid zero dynamics and its exact
Jacobian A^z (AD through the map, or the variational equation along the orbit), and the
one-dimensional map of virtual constraints; the step-to-step map of the full-order closed
loop with its exact Jacobians; the stride map over a cycle of domains (walking: one
domain; running: stance and flight) with its exact Jacobian, and the closed loop of a
running gait under its tracking controller."""
from .poincare import (METHODS, STATUSES, ImpactBracket, JacobianBatch, MapStep, PoincareMap,
                       PoincareResult, Screen, poincare_eigenvalues, poincare_map,
                       singular_m1_values)
from .variational import VariationalJacobian, variational_jacobian
from .step_map import StepLinearisation, StepMap, StepValue, step_map
from .hybrid_cycle import (Domain, DomainPass, HybridCycle, HybridCycleError,
                           StrideLinearisation, StrideValue)
from .cycle_domains import stance_flight_cycle, walking_cycle, walking_domain
from .running_cycle import (RunningCycle, RunningRun, RunningStability, StrideRecord,
                            finite_difference_jacobian, running_cycle, running_stability,
                            simulate_running)
from .vc_map import VCEigenResult, VirtualConstraintMap, vc_eigenvalue, vc_map

__all__ = ["PoincareMap", "PoincareResult", "JacobianBatch", "Screen", "ImpactBracket",
           "MapStep", "poincare_eigenvalues", "poincare_map",
           "singular_m1_values", "STATUSES", "METHODS", "VariationalJacobian",
           "variational_jacobian", "VCEigenResult", "VirtualConstraintMap", "vc_eigenvalue",
           "vc_map", "StepMap", "StepLinearisation", "StepValue", "step_map",
           "Domain", "DomainPass", "HybridCycle", "HybridCycleError", "StrideValue",
           "StrideLinearisation", "walking_domain", "walking_cycle", "stance_flight_cycle",
           "RunningCycle", "RunningRun", "RunningStability", "StrideRecord",
           "finite_difference_jacobian", "running_cycle", "running_stability",
           "simulate_running"]
