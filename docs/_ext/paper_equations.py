"""Sphinx directive ``paper-equations``: the table of the paper's numbered equations and
the one function or class of the toolkit that implements each, read from the docstrings
of the public surface (``docs/public_api.txt``), so the page cannot drift from the code.

A docstring declares what it implements with the phrase ``Implements eq. (N)`` or
``Implements eqs. (N), (M)`` (numbers separated by commas or "and", ranges
``(N)-(M)``).  ``tests/test_docs.py`` checks that every equation is claimed exactly
once, and only by a public function, class or method.

The same module decides where the API reference documents each public object
(:func:`api_sections`), so the table's links, the API page and the test agree on names.
Importing it needs no Sphinx (the test suite uses it without the docs extra).
"""
from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path

MARKER = re.compile(r"Implements eqs?\.\s*((?:\(\d+\)(?:\s*(?:,|-|and|to)\s*)?)+)")
NUMBER = re.compile(r"\((\d+)\)")
API_LIST = Path(__file__).resolve().parents[1] / "public_api.txt"
#: the toolkit's own packages: members inherited from anything else are not its API
PACKAGES = ("biped_casadi", "gait_opt", "analysis")


#: what each numbered equation of the paper says, in a line (the paper does not change;
#: the implementers are read from the code)
EQUATIONS = {
    1: "single-support dynamics D(q) ddq + H(q, dq) = B u",
    2: "impact: dq+ = I(q-) dq-",
    3: "leg relabelling q+ = E q-",
    4: "the robot as a system with impulse effects: f, g, Delta, switching surface S",
    5: "controlled outputs v = M q = M1 q_u + M2 q_a",
    6: "output y = v - v^d(t)",
    7: "the output with the reference restarted at every impact (tau' = 1, tau+ = 0)",
    8: "reference outputs v^d(tau) = M q^d(tau)",
    9: "closed-loop hybrid system in the extended state X = (x, tau)",
    10: "configuration from (q_u, v)",
    11: "D and H split into unactuated and actuated blocks",
    12: "the dynamics in the outputs: ddq_u and the torques u",
    13: "output dynamics ddv = ddv^d - Kd/eps (dv - dv^d) - Kp/eps^2 (v - v^d)",
    14: "swing-phase zero dynamics",
    15: "outputs on the zero dynamics: M1 q_u + M2 q_a = M1 q_u^d + M2 q_a^d",
    16: "zero dynamics in q_u and q_a",
    17: "corrected output y_c = v - v^d - v_c(tau, y_i, dy_i)",
    18: "the correction v_c: starts at (y_i, dy_i), zero from T/2",
    19: "hybrid zero dynamics with the correction (M2 = I)",
    20: "linearised restricted Poincare map dx_{k+1} = A^z dx_k",
    21: "v^d, dv^d, ddv^d from q^d, dq^d, ddq^d",
    22: "stability: max |lambda_1,2| of A^z < 1",
    23: "ddq_u = (-D12 ddv - H1) / (D11 - D12 M1)",
    24: "singular controller: D11 - D12 M1 = 0",
    25: "outputs on their reference at the desired impact time T^d",
    26: "q(T^d) = q^d(T^d) + M_T dq_u, M_T = [1, -M1]'",
    27: "Taylor expansion Z_sw ~ Z_sw(q^d) + a dq_u + b dq_u^2",
    28: "the output conditions a = b = 0",
}


def public_modules() -> list[str]:
    """The modules of ``docs/public_api.txt``, in its order."""
    lines = API_LIST.read_text().splitlines()
    return [ln.strip() for ln in lines if ln.strip() and not ln.startswith("#")]


def _ours(obj) -> bool:
    return getattr(obj, "__module__", "").split(".")[0] in PACKAGES


def api_sections() -> list[tuple[str, list[str]]]:
    """(module, names) for the API reference: every function and class of the toolkit
    in a public module's ``__all__``, documented once, under the first module of
    ``public_api.txt`` that exports it (``biped_casadi.Gains``, not
    ``biped_casadi.control.output_law.Gains``)."""
    seen, sections = set(), []
    for modname in public_modules():
        mod = importlib.import_module(modname)
        names = []
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)) or not _ours(obj):
                continue
            if id(obj) in seen:
                continue
            seen.add(id(obj))
            names.append(name)
        sections.append((modname, names))
    return sections


