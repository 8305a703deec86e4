"""The docs' findings page, made from the summary of a full ``biped reproduce`` that is
kept with the documentation (``docs/results/summary_full.json``): every number on the
page is that run's, through the report's own tables."""
from __future__ import annotations

import json
from pathlib import Path

__all__ = ["findings_page"]

INTRO = """# What the toolkit found

Every number on this page comes from one full run of `biped reproduce` on RABBIT, whose
`summary.json` is kept with the documentation (`docs/results/summary_full.json`, run
{finished}); the tables are the ones of that run's `report.md`.  The paper's gait is not
ours (it is not published), so this is about the method, not their robot.

## What it says

- The paper's linear analysis recommends deadbeat outputs (max|λ| -> 0).  Linear
  eigenvalues do not say whether a robot walks: from the paper's own perturbation
  (0.01 rad on every joint, 0.1 rad/s on every velocity, mu = 0.6, the torque limit),
  with every step checked for normal force, friction cone (the impact impulse
  included), lift-off, scuffing and the torque limit, the deadbeat outputs lose the
  ground in the first step: their s* is the smallest of all.
- Virtual constraints walk from the paper's perturbation on every gait and have large
  basins.
- The robust co-design (one NLP over M1, the perturbation scale, the correction's rejoin
  time and the gait's own Bezier coefficients, against scenarios walked by the walker's
  own rule, with scenario exchange and trust-region gait steps) reaches a larger s*
  than virtual constraints on its own gait, with a smaller max|λ|, and converges faster.
- Eigenvalues and robustness pull apart: bounding max|λ| more tightly lowers the s* the
  NLP reaches (the trade-off curve).
- On uneven ground and with a wrong model the same ranking holds; the output gains
  change nothing without a model error (the closed loop is its zero dynamics) and
  matter with one.

"""


def findings_page(summary_file: Path, page: Path, static: str = "_static") -> Path:
    """Write the findings page from a full run's summary (only when it changes).

    Parameters
    ----------
    summary_file : Path
        The kept ``summary.json`` of a full run.
    page : Path
        The page to write (``docs/findings.md``).
    static : str
        Where the page's figures are, relative to the page.

    Returns
    -------
    Path
    """
    from analysis.reporting.report import (_comparison_lines, _comparison_rows,
                                           _robust_lines, _terrain_lines)
    if not Path(summary_file).is_file():
        text = "# What the toolkit found\n\nNo full run is kept with the documentation.\n"
    else:
        s = json.loads(Path(summary_file).read_text())
        esc = lambda t: str(t).replace("|", "\\|").replace("\n", " ")        # noqa: E731
        lines = [INTRO.format(finished=s.get("finished", "?")),
                 "## Against the paper", "", "| quantity | paper | ours | why they differ |",
                 "|---|---|---|---|"]
        lines += [f"| {esc(a)} | {esc(b)} | {esc(c)} | {esc(d)} |"
                  for a, b, c, d in _comparison_rows(s)]
        lines += [""] + _comparison_lines(s) + _robust_lines(s) + _terrain_lines(s)
        for name, caption in (("tradeoff", "s* against max|λ| on the co-design's gait"),
                              ("basin_robust", "Basins of the co-design, the sampling "
                                               "search's design and virtual constraints"),
                              ("terrain_mfpt", "Mean first-passage time against sigma")):
            lines += [f"```{{figure}} {static}/{name}.png", f":alt: {caption}", "",
                      caption, "```", ""]
        text = "\n".join(lines)
    if not page.exists() or page.read_text() != text:
        page.write_text(text)
    return page
