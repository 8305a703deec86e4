"""Sweeps over M1: chunks as tasks (threads, processes or a Dask cluster), resumable, stored as
Parquet chunks; and the paper's 9^4 grid of a gait, computed once and reused."""
from .grid_cache import grid_best, grid_results
from .storage import SweepStoreError
from .sweep import (DEFAULT_CHUNK_SIZE, OneDSweeps, SweepResult, SweepSettings,
                    evaluate_chunk, grid_points, line_points,
                    load_sweep, max_grid_n, one_d_sweeps, run_sweep)

__all__ = ["run_sweep", "SweepResult", "SweepSettings", "grid_points", "line_points",
           "max_grid_n", "one_d_sweeps", "OneDSweeps", "load_sweep", "evaluate_chunk",
           "DEFAULT_CHUNK_SIZE",
           "SweepStoreError", "grid_results", "grid_best"]
