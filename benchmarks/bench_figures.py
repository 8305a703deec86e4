"""The figures of ``biped reproduce --quick``, timed on their own: every figure task
(``@task(code="figures")``) called on the stage results of one quick run, in one process,
this version against a baseline, and the files compared (PNG pixels, PDF page size).

    python benchmarks/bench_figures.py --baseline-commit c6f1ac9
    python benchmarks/bench_figures.py --baseline-commit c6f1ac9 --repeats 5 --keep /tmp/figs

The stage results are recorded once (a quick run of this version with the figure tasks'
arguments pickled as they are submitted; ``$BIPED_CACHE_DIR`` warm makes it quick), then
each version draws every figure ``--repeats`` times in a fresh process (CPU seconds of
each task, the least of the repeats).  Versions run from snapshots (``git archive REV`` for
the baseline, the working tree for this one), by this interpreter.  Results are saved in
benchmarks/results/figures.json.
"""
from __future__ import annotations

import argparse
import io
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402
from bench_reproduce import snapshot  # noqa: E402


def record(out: str):
    """(In a child process) a quick run whose figure tasks' arguments are pickled to
    ``out`` as (module, name, args, kwargs) when they are submitted."""
    from analysis.cli import main as cli
    from analysis.tasks import engine as E
    calls, start = [], E.Engine._start

    def _start(self, fn, args, kwargs, flow):
        if not flow and E._info(fn).code == "figures":
            got = [E._unpack(E._pack(x, lambda f: f.result())) for x in (args, kwargs)]
            calls.append((fn.__module__, fn.__name__, *got))
        return start(self, fn, args, kwargs, flow)

    E.Engine._start = _start
    with tempfile.TemporaryDirectory() as tmp:
        code = cli(["reproduce", "--quick", "--workers", "1", "--no-progress", "--out", tmp])
    Path(out).write_bytes(pickle.dumps(calls))
    return code


def draw(calls_file: str, repeats: int, keep: str, out: str):
    """(In a child process) every recorded figure task ``repeats`` times: its CPU and
    wall seconds (least of the repeats) to ``out``; its files into ``keep``."""
    import importlib
    calls = pickle.loads(Path(calls_file).read_bytes())
    times = {}
    for mod, name, args, kwargs in calls:
        fn = importlib.import_module(mod).__dict__[name]
        fn = getattr(fn, "__wrapped__", fn)
        cpu, wall = [], []
        for _ in range(repeats):
            c, w = time.process_time(), time.perf_counter()
            files = fn(*args, **kwargs)
            cpu.append(time.process_time() - c)
            wall.append(time.perf_counter() - w)
        times[name] = dict(cpu=min(cpu), wall=min(wall), cpu_all=cpu)
        for fig, by_fmt in files.items():
            for ext, data in by_fmt.items():
                (Path(keep) / f"{fig}.{ext}").write_bytes(data)
    Path(out).write_text(json.dumps(times))


def _pdf_box(data: bytes):
    import re
    m = re.search(rb"/MediaBox\s*\[\s*([-\d.\s]+)\]", data)
    return [float(v) for v in m.group(1).split()] if m else None


def compare(ours: Path, base: Path) -> dict:
    """Per file: PNG size and the largest pixel difference; PDF page size."""
    import numpy as np
    from PIL import Image
    out = {}
    for f in sorted(base.iterdir()):
        g = ours / f.name
        if not g.exists():
            out[f.name] = "missing"
            continue
        if f.suffix == ".png":
            a = np.asarray(Image.open(io.BytesIO(f.read_bytes())).convert("RGBA"), int)
            b = np.asarray(Image.open(io.BytesIO(g.read_bytes())).convert("RGBA"), int)
            row = dict(size=[list(a.shape[:2]), list(b.shape[:2])])
            if a.shape == b.shape:
                d = np.abs(a - b).max(axis=2)
                row.update(max_diff=int(d.max()), pixels_differing=int((d > 0).sum()))
            out[f.name] = row
        elif f.suffix == ".pdf":
            out[f.name] = dict(mediabox=[_pdf_box(f.read_bytes()), _pdf_box(g.read_bytes())])
        else:
            out[f.name] = dict(identical=f.read_bytes() == g.read_bytes())
    return out


def _child(packages: Path, *args) -> None:
    path = [str(packages)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=os.pathsep.join(path))
    subprocess.run([sys.executable, __file__, *args], env=env, check=True, cwd=packages)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline-commit", metavar="REV", help="the version to compare with")
    ap.add_argument("--repeats", type=int, default=3, help="draws of each figure (default 3)")
    ap.add_argument("--keep", metavar="DIR", help="keep the files drawn here (ours/, base/)")
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    ap.add_argument("--record", metavar="FILE", help=argparse.SUPPRESS)
    ap.add_argument("--draw", nargs=4, metavar=("CALLS", "N", "KEEP", "OUT"),
                    help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.record:
        return record(a.record)
    if a.draw:
        return draw(a.draw[0], int(a.draw[1]), a.draw[2], a.draw[3])
    with tempfile.TemporaryDirectory() as tmp, \
            Run("figures", "the figure tasks of biped reproduce --quick, CPU s",
                save=not a.no_save) as bench:
        tmp = Path(tmp)
        keep = Path(a.keep) if a.keep else tmp / "files"
        versions = {"ours": snapshot(None, tmp / "ours")}
        if a.baseline_commit:
            versions["base"] = snapshot(a.baseline_commit, tmp / "base")
        calls = (Path(a.keep) if a.keep else tmp) / "calls.pkl"
        calls.parent.mkdir(parents=True, exist_ok=True)
        _child(versions["ours"], "--record", str(calls))
        res = {}
        for name, pk in versions.items():
            (keep / name).mkdir(parents=True, exist_ok=True)
            _child(pk, "--draw", str(calls), str(a.repeats), str(keep / name),
                   str(tmp / f"{name}.json"))
            res[name] = json.loads((tmp / f"{name}.json").read_text())
        base = res.get("base", {})
        for task in res["ours"]:
            o, b = res["ours"][task]["cpu"], base.get(task, {}).get("cpu")
            bench.row(f"figure task {task}", round(o, 3), b and round(b, 3))
            print(f"{task:20s} ours {o:6.3f} s" + (f"   baseline {b:6.3f} s" if b else ""))
        tot = sum(r["cpu"] for r in res["ours"].values())
        btot = sum(r["cpu"] for r in base.values()) if base else None
        bench.row("all figure tasks", round(tot, 3), btot and round(btot, 3))
        print(f"{'all':20s} ours {tot:6.3f} s" + (f"   baseline {btot:6.3f} s" if btot else ""))
        bench.data.update(times=res, baseline=a.baseline_commit, repeats=a.repeats)
        if base:
            bench.data["files"] = cmp = compare(keep / "ours", keep / "base")
            for f, row in cmp.items():
                print(f"{f:28s} {row}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
