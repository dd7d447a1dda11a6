"""Two processes that want the same reference at once: the second waits for the
first (a note names it by PID) and takes the finished reference from the cache,
rendering nothing; if the first is killed, the second goes on from its last pass.

Real processes on a tiny scene: the first (the Python API) stops inside its
render, holding the lock, until the test says on its stdin; the second is
``mcrt reference``. No step depends on timing.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT, end_holder, stream_lines

pytestmark = [
    pytest.mark.slow,
]

CORNELL = ROOT / "scenes" / "cornell_box.xml"

#: The reference both want: 8x8 pixels, two passes of 4 samples.
DEFINES = {"res": "8", "max_depth": "2"}
SPP, PER_PASS = 8, 4

#: The first process: renders the reference, and after its first pass (saved to
#: the cache, the lock held) says "holding" and waits for a line on its stdin.
FIRST = f"""
import sys
from mcrt.analysis.reference import get_reference

def on_pass(index, passes):
    if index == 0:
        print("holding", flush=True)
        sys.stdin.readline()

ref = get_reference({str(CORNELL)!r}, {DEFINES!r}, spp={SPP}, spp_per_pass={PER_PASS},
                    on_pass=on_pass)
print("cached" if ref.cached else "rendered", flush=True)
"""


def _env(tmp: Path) -> dict[str, str]:
    return {**os.environ, "MCRT_CACHE_DIR": str(tmp / "cache"), "OPENBLAS_NUM_THREADS": "1"}


def _until(lines: queue.Queue, text: str) -> list[str]:
    """The lines up to the first that holds ``text`` (all of them if none does)."""
    seen: list[str] = []
    while (line := lines.get(timeout=120)) is not None:  # (a bound against a hang)
        seen.append(line)
        if text in line:
            break
    return seen


@pytest.mark.parametrize("end", ["finishes", "killed"])
def test_a_second_reference_waits_for_the_first(tmp_path, end):
    script = tmp_path / "first.py"
    script.write_text(FIRST)
    env = _env(tmp_path)
    first = subprocess.Popen([sys.executable, str(script)], cwd=tmp_path, env=env,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, text=True)
    second = None
    try:
        assert first.stdout.readline() == "holding\n"
        defines = [w for k, v in DEFINES.items() for w in ("-D", f"{k}={v}")]
        second = subprocess.Popen(
            [sys.executable, "-m", "mcrt", "reference", str(CORNELL), *defines, "--spp",
             str(SPP), "--spp-per-pass", str(PER_PASS), "-o", "second.exr"],
            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        notes = stream_lines(second.stderr)
        seen = _until(notes, "is rendering the same reference")
        assert seen and f"mcrt: note: another mcrt (PID {first.pid}: first.py) is rendering " \
            "the same reference: waiting for it, then taking its result" in seen[-1], seen
        assert second.poll() is None  # waiting
        end_holder(first, end)
        second.wait(timeout=120)
        out = second.stdout.read()
        assert second.returncode == 0, _until(notes, "\0")
        first_out, _ = first.communicate(timeout=120)
        if end == "killed":  # its first pass was saved: the second renders the other
            assert first.returncode == -signal.SIGKILL
            assert f"resumed after pass 1 of {SPP // PER_PASS}" in out, out
        else:
            assert first.returncode == 0 and first_out == "rendered\n"
            assert "found in cache" in out and "nothing rendered" in out, out
    finally:
        for process in (first, second):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()
    assert (tmp_path / "second.exr").is_file()
    assert not list((tmp_path / "cache" / "reference").glob("*.lock"))
