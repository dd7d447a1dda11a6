"""docs/tutorial.ipynb runs from top to bottom without errors, in a fresh kernel."""

from __future__ import annotations

import re
import sys

import pytest

from tests.conftest import ROOT

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOK = ROOT / "docs" / "tutorial.ipynb"


def _text(cell) -> str:
    """The text a code cell printed."""
    return "".join(o.get("text", "") for o in cell.get("outputs", [])
                   if o.get("output_type") == "stream" and o.get("name") == "stdout")


def _kernel_manager(prefix):
    """A kernel manager for a kernel running this interpreter (``sys.executable``),
    from a kernelspec installed in ``prefix``: independent of the kernelspecs the
    machine has (a user-wide ``python3`` kernel may be another Python)."""
    from ipykernel.kernelspec import install
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager

    install(kernel_name="mcrt-test", prefix=str(prefix))
    specs = KernelSpecManager(kernel_dirs=[str(prefix / "share" / "jupyter" / "kernels")],
                              ensure_native_kernel=False)
    assert specs.get_kernel_spec("mcrt-test").argv[0] == sys.executable
    return KernelManager(kernel_name="mcrt-test", kernel_spec_manager=specs)


def test_tutorial_notebook_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("IPYTHONDIR", str(tmp_path / "ipython"))  # no profile in $HOME
    monkeypatch.setenv("JUPYTER_RUNTIME_DIR", str(tmp_path / "runtime"))
    workdir = tmp_path / "work"
    workdir.mkdir()
    nb = nbformat.read(NOTEBOOK, as_version=4)
    assert not any(c.get("outputs") for c in nb.cells if c.cell_type == "code"), \
        "commit the notebook with its outputs cleared"

    client = nbclient.NotebookClient(nb, km=_kernel_manager(tmp_path / "kernel"), timeout=300,
                                     resources={"metadata": {"path": str(workdir)}})
    client.execute()  # raises CellExecutionError on the first failing cell

    code = [c for c in nb.cells if c.cell_type == "code"]
    errors = [o for c in code for o in c.outputs if o.output_type == "error"]
    assert not errors
    text = "\n".join(_text(c) for c in code)
    assert "llvm_ad_rgb" in text and "JitteredSampler" in text
    # the Cornell box against a 1024-spp render: stratification pays
    cornell = dict(re.findall(r"^(\w+) +MSE (\S+)$", text, flags=re.M))
    assert float(cornell["jittered"]) < float(cornell["independent"])
    # the study's table: one row per (sampler, spp) cell, in the study's order
    table = next(_text(c) for c in code if "MSE excess" in _text(c)).splitlines()
    rows = [line.split()[:2] for line in table[1:]]
    assert rows == [["jittered", "4"], ["jittered", "16"],
                    ["independent", "4"], ["independent", "16"]]
    assert all(float(line.split()[2]) > 0 for line in table[1:])
    # the pattern table: discrepancies of three samplers, jittered more uniform than random
    pattern = next(_text(c) for c in code if "L2-star discrepancy" in _text(c)).splitlines()
    values = {line.split()[0]: float(line.split()[1]) for line in pattern[1:]}
    assert set(values) == {"independent", "jittered", "poisson_disk"}
    assert values["jittered"] < values["independent"]
    # every figure was drawn (Cornell box, MSE plot, point sets, radial spectrum)
    figures = sum("image/png" in o.get("data", {}) for c in code for o in c.outputs)
    assert figures == 4
    assert not list(workdir.iterdir()), "the notebook wrote files into its directory"


def test_the_documented_headless_command_runs_the_notebook():
    """docs/python-api.md's command, as a user runs it: `jupyter execute` of the
    environment's Jupyter (no nbconvert), exit status 0, every cell executed."""
    import subprocess
    from pathlib import Path

    jupyter = Path(sys.executable).parent / "jupyter"
    if not jupyter.exists():
        pytest.skip("jupyter is not installed next to this interpreter")
    assert ".venv/bin/jupyter execute docs/tutorial.ipynb" in (
        ROOT / "docs" / "python-api.md").read_text()
    done = subprocess.run([str(jupyter), "execute", "docs/tutorial.ipynb"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    cells = sum(1 for c in nbformat.read(NOTEBOOK, as_version=4).cells if c.cell_type == "code")
    assert cells > 0 and "Executing notebook" in done.stderr
