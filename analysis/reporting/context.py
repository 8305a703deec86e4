"""The state a reproduction's stages share: the run's options, where figures are staged,
the summary being written, data handed from stage to stage, and the cache of its long
computations (:meth:`Context.memo`)."""
from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from biped_casadi import RABBIT_DESCRIPTION
from biped_casadi.caching import DiskCache, claimed, shared_result, source_digest

__all__ = ["Context", "RESULTS", "FORMATS", "is_rabbit", "claimed"]

#: every figure is written in these formats
FORMATS = ("png", "pdf")

#: the reproduction's long computations kept between runs (M1 NLP, s*, basins,
#: simulations): pickles in the cache folder, named by the digest of their inputs and of
#: the toolkit's source, so a run by other code recomputes them; any run of any mode
#: reuses what another computed with the same inputs
RESULTS = DiskCache("reproduce", version=1)


@dataclass
class Context:
    out: Path                     # where this run's figures and files are staged
    opts: object                  # ReproduceOptions
    sweeps: Path = None           # persistent sweep folders of the run's mode
    summary: dict = field(default_factory=dict)
    figures: dict = field(default_factory=dict)
    data: dict = field(default_factory=dict)
    model: object = None
    gait: object = None
    stage: str = ""               # the stage running now
    reused: dict = field(default_factory=dict)
    helped: dict = field(default_factory=dict)     # results the helper process computed
    started: float = field(default_factory=time.time)

    def log(self, msg):
        if self.opts.progress:
            print(msg, file=sys.stderr, flush=True)

    def memo(self, name: str, inputs: dict, compute, claim: bool = True):
        """``compute()``, or its result kept by an earlier run with the same inputs and
        the same code (:data:`RESULTS`); what was reused is listed per stage in
        summary.json (``reused``; ``helped``: what the helper process computed for this
        run).  ``claim=False``: no claim on the whole result (its parts are shared
        between the processes on their own)."""
        body = dict(name=name, inputs=inputs, code=source_digest(),
                    robot=self.model.params.to_dict() if self.model is not None else None)
        path = RESULTS.path(body, suffix=".pkl")
        value, read = shared_result(path, compute, claim)
        if read:
            # written since this run began: the helper process's, else reused
            with contextlib.suppress(OSError):
                mine = path.stat().st_mtime >= self.started
                (self.helped if mine else self.reused).setdefault(self.stage, []).append(name)
        return value

    def sweep_dir(self, name: str, *settings) -> Path:
        """The sweep folder of ``name`` made with ``settings`` (part of the folder name,
        so a run with other settings never meets a folder it would refuse)."""
        return self.sweeps / "_".join([name, *(format(v, "g") if isinstance(v, float)
                                               else str(v) for v in settings)])




def is_rabbit(ctx) -> bool:
    """Whether the paper's published (RABBIT) numbers apply."""
    return ctx.model is not None and ctx.model.description == RABBIT_DESCRIPTION
