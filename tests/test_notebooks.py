"""Notebooks are executed, so they never rot."""
import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    # notebooks that use experiments/ find it through this (the kernel runs in tmp_path)
    os.environ["GREYBOX_EXPERIMENTS"] = str(Path(__file__).resolve().parent.parent / "experiments")
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    produced = {"01_model_and_fit.ipynb": "compare_ground_effect.png",
                "02_find_the_missing_physics.ipynb": "diagnosis_report/report.html",
                "03_paper_figures.ipynb": "paper_figures/fig5_position.png"}
    assert (tmp_path / produced[path.name]).exists()
