"""Sphinx directive ``paper-equations``: the table of the paper's numbered equations and
the one function or class of the toolkit that implements each, read from the docstrings
of the public surface (``docs/public_api.txt``), so the page cannot drift from the code.

A docstring declares what it implements with the phrase ``Implements eq. (N)`` or
``Implements eqs. (N), (M)`` (numbers separated by commas, ranges N-M allowed).
``tests/test_docs.py`` checks that no equation is claimed twice.
"""
from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import Directive
from sphinx import addnodes

MARKER = re.compile(r"Implements eqs?\.\s*((?:\(\d+\)(?:\s*(?:,|-|and|to)\s*)?)+)")
NUMBER = re.compile(r"\((\d+)\)")
API_LIST = Path(__file__).resolve().parents[1] / "public_api.txt"


def public_modules() -> list[str]:
    """The modules of ``docs/public_api.txt``."""
    lines = API_LIST.read_text().splitlines()
    return [ln.strip() for ln in lines if ln.strip() and not ln.startswith("#")]


def _numbers(spec: str) -> list[int]:
    nums = [int(n) for n in NUMBER.findall(spec)]
    if "-" in spec and len(nums) == 2:           # a range (N)-(M)
        return list(range(nums[0], nums[1] + 1))
    return nums


def public_objects():
    """(qualified name, object) for every public function, class and method."""
    seen = set()
    for modname in public_modules():
        mod = importlib.import_module(modname)
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue
            home = f"{obj.__module__}.{obj.__qualname__}"
            if home in seen or not obj.__module__.split(".")[0] in (
                    "biped_casadi", "gait_opt", "analysis"):
                continue
            seen.add(home)
            yield home, obj
            if inspect.isclass(obj):
                for mname, meth in vars(obj).items():
                    if mname.startswith("_") or not inspect.isfunction(meth):
                        continue
                    yield f"{home}.{mname}", meth


def equation_claims() -> dict[int, list[tuple[str, str]]]:
    """Equation number -> [(qualified name, first docstring line)] of its implementers."""
    claims: dict[int, list] = {}
    for home, obj in public_objects():
        doc = inspect.getdoc(obj) or ""
        for m in MARKER.finditer(" ".join(doc.split())):
            for n in _numbers(m.group(1)):
                claims.setdefault(n, []).append((home, doc.splitlines()[0] if doc else ""))
    return dict(sorted(claims.items()))


class PaperEquations(Directive):
    """The table: equation | implemented by | what it does."""

    has_content = False

    def run(self):
        table = nodes.table()
        group = nodes.tgroup(cols=3)
        table += group
        for width in (10, 45, 45):
            group += nodes.colspec(colwidth=width)
        head = nodes.thead()
        group += head
        head += self._row(["paper eq.", "implemented by", "summary"])
        body = nodes.tbody()
        group += body
        for n, who in equation_claims().items():
            for home, summary in who:
                body += self._row([f"({n})", home, summary], ref=home)
        return [table]

    @staticmethod
    def _row(cells, ref=None):
        row = nodes.row()
        for i, text in enumerate(cells):
            entry = nodes.entry()
            para = nodes.paragraph()
            if i == 1 and ref is not None:
                xref = addnodes.pending_xref("", refdomain="py", reftype="obj",
                                             reftarget=ref, refexplicit=False)
                xref += nodes.literal(text=text)
                para += xref
            else:
                para += nodes.Text(text)
            entry += para
            row += entry
        return row


def setup(app):
    app.add_directive("paper-equations", PaperEquations)
    return {"version": "1.0", "parallel_read_safe": True}
