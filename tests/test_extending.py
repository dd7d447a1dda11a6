"""docs/extending.md holds: its worked example runs as written, and its tables
say what the code declares."""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
from pathlib import Path

from mcrt.samplers import pointset, registry
from tests.conftest import ROOT

PAGE = (ROOT / "docs" / "extending.md").read_text()


def section(title: str) -> str:
    """The text of the ``## title`` section."""
    start = PAGE.index(f"## {title}")
    end = PAGE.find("\n## ", start + 1)
    return PAGE[start:end if end > 0 else None]


def test_the_worked_example_runs_as_written(tmp_path):
    """The example's bash block, verbatim, in a fresh directory beside the
    repository's scenes (it names ../scenes/...), with the test environment's
    `mcrt` first on PATH, as `bash scripts/setup.sh` leaves it."""
    block = re.search(r"```bash\n(.*?)```", section("Worked example"), re.S)
    assert block is not None
    (tmp_path / "scenes").symlink_to(ROOT / "scenes")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
           "MCRT_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("MCRT_PLUGINS", None)
    run = subprocess.run(["bash", "-e", "-c", block.group(1)], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert re.search(r"all \d+ checks hold", run.stdout), run.stdout
    out = tmp_path / "my-sampler" / "out"
    assert (out / "report.html").is_file()
    with (out / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert {row["sampler"] for row in rows} == {"halton", "sobol", "multijitter"}


def test_the_randomisation_table_is_the_plugins_declaration():
    rows = re.findall(r"^\| `(\w+)`(?: \(default\))? \|", section("Point sets from a file"),
                      re.M)
    assert sorted(rows) == sorted(["randomize", *pointset.RANDOMIZATIONS])  # with the header
    assert f"`{pointset.DEFAULT_RANDOMIZE}` (default)" in PAGE
    for mode in pointset.ONE_D:
        assert f"`{mode}`" in section("Point sets from a file")


def test_every_claim_is_named():
    text = section("A Python generator: no Dr.Jit")
    assert all(f"`{claim}`" in text for claim in registry.CLAIMS), registry.CLAIMS
