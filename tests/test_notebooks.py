"""The notebooks run top to bottom with small settings (BIPED_NOTEBOOK_QUICK=1), so
they never rot.  They share the on-disk gait cache with the rest of the suite."""
from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_are_seven_notebooks():
    assert [p.name[:2] for p in NOTEBOOKS] == ["01", "02", "03", "04", "05", "06", "07"]


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs(path, tmp_path, monkeypatch, gait):
    # `gait` makes sure the cached default gait exists before the kernel asks for it;
    # the kernel uses Jupyter's inline backend, as a user's would
    monkeypatch.setenv("BIPED_NOTEBOOK_QUICK", "1")
    monkeypatch.delenv("MPLBACKEND", raising=False)
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert any(o.get("output_type") == "stream" for o in outputs)   # it printed results
    figures = [o for o in outputs if "image/png" in o.get("data", {})]
    assert figures                                                   # figures were shown


def test_progress_bars_print_nothing_in_a_notebook(tmp_path):
    """The progress bar is a terminal's: in a Jupyter kernel (stderr not a terminal) it is
    off and prints nothing, not tqdm's notebook warning about missing widgets."""
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(
        "from analysis.reporting.progress import progress_bar\n"
        "bar = progress_bar(False, 10, 0, 'M1', 'sweep')\n"
        "bar.update(10); bar.close()\n"
        "print('done')")]
    NotebookClient(nb, timeout=120, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = nb.cells[0].outputs
    assert [o.get("text") for o in outputs if o.get("name") == "stdout"] == ["done\n"]
    assert not [o for o in outputs if o.get("name") == "stderr" or "error" in o.get(
        "output_type", "")], outputs
