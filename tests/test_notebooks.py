"""Every notebook in notebooks/ runs top to bottom on a fresh kernel without error.

Each is executed with nbclient in the notebooks/ folder (as a reader would run it), with this
checkout first on the kernel's path. Outputs are not written back: the committed notebooks keep
the outputs they were committed with.
"""

import os
from pathlib import Path

import jax
import nbclient
import nbformat
import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
PATHS = sorted(NOTEBOOKS.glob("*.ipynb"))
# Notebooks run with `python -m pytest -m slow` only, but for the quick start: 07 runs for
# minutes (spot's posing compared with medial deformation, LBS and DQS, and a gradient: about
# 9 minutes on 2 busy cores); 04 runs the paper's experiments (`benchmarks/paper`), which
# `test_paper.py` runs and checks too; 02, 03, 05 and 06 take 25-60 s each on 2 busy cores
# (160 s of the suite, mostly compilation), and what they show is checked by the tests of its
# subsystem: det J of every method (`test_fleshing`, `test_free_form_fleshing`), the fits
# (`test_fit`), the medial meshes (`test_medial*`) and their deformation (`test_medial_deform`,
# `test_arap`).
SLOW = {"02_verify_det_jacobian", "03_fit_spine", "04_paper_experiments", "05_medial_axis",
        "06_medial_deformation", "07_posing_limbs"}


def test_notebooks_exist():
    assert len(PATHS) >= 4, f"expected the tutorial notebooks in {NOTEBOOKS}"


@pytest.mark.parametrize(
    "path",
    [pytest.param(p, marks=pytest.mark.slow) if p.stem in SLOW else p for p in PATHS],
    ids=[p.stem for p in PATHS],
)
def test_notebook_runs(path, monkeypatch):
    nb = nbformat.read(path, as_version=4)
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    assert code, f"{path.name} has no code cell"
    assert 'jax.config.update("jax_enable_x64", True)' in code[0].source, (
        f"{path.name}: the first code cell must enable float64"
    )
    assert nb.metadata["kernelspec"]["name"] == "python3"
    # The kernel inherits the environment: import this checkout, not another installed copy.
    path_entries = [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(path_entries))
    # Share the tests' persistent compilation cache (see conftest.py) with the kernels.
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", jax.config.jax_compilation_cache_dir)
    monkeypatch.setenv(
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS",
        str(jax.config.jax_persistent_cache_min_compile_time_secs),
    )
    client = nbclient.NotebookClient(
        nb,
        timeout=300,
        kernel_name="python3",
        resources={"metadata": {"path": str(NOTEBOOKS)}},
    )
    client.execute()  # raises CellExecutionError on the first failing cell
    errors = [o for cell in nb.cells for o in cell.get("outputs", []) if o.output_type == "error"]
    assert not errors
