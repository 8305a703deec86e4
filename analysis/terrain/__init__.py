"""Beyond the initial push: walking on uneven ground and with a wrong model.  The mean
first-passage time by Monte Carlo on stochastic terrain (chunked, resumable, on Dask),
and the exact gait sensitivity norm of the step-to-step map."""
from .gsn import GROUND_OFFSET, GaitSensitivity, gait_sensitivity, gsn_of, predicted_rms
from .montecarlo import (MAX_RUNS, MAX_STEPS, MFPTEstimate, MonteCarloResult,
                         MonteCarloSettings, MonteCarloStore, WalkerSpec, evaluate_chunk,
                         mfpt_estimate, monte_carlo)

__all__ = ["GaitSensitivity", "gait_sensitivity", "gsn_of", "predicted_rms", "GROUND_OFFSET",
           "WalkerSpec", "MonteCarloSettings", "MonteCarloResult",
           "MFPTEstimate", "monte_carlo", "mfpt_estimate", "evaluate_chunk", "MAX_RUNS",
           "MAX_STEPS"]
