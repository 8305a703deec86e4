"""The paper's published figures (Wang & Chevallereau), for the side-by-side tables."""
from __future__ import annotations

__all__ = ["PAPER"]

#: the paper's published figures (Wang & Chevallereau), for the side-by-side table
PAPER = dict(
    D11_T=24.2445,
    D12_T=[13.4347, 3.6283, 0.5375, 0.0410],
    singular_values=[1.8046, 6.6821, 45.1060, 592.7751],
    grid_counts=dict(stable=19, unstable=5363, singular_or_no_impact=6561 - 19 - 5363),
    example_M1=[1.9121, -4.0, -3.0, -1.4090],
    example_max_abs=0.2392,
    tv_convergence_steps=4,
)
