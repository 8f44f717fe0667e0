"""notebooks/quickstart.ipynb runs top to bottom in a fresh python3 kernel and draws its figures inline."""

from __future__ import annotations


import nbformat
import pytest
from nbclient import NotebookClient
import paths

NOTEBOOK = paths.REPO / "notebooks" / "quickstart.ipynb"


@pytest.mark.slow  # ~30 s: a kernel and a training; the same job runs in test_end_to_end, the notebook with `pytest -m slow`
def test_quickstart_notebook_executes():
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    # A generous per-cell limit: the whole notebook takes well under a minute on an idle laptop CPU,
    # but test machines are shared.  Any cell error raises CellExecutionError.
    resources = {"metadata": {"path": str(NOTEBOOK.parent)}}
    NotebookClient(notebook, timeout=600, kernel_name="python3", resources=resources).execute()
    outputs = [output for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    figures = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(figures) == 4, "multi-view sample, loss curves, GT vs prediction and lifting figures render inline"
    assert any("P-MPJPE" in o.get("data", {}).get("text/markdown", "") for o in outputs)
