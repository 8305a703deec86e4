"""Sphinx configuration of the biped-casadi documentation.

Build: ``sphinx-build -W -b html docs docs/_build/html`` (warnings are errors).  The
notebooks of ``notebooks/`` are copied into ``docs/tutorials/`` and executed at build time
with their small settings (BIPED_NOTEBOOK_QUICK=1, about a minute)."""
from __future__ import annotations

import os
import shutil
import sys
from importlib.metadata import version as _version
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE / "_ext"))

project = "biped-casadi"
author = "the biped-casadi developers"
copyright = "2026, the biped-casadi developers"
release = _version("biped-casadi")
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_nb",
    "paper_equations",
]
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
exclude_patterns = ["_build", "**.ipynb_checkpoints", "public_api.txt"]
templates_path = ["_templates"]
html_theme = "pydata_sphinx_theme"
html_title = f"biped-casadi {release}"
html_static_path = ["_static"]
html_theme_options = {"navigation_with_keys": False, "show_toc_level": 2}

autosummary_generate = True
autodoc_member_order = "bysource"
autodoc_typehints = "none"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks = set()
myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 2

# ---- notebooks: copied from notebooks/, executed with small settings at build time
nb_execution_mode = os.environ.get("BIPED_DOCS_EXECUTE", "force")
nb_execution_timeout = 600
nb_execution_raise_on_error = True
# run every page in a temporary folder: the how-to's sweep folder (and anything else a
# page writes) never lands in the source tree, so a re-build starts from scratch
nb_execution_in_temp = True
os.environ.setdefault("BIPED_NOTEBOOK_QUICK", "1")
os.environ.pop("MPLBACKEND", None)
_tutorials = HERE / "tutorials"
_tutorials.mkdir(exist_ok=True)
for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
    target = _tutorials / nb.name
    if not target.exists() or target.read_bytes() != nb.read_bytes():
        shutil.copyfile(nb, target)


# ---- the API reference: every module of public_api.txt, each public name once
def _write_api_page():
    import importlib
    import inspect

    from paper_equations import api_sections
    lines = ["API reference", "=============", "",
             "The public surface: what the packages and the modules below export "
             "(``__all__``).  Everything else is internal and may change.", ""]
    for modname, names in api_sections():
        if not names:
            continue
        doc = (inspect.getdoc(importlib.import_module(modname)) or "").split("\n\n")[0]
        lines += [modname, "-" * len(modname), "", f".. currentmodule:: {modname}", "",
                  doc.replace("\n", " "), "", ".. autosummary::", "   :toctree: generated",
                  "   :nosignatures:", ""]
        lines += [f"   {n}" for n in names] + [""]
    text = "\n".join(lines)
    page = HERE / "api.rst"
    if not page.exists() or page.read_text() != text:
        page.write_text(text)


_write_api_page()


# ---- the benchmarks page, made from the results the benchmark scripts saved
from benchmarks_page import benchmarks_page  # noqa: E402

benchmarks_page(ROOT / "benchmarks" / "results", HERE / "benchmarks.md")

# ---- the findings page, made from the summary of a full run kept with the docs
from findings_page import findings_page  # noqa: E402

findings_page(HERE / "results" / "summary_full.json", HERE / "findings.md")
