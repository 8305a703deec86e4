"""The package's structure: layers import downward only, figures and process logic live
where they belong, and modules and functions stay a readable size."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("biped_casadi", "gait_opt", "analysis")
#: what each layer may import of ours
ALLOWED = {"biped_casadi": {"biped_casadi"}, "gait_opt": {"biped_casadi", "gait_opt"},
           "analysis": set(OURS)}
MAX_MODULE_LINES = 700
MAX_FUNCTION_LINES = 80          # the body, without its docstring
MAX_INNER_IMPORTS = 3


def _modules():
    for top in OURS:
        for f in sorted((ROOT / top).rglob("*.py")):
            yield top, f, ast.parse(f.read_text())


def _ours(node, f: Path):
    """The top packages of ours a node imports (relative imports resolved)."""
    if isinstance(node, ast.Import):
        return {a.name.split(".")[0] for a in node.names} & set(OURS)
    if isinstance(node, ast.ImportFrom):
        if node.level:
            return {f.relative_to(ROOT).parts[0]}
        return {(node.module or "").split(".")[0]} & set(OURS)
    return set()


def _third(node):
    if isinstance(node, ast.Import):
        return {a.name.split(".")[0] for a in node.names}
    if isinstance(node, ast.ImportFrom) and not node.level:
        return {(node.module or "").split(".")[0]}
    return set()


def test_layers_import_downward_only():
    bad = [(f.relative_to(ROOT).as_posix(), sorted(_ours(n, f) - ALLOWED[top]))
           for top, f, tree in _modules() for n in ast.walk(tree) if _ours(n, f) - ALLOWED[top]]
    assert not bad, bad


def test_figures_and_processes_live_in_their_modules():
    """matplotlib only where figures are drawn; no process or cluster logic in the
    report; matplotlib.use nowhere."""
    draw = ("analysis/reporting/plots/", "analysis/pipeline/figures.py")
    plots, procs, use = [], [], []
    for _, f, tree in _modules():
        rel = f.relative_to(ROOT).as_posix()
        names = set().union(*(_third(n) for n in ast.walk(tree)))
        if "matplotlib" in names and not rel.startswith(draw):
            plots.append(rel)
        if rel.startswith("analysis/reporting/") and names & {
                "dask", "distributed", "multiprocessing", "subprocess", "threading",
                "concurrent"}:
            procs.append(rel)
        use += [rel for n in ast.walk(tree) if isinstance(n, ast.Attribute)
                and n.attr == "use" and getattr(n.value, "id", "") == "matplotlib"]
    assert not plots and not procs and not use, (plots, procs, use)


@pytest.mark.parametrize("top", OURS)
def test_modules_are_short(top):
    long = {f.relative_to(ROOT).as_posix(): f.read_text().count("\n")
            for t, f, _ in _modules() if t == top}
    assert all(n <= MAX_MODULE_LINES for n in long.values()), \
        {k: v for k, v in long.items() if v > MAX_MODULE_LINES}


def _functions(tree):
    for n in ast.walk(tree):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = n.body[0] if (n.body and isinstance(n.body[0], ast.Expr)
                                and isinstance(n.body[0].value, ast.Constant)) else None
            body = n.end_lineno - n.lineno + 1 - (0 if doc is None else
                                                  doc.end_lineno - doc.lineno + 1)
            yield n, body


def test_functions_are_short():
    long = [(f"{f.relative_to(ROOT).as_posix()}:{n.lineno} {n.name}", body)
            for _, f, tree in _modules() for n, body in _functions(tree)
            if body > MAX_FUNCTION_LINES]
    assert not long, sorted(long, key=lambda x: -x[1])


def test_few_project_imports_inside_functions():
    """An import of ours inside a function dodges a cycle: the code is in the wrong
    layer."""
    inner = set()
    for _, f, tree in _modules():
        for n, _ in _functions(tree):
            for sub in ast.walk(n):
                if _ours(sub, f):
                    inner.add(f"{f.relative_to(ROOT).as_posix()}:{sub.lineno}")
    assert len(inner) <= MAX_INNER_IMPORTS, sorted(inner)
