"""Design of the outputs: the swing-height conditions a = b = 0 and their solution groups
(paper §V-B), the M1 NLP, and the robust design that maximises the perturbation a
design survives."""
from .m1_nlp import M1Result, optimize_m1
from .output_selection import (ABGroups, ABSet, ABSolution, TaylorAB, ab_groups, ab_solution_set,
                               coarse_grid_size, conjecture_figures, domain_grid, group_of,
                               isolated_ab_solutions, solve_ab, swing_height_at_Td, taylor_ab)
from .robust_search import (ROBUST_GAIT, RobustDesignResult, RobustDesignSettings, robust_design,
                            robust_gait)

__all__ = ["optimize_m1", "M1Result", "swing_height_at_Td", "TaylorAB", "taylor_ab",
           "solve_ab", "ABSolution", "conjecture_figures", "domain_grid",
           "isolated_ab_solutions", "ab_solution_set", "ABSet", "ABGroups", "ab_groups", "group_of",
           "coarse_grid_size",
           "robust_design", "RobustDesignSettings", "RobustDesignResult", "ROBUST_GAIT",
           "robust_gait"]
