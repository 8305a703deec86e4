"""The README is short, and every number in its table of findings is a number of the
full run kept with the documentation (docs/results/summary_full.json)."""
from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _numbers(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _numbers(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _numbers(v)
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield float(obj)


def _table(text: str, heading: str) -> list:
    part = text.split(heading, 1)[1].split("\n## ", 1)[0]
    rows = [r for r in part.splitlines() if r.startswith("|")]
    return [[c.strip() for c in r.strip("|").split("|")] for r in rows[2:]]


def test_readme_is_for_users():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    assert "../shared" not in text and "SPEC" not in text
    for cmd in ("pip install . && biped reproduce", 'pip install -e ".[test]" && python -m '
                "pytest -q"):
        assert cmd in text


def test_readme_findings_are_the_kept_runs_numbers():
    s = json.loads((ROOT / "docs" / "results" / "summary_full.json").read_text())
    values = list(_numbers(s))
    rows = _table((ROOT / "README.md").read_text(), "## What it found")
    assert len(rows) >= 3
    checked = 0
    for row in rows:
        for cell in row[1:]:
            if "<" in cell or not cell:
                continue
            for num, pct in re.findall(r"(?<![\w.-])(\d+(?:\.\d+)?)(\s*%)?(?![\w.])", cell):
                digits = len(num.split(".")[1]) if "." in num else 0
                x = float(num)
                scale = 100.0 if pct else 1.0
                assert any(round(v * scale, digits) == x for v in values), (row[0], cell)
                checked += 1
    assert checked >= 8
