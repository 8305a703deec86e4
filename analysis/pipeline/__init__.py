"""``biped reproduce`` as a graph of cached tasks on Dask: its stages (:mod:`.paper`,
:mod:`.walking`, :mod:`.terrain`, :mod:`.speed`), figures (:mod:`.figures`), options and
folders (:mod:`.options`) and the graph itself (:mod:`.graph`: how a stage is declared is
in :mod:`analysis.tasks`)."""
from .graph import (STAGES, THIS, Figures, Need, Outcome, ReproduceResult, Scope, Stage,
                    StageRecord, optional, reproduce)
from .options import ReproduceOptions, Resolution, run_folder

__all__ = ["reproduce", "ReproduceResult", "ReproduceOptions", "Resolution", "run_folder",
           "STAGES", "Stage", "Figures", "Need", "optional", "THIS", "Scope", "Outcome",
           "StageRecord"]
