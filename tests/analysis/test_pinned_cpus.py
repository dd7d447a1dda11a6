"""A study run on fewer CPUs than its machine has (``taskset -c 0 mcrt compare``,
a container's cpuset) recorded ``cpus_usable`` in results.json but said nothing,
while its absolute times were ~70% slower than the machine's (1 of 2 CPUs): the
console and the report's note on time now say which CPU count the times hold for.
No timing is asserted: the lines are built from environment dicts, and from the
facts the study records, taken under taskset."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from mcrt.analysis.report import TIME_NOTE, time_note
from mcrt.analysis.study.conclude import cpus_line


def _env(cpus, usable) -> dict:
    return {"cpus": cpus, "machine": {"cpu_model": "", "cpus_usable": usable, "loadavg": []}}


def test_fewer_usable_cpus_than_the_machine_has_are_noted():
    line = cpus_line(_env(8, 1))
    assert line == ("only 1 of the machine's 8 CPUs were usable (CPU affinity: taskset, a "
                    "container's cpuset): the absolute times hold for 1 CPU, not for the whole "
                    "machine; ratios are unaffected")
    assert "hold for 3 CPUs" in cpus_line(_env(8, 3))
    assert time_note(_env(8, 1)) == f"{TIME_NOTE} Note: {line}."
    for quiet in (_env(8, 8), _env(2, 2), {}, _env(None, 1), _env(8, None), {"cpus": 4}):
        assert cpus_line(quiet) == "" and time_note(quiet) == TIME_NOTE


@pytest.mark.skipif(shutil.which("taskset") is None or (os.cpu_count() or 1) < 2,
                    reason="needs taskset and two CPUs")
def test_a_pinned_process_records_and_notes_its_cpus():
    """The environment a study records (mcrt.analysis.study.runner.environment's
    cpus and machine facts), taken by a process pinned to CPU 0."""
    code = ("import os; from mcrt.core.timing import machine; "
            "from mcrt.analysis.study.conclude import cpus_line; "
            "print(cpus_line({'cpus': os.cpu_count(), 'machine': machine()}))")
    pinned = subprocess.run(["taskset", "-c", "0", sys.executable, "-c", code],
                            capture_output=True, text=True, check=True).stdout.strip()
    assert pinned.startswith(f"only 1 of the machine's {os.cpu_count()} CPUs were usable")
    if len(os.sched_getaffinity(0)) == os.cpu_count():  # (this process is not pinned)
        free = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              check=True).stdout.strip()
        assert free == ""
