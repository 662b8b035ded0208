"""Every notebook under notebooks/ runs from top to bottom (nbclient) in a temporary folder; a
failing cell fails the test, and so does a warning printed by a cell or a file left behind."""

from pathlib import Path

import nbclient  # the test extra: pip install -e ".[test]"
import nbformat
import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert NOTEBOOKS


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError, naming the cell, when one fails
    stderr = [o.get("text", "") for cell in nb.cells for o in cell.get("outputs", [])
              if o.get("output_type") == "stream" and o.get("name") == "stderr"]
    assert not stderr, f"{path.name} printed to stderr: {stderr}"  # e.g. a TqdmWarning
    assert any("image/png" in o.get("data", {}) for cell in nb.cells for o in cell.get("outputs", [])), \
        f"{path.name} shows no figure"
    assert list(tmp_path.iterdir()) == [], "the notebook left files in its working folder"
