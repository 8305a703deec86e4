"""Beyond the initial push: walking on uneven ground and with a wrong model.  The mean
first-passage time by Monte Carlo on stochastic terrain (chunked, resumable, on Dask),
and the exact gait sensitivity norm of the step-to-step map."""
from .gsn import GaitSensitivity, gait_sensitivity, gsn_of, predicted_rms
from .chunks import evaluate_chunk
from .estimates import MFPTEstimate, mfpt_estimate
from .montecarlo import MonteCarloResult, monte_carlo
from .spec import MAX_RUNS, MAX_STEPS, MonteCarloSettings, WalkerSpec

__all__ = ["GaitSensitivity", "gait_sensitivity", "gsn_of", "predicted_rms",
           "WalkerSpec", "MonteCarloSettings", "MonteCarloResult",
           "MFPTEstimate", "monte_carlo", "mfpt_estimate", "evaluate_chunk", "MAX_RUNS",
           "MAX_STEPS"]
