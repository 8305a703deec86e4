"""The documentation's promises, checked without building the site.

- Every public function, class and method (the modules of ``docs/public_api.txt`` and
  their ``__all__``, as the API reference shows them) has a numpydoc docstring: a
  one-line summary, a Parameters section naming exactly the arguments (dataclass fields
  count), and a Returns section when it returns something.  Public properties have a
  one-line summary.
- Every paper equation named with the marker ``Implements eq. (N)`` is claimed by exactly
  one public function or class, the marker appears nowhere else in the packages, and the
  equations the toolkit implements (the theory page's table) are all claimed.
"""
from __future__ import annotations

import ast
import enum
import importlib
import inspect
import pkgutil
import re
import sys
import textwrap
import warnings
from pathlib import Path

import pytest
from numpydoc.docscrape import ClassDoc, FunctionDoc

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

from paper_equations import (EQUATIONS, PACKAGES, claimed_equations,  # noqa: E402
                             equation_claims, public_modules, public_objects)

#: the paper's numbered equations (Wang & Chevallereau: 28) that the toolkit implements
IMPLEMENTED = set(range(1, 29))

OBJECTS = list(public_objects(properties=True))
CALLABLES = [(n, o) for n, o in OBJECTS if not isinstance(o, property)]
PROPERTIES = [(n, o) for n, o in OBJECTS if isinstance(o, property)]


def test_the_public_surface_is_found():
    names = [n for n, _ in CALLABLES]
    assert len(names) > 150, len(names)
    assert {"biped_casadi.rabbit", "gait_opt.Gait.load", "analysis.poincare_eigenvalues",
            "biped_casadi.control.output_law.correction"} <= set(names)
    assert public_modules()[0] == "biped_casadi"


def _signature_names(obj) -> list[str]:
    """The arguments a caller passes: parameters without self/cls, with * and **
    (none for an enumeration: its members are its values)."""
    if inspect.isclass(obj) and issubclass(obj, enum.Enum):
        return []
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):          # builtin base classes (exceptions)
        return []
    out = []
    for p in sig.parameters.values():
        if p.name in ("self", "cls"):
            continue
        prefix = {p.VAR_POSITIONAL: "*", p.VAR_KEYWORD: "**"}.get(p.kind, "")
        out.append(prefix + p.name)
    return out


def _documented_names(doc) -> list[str]:
    names = []
    for section in ("Parameters", "Other Parameters"):
        for p in doc[section]:
            names += [n.strip() for n in p.name.split(",") if n.strip()]
    return names


def _returns_value(func) -> bool:
    """Whether a function returns something: a ``return <value>`` in its own body, or a
    return annotation other than None."""
    ann = inspect.signature(func).return_annotation
    if ann not in (inspect.Signature.empty, None, "None"):
        return True
    src = textwrap.dedent(inspect.getsource(inspect.unwrap(func)))
    tree = ast.parse(src)
    fn = next(n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)))

    def walk(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda,
                                  ast.ClassDef)):
                continue
            if isinstance(child, ast.Return) and child.value is not None and not (
                    isinstance(child.value, ast.Constant) and child.value.value is None):
                return True
            if walk(child):
                return True
        return False
    return walk(fn)


def _parse(name, obj):
    with warnings.catch_warnings():
        warnings.simplefilter("error")        # an unknown section or a malformed one
        return ClassDoc(obj) if inspect.isclass(obj) else FunctionDoc(obj)


@pytest.mark.parametrize("name,obj", CALLABLES, ids=[n for n, _ in CALLABLES])
def test_numpydoc_docstring(name, obj):
    assert inspect.getdoc(obj), f"{name}: no docstring"
    doc = _parse(name, obj)
    summary = doc["Summary"]
    assert len(summary) == 1 and summary[0].strip(), \
        f"{name}: the summary must be one line, got {summary!r}"
    args = _signature_names(obj)
    documented = _documented_names(doc)
    bare = [a.lstrip("*") for a in args]
    missing = [a for a, b in zip(args, bare) if a not in documented and b not in documented]
    unknown = [d for d in documented if d not in args and d not in bare]
    assert not missing, f"{name}: Parameters lacks {missing}"
    assert not unknown, f"{name}: Parameters names {unknown}, which it does not take"
    for p in doc["Parameters"]:
        assert p.type or p.desc, f"{name}: parameter {p.name!r} has neither type nor text"
    if not inspect.isclass(obj) and _returns_value(obj):
        assert doc["Returns"] or doc["Yields"], f"{name}: returns a value but has no Returns"