def _members(cls):
    """(name, function or property) of the public methods and properties of ``cls``,
    its own and those inherited from the toolkit's classes (as the API reference shows
    them), the most derived definition of each name."""
    seen = set()
    for klass in cls.__mro__:
        if klass is object or not _ours(klass):
            continue
        for name, member in vars(klass).items():
            if name.startswith("_") or name in seen:
                continue
            seen.add(name)
            if isinstance(member, (classmethod, staticmethod)):
                member = member.__func__
            if inspect.isfunction(member) or isinstance(member, property):
                yield name, member


def public_objects(properties: bool = False):
    """(documented name, object) for every public function and class and every public
    method of those classes (and, with ``properties``, every public property), each
    object once, under the name the API reference documents it by."""
    seen = set()
    for modname, names in api_sections():
        mod = importlib.import_module(modname)
        for name in names:
            obj = getattr(mod, name)
            public = f"{modname}.{name}"
            seen.add(id(obj))
            yield public, obj
            if not inspect.isclass(obj):
                continue
            for mname, member in _members(obj):
                if id(member) in seen or (isinstance(member, property) and not properties):
                    continue
                seen.add(id(member))
                yield f"{public}.{mname}", member


def _numbers(spec: str) -> list[int]:
    nums = [int(n) for n in NUMBER.findall(spec)]
    if "-" in spec and len(nums) == 2:           # a range (N)-(M)
        return list(range(nums[0], nums[1] + 1))
    return nums


def claimed_equations(doc: str) -> list[int]:
    """The equation numbers a docstring claims with the ``Implements eq.`` marker."""
    out = []
    for m in MARKER.finditer(" ".join((doc or "").split())):
        out += _numbers(m.group(1))
    return out


def summary_line(doc: str) -> str:
    """The one-line summary of a docstring."""
    return doc.strip().splitlines()[0].strip() if doc and doc.strip() else ""


def equation_claims() -> dict[int, list[tuple[str, str]]]:
    """Equation number -> [(documented name, summary line)] of its implementers."""
    claims: dict[int, list] = {}
    for name, obj in public_objects():
        doc = inspect.getdoc(obj) or ""
        for n in claimed_equations(doc):
            claims.setdefault(n, []).append((name, summary_line(doc)))
    return dict(sorted(claims.items()))


def setup(app):
    from docutils import nodes
    from docutils.parsers.rst import Directive
    from sphinx import addnodes

    def row(cells, ref=None):
        r = nodes.row()
        for i, text in enumerate(cells):
            entry = nodes.entry()
            para = nodes.paragraph()
            if i == 2 and ref is not None:
                xref = addnodes.pending_xref("", refdomain="py", reftype="obj",
                                             reftarget=ref, refexplicit=False,
                                             paper_equations=True)
                xref += nodes.literal(text=text)
                para += xref
            else:
                para += nodes.Text(text)
            entry += para
            r += entry
        return r

    class PaperEquations(Directive):
        """The table: equation | what it says | implemented by."""

        has_content = False

        def run(self):
            table = nodes.table()
            group = nodes.tgroup(cols=3)
            table += group
            for width in (8, 52, 40):
                group += nodes.colspec(colwidth=width)
            head = nodes.thead()
            group += head
            head += row(["paper eq.", "what it says", "implemented by"])
            body = nodes.tbody()
            group += body
            for n, who in equation_claims().items():
                for name, _ in who:
                    body += row([f"({n})", EQUATIONS.get(n, ""), name], ref=name)
            return [table]

    def unresolved(app, env, node, contnode):
        # a row whose implementer is not in the API reference is an error (with -W),
        # never a silent dead link
        if node.get("paper_equations"):
            from sphinx.util import logging
            logging.getLogger(__name__).warning(
                "paper-equations: %s is not documented in the API reference",
                node["reftarget"], location=node)

    app.add_directive("paper-equations", PaperEquations)
    app.connect("missing-reference", unresolved)
    return {"version": "1.1", "parallel_read_safe": True}
