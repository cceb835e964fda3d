"""Notebooks are executed, so they never rot; they are stored executed, with their figures."""
import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

REPO = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))
SLOW = {"04_real_flight.ipynb"}   # a real flight's fit and diagnosis: 1-3 min
PRODUCED = {"01_model_and_fit.ipynb": "compare_ground_effect.png",
            "02_find_the_missing_physics.ipynb": "diagnosis_report/report.html",
            "03_paper_figures.ipynb": "paper_figures/fig5_position.png",
            "04_real_flight.ipynb": "real_flight_report/report.html"}


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.slow) if p.name in SLOW else p
                                  for p in NOTEBOOKS], ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path, monkeypatch):
    nb = nbformat.read(path, as_version=4)
    # the kernel runs in tmp_path: notebooks that use the repository's experiments/ or the
    # bundled NanoBench slice (tests/data/) find them through these
    monkeypatch.setenv("GREYBOX_EXPERIMENTS", str(REPO / "experiments"))
    monkeypatch.setenv("GREYBOX_NANOBENCH_CSV", str(REPO / "tests" / "data" / "nanobench_B2_slice.csv"))
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    assert (tmp_path / PRODUCED[path.name]).exists()


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_stored_executed_with_figures_and_no_path_hacks(path):
    nb = nbformat.read(path, as_version=4)
    cells = [c for c in nb.cells if c.cell_type == "code"]
    source = "\n".join(c.source for c in cells)
    assert "sys.path" not in source and "matplotlib.use" not in source
    assert all(c.execution_count is not None for c in cells), "store the notebook executed"
    assert not any(o.output_type == "error" for c in cells for o in c.outputs)
    assert any("image/png" in o.get("data", {}) for c in cells for o in c.outputs), "no figure shown"
