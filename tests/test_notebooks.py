"""Every notebook in experiments/notebooks/ executes with small parameters.

Each notebook reads its size from a cell tagged ``parameters`` at the top. The test inserts a
cell with small values right after it (as papermill does), executes the notebook in memory
through nbclient with the repository root as the working directory, and never writes it back,
so no outputs are left in the repository. Files a notebook writes go to ``tmp_path``.

The notebooks run one after another in one kernel, each from an empty namespace (``%reset -f``
before its first cell): the kernel imports the project's modules once (about five seconds a
kernel, most of a small notebook's time), and no notebook sees another's variables.
"""

from pathlib import Path

import nbformat
import pytest
from jupyter_client import KernelManager
from nbclient import NotebookClient

pytestmark = pytest.mark.engine  # runs the compiled engines

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "experiments" / "notebooks"

SMALL = {
    "bode_phase_margin.ipynb": {"N_DELAYS": 4, "MAX_DELAY_MS": 45.0},
    "kalman_qr_tuning.ipynb": {
        "DELAYS_MS": (31.23,),
        "GRID_POINTS": 1,
        "GRID_DECADES": 1.0,
        "N_TRIALS": 2,
        "SEEDS": (0,),
        "VALIDATION_SEEDS": (100,),
        "DURATION_S": 0.3,
        "WORKERS": 1,
    },
    "closed_loop_16_vs_31ms.ipynb": {"DURATION_S": 0.4, "N_FRAMES_STRIP": 2},
    "lti_margins.ipynb": {"N_DELAYS": 4},
    "codesign.ipynb": {"N_TRIALS": 3, "BATCH_SIZE": 3, "SEEDS": (0,), "DURATION_S": 0.4,
                       "IMAGE_CHECK": True, "IMAGE_SEEDS": (0,)},
}


def test_every_notebook_has_small_parameters():
    assert {p.name for p in NOTEBOOKS.glob("*.ipynb")} == set(SMALL)


def _inject(nb: nbformat.NotebookNode, values: dict) -> None:
    idx = [i for i, c in enumerate(nb.cells) if "parameters" in c.metadata.get("tags", [])]
    assert len(idx) == 1, "exactly one cell must be tagged 'parameters'"
    (i,) = idx
    assert i <= 1, "the parameter cell must be at the top (after at most a title)"
    params = nb.cells[i].source
    for name in values:
        assert f"{name} =" in params, f"{name} is not a parameter of this notebook"
    source = "\n".join(f"{k} = {v!r}" for k, v in values.items())
    cell = nbformat.v4.new_code_cell(source)
    cell.metadata["tags"] = ["injected-parameters"]
    nb.cells.insert(i + 1, cell)


@pytest.fixture(scope="module")
def kernel():
    """A Python kernel started in the repository root, shared by this module's notebooks."""
    km = KernelManager(kernel_name="python3")
    km.start_kernel(cwd=str(ROOT))
    yield km
    km.shutdown_kernel(now=True)


@pytest.mark.parametrize("name", sorted(SMALL))
def test_notebook_executes(name, tmp_path, kernel):
    path = NOTEBOOKS / name
    before = path.read_bytes()
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    values = dict(SMALL[name])
    if "OUT_DIR =" in "".join(c.source for c in nb.cells):
        values["OUT_DIR"] = str(tmp_path / "out")
    _inject(nb, values)
    nb.cells.insert(0, nbformat.v4.new_code_cell("%reset -f"))
    client = NotebookClient(nb, km=kernel, timeout=120)
    client.execute()
    errors = [
        o
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if o.output_type == "error"
    ]
    assert not errors
    shown = [
        o.get("data", {})
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if o.output_type in ("display_data", "execute_result")
    ]
    assert any("image/png" in d for d in shown), "the notebook shows no figure"
    unrendered = [d for d in shown if str(d.get("text/plain", "")).startswith("<Figure")]
    assert all("image/png" in d for d in unrendered), "a figure was shown as text only"
    assert path.read_bytes() == before  # executed in memory only
