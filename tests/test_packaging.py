"""The wheel carries every package of the source tree (a sub-package missing from
pyproject.toml's list would be absent from an installed toolkit)."""
from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_is_in_the_wheel():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
                 ["packages"])
    found = {p.parent.relative_to(ROOT).as_posix().replace("/", ".")
             for top in ("biped_casadi", "gait_opt", "analysis")
             for p in (ROOT / top).rglob("__init__.py")}
    assert found <= listed, f"packages missing from pyproject.toml: {sorted(found - listed)}"
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]
    for pkg in data:
        assert (ROOT / pkg.replace(".", "/")).is_dir(), pkg


def test_every_third_party_import_is_a_dependency():
    """`pip install .` alone must run every stage: a module the packages import (at the
    top or inside a function) is the standard library's, the toolkit's own, or one of
    pyproject.toml's dependencies (a new user's `biped reproduce` once failed its terrain
    stage on a missing scipy, which only the test extra installed)."""
    import ast
    import re
    import sys
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    names = {re.split(r"[\[<>=!~ ]", d, maxsplit=1)[0].lower() for d in deps}
    imported = set()
    for top in ("biped_casadi", "gait_opt", "analysis"):
        for f in (ROOT / top).rglob("*.py"):
            for n in ast.walk(ast.parse(f.read_text())):
                if isinstance(n, ast.Import):
                    imported |= {a.name.split(".")[0] for a in n.names}
                elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
                    imported.add(n.module.split(".")[0])
    own = {"biped_casadi", "gait_opt", "analysis",
           *tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
           ["py-modules"]}                                  # biped_cli, the entry point
    third = {m for m in imported if m not in sys.stdlib_module_names and m not in own}
    distribution = {"PIL": "pillow", "urdf_parser_py": "urdf-parser-py"}   # import names that differ
    missing = {m for m in third if distribution.get(m, m).lower() not in names}
    missing -= _lazy_extras()
    assert not missing, f"imported but not in pyproject.toml's dependencies: {sorted(missing)}"


def _lazy_extras() -> set:
    """The modules of the optional extra 'view' (``biped view``): allowed where they are
    imported only inside functions, so that everything else runs without them."""
    import ast
    import re
    extra = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]["view"]
    names = {re.split(r"[\[<>=!~ ]", d, maxsplit=1)[0].lower() for d in extra}
    for top in ("biped_casadi", "gait_opt", "analysis"):
        for f in (ROOT / top).rglob("*.py"):
            for n in ast.parse(f.read_text()).body:          # module level only
                mods = ({a.name.split(".")[0] for a in n.names} if isinstance(n, ast.Import)
                        else {(n.module or "").split(".")[0]} if isinstance(n, ast.ImportFrom)
                        else set())
                assert not mods & names, f"{f}: imports {mods & names} at the top"
    return names
