"""The research notebooks run top to bottom (reduced sizes) and their committed
``.ipynb`` twins match the jupytext ``.py`` sources and carry no outputs.

Each notebook is executed in a fresh Jupyter kernel of this interpreter (nbclient),
with ``STICKSLIP_NOTEBOOK_QUICK=1``; a failing cell fails the test. Run times are
printed (``pytest -s``) and collected in ``notebooks/README.md`` by hand.
"""

import os
import time
from pathlib import Path

import pytest

jupytext = pytest.importorskip("jupytext")
nbclient = pytest.importorskip("nbclient")
nbformat = pytest.importorskip("nbformat")

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
SOURCES = sorted(NOTEBOOKS.glob("[0-9][0-9]_*.py"))


def test_there_are_seven_notebooks():
    assert len(SOURCES) == 7, [p.name for p in SOURCES]


def _runner():
    """scripts/run_notebooks.py, which also executes the notebooks outside the tests."""
    import importlib.util

    path = NOTEBOOKS.parent / "scripts" / "run_notebooks.py"
    spec = importlib.util.spec_from_file_location("run_notebooks", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def kernel_dir():
    """A kernelspec for this very interpreter (not whatever `python3` a machine has)."""
    return _runner().kernel_spec_dir()


@pytest.mark.slow
@pytest.mark.parametrize("source", SOURCES, ids=lambda p: p.stem)
def test_notebook_runs(source, kernel_dir, monkeypatch):
    monkeypatch.setenv("STICKSLIP_NOTEBOOK_QUICK", "1")
    # A notebook runs once per suite and compiles mostly programs of its own, so the
    # workers' fresh cache would mostly be written, not read: notebook 04 took 131.0 s
    # with a fresh cache against 119.5 s without (2026-12-07, quick mode, one pair).
    monkeypatch.setenv("STICKSLIP_CACHE_DIR", "off")
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    monkeypatch.setenv("JUPYTER_PATH", str(kernel_dir) + os.pathsep + os.environ.get(
        "JUPYTER_PATH", ""))
    nb = jupytext.read(source)
    client = nbclient.NotebookClient(nb, timeout=900, kernel_name="stickslip",
                                     resources={"metadata": {"path": str(NOTEBOOKS)}})
    t0 = time.perf_counter()
    client.execute()
    print(f"{source.name}: {time.perf_counter() - t0:.1f} s")
    images = sum(1 for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
                 if "image/png" in o.get("data", {}))
    assert images >= 1, "the notebook drew no figure"


@pytest.mark.parametrize("source", SOURCES, ids=lambda p: p.stem)
def test_ipynb_twin_matches_and_has_no_outputs(source):
    twin = source.with_suffix(".ipynb")
    assert twin.exists(), f"missing {twin.name}: run `jupytext --to ipynb {source.name}`"
    committed = nbformat.read(twin, as_version=4)
    expected = jupytext.read(source)
    assert [(c.cell_type, c.source) for c in committed.cells] == \
        [(c.cell_type, c.source) for c in expected.cells], \
        f"{twin.name} is out of date: run `jupytext --sync {source.name}`"
    for cell in committed.cells:
        if cell.cell_type == "code":
            assert not cell.outputs and cell.execution_count is None, \
                f"{twin.name} has outputs: strip them"
