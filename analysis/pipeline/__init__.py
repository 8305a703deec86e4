"""``biped reproduce`` as a graph of cached tasks on Dask: its stages (:mod:`.paper`,
:mod:`.walking`, :mod:`.terrain`), figures (:mod:`.figures`), options and folders
(:mod:`.options`) and the graph itself (:mod:`.graph`)."""
from .graph import STAGES, ReproduceResult, Stage, reproduce
from .options import ReproduceOptions, Resolution, run_folder

__all__ = ["reproduce", "ReproduceResult", "ReproduceOptions", "Resolution", "run_folder",
           "STAGES", "Stage"]