@pytest.mark.parametrize("name,prop", PROPERTIES, ids=[n for n, _ in PROPERTIES])
def test_property_has_a_summary(name, prop):
    doc = inspect.getdoc(prop) or ""
    lines = doc.strip().split("\n\n")[0].splitlines() if doc.strip() else []
    assert len(lines) == 1, f"{name}: a property needs a one-line summary, got {doc!r}"


# ---------------------------------------------------------------- paper equations
def test_each_equation_has_exactly_one_implementer():
    claims = equation_claims()
    twice = {n: [w for w, _ in who] for n, who in claims.items() if len(who) > 1}
    assert not twice, f"equations claimed more than once: {twice}"


def test_every_implemented_equation_is_claimed():
    assert set(EQUATIONS) == set(range(1, 29))        # the theory table's descriptions
    claims = equation_claims()
    assert set(claims) == IMPLEMENTED, (
        f"missing {sorted(IMPLEMENTED - set(claims))}, "
        f"unexpected {sorted(set(claims) - IMPLEMENTED)}")


def _all_definitions():
    """(qualified name, object) of every module, class, function and method defined in
    the packages, public or not."""
    for pkg_name in PACKAGES:
        pkg = importlib.import_module(pkg_name)
        mods = [pkg] + [importlib.import_module(m.name) for m in
                        pkgutil.walk_packages(pkg.__path__, pkg_name + ".")
                        if not m.name.endswith(".__main__")]      # runs the CLI
        for mod in mods:
            yield mod.__name__, mod
            for name, obj in vars(mod).items():
                if getattr(obj, "__module__", None) != mod.__name__:
                    continue
                if inspect.isfunction(obj) or inspect.isclass(obj):
                    yield f"{mod.__name__}.{name}", obj
                if inspect.isclass(obj):
                    for mname, member in vars(obj).items():
                        if isinstance(member, (classmethod, staticmethod)):
                            member = member.__func__
                        if inspect.isfunction(member) or isinstance(member, property):
                            yield f"{mod.__name__}.{name}.{mname}", member


def test_the_marker_is_only_on_public_objects():
    public = {id(o) for _, o in public_objects(properties=True)}
    stray = [name for name, obj in _all_definitions()
             if claimed_equations(inspect.getdoc(obj) or "") and id(obj) not in public]
    assert not stray, (f"'Implements eq.' on objects the theory page cannot list "
                       f"(not public): {stray}")


def test_marker_parsing():
    assert claimed_equations("Implements eq. (24).") == [24]
    assert claimed_equations("Implements eqs. (5), (8) and\n(21): more") == [5, 8, 21]
    assert claimed_equations("Implements eqs. (1)-(4).") == [1, 2, 3, 4]
    assert claimed_equations("uses eq. (12) but Implements nothing") == []


#: a reST substitution reference, |name|, where inline markup may start and end (the
#: docs build with -W fails on one: ``|M1(i)|``, ``(|v_z| dt)``); spans in backticks are
#: literal or math and are removed first
_SUBSTITUTION = re.compile(r"(?:^|(?<=[\s(\[{<'\"/:-]))\|(?=\S)[^|\n]*?(?<=\S)\|"
                           r"(?=[\s)\]}>.,;:!?'\"/-]|$)")
_BACKTICKS = re.compile(r"``.*?``|`[^`\n]*`", re.S)


@pytest.mark.parametrize("name,obj", CALLABLES, ids=[n for n, _ in CALLABLES])
def test_no_stray_substitution_references(name, obj):
    """|x| in a docstring is a reST substitution the docs build rejects; write
    ``|x|`` or :math:`|x|`."""
    doc = _BACKTICKS.sub("", inspect.getdoc(obj) or "")
    assert not _SUBSTITUTION.findall(doc), (name, _SUBSTITUTION.findall(doc))
