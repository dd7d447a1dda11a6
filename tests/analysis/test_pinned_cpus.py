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
    code = ("import os; from mcrt.core.machine import machine; "
            "from mcrt.analysis.study.conclude import cpus_line; "
            "print(cpus_line({'cpus': os.cpu_count(), 'machine': machine()}))")
    pinned = subprocess.run(["taskset", "-c", "0", sys.executable, "-c", code],
                            capture_output=True, text=True, check=True).stdout.strip()
    assert pinned.startswith(f"only 1 of the machine's {os.cpu_count()} CPUs were usable")
    if len(os.sched_getaffinity(0)) == os.cpu_count():  # (this process is not pinned)
        free = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              check=True).stdout.strip()
        assert free == ""


# --------------------------------------------------------------------------- a CPU quota
# (docker --cpus=1 sets a cgroup CPU quota and leaves the affinity whole: cpus_usable
# alone did not see it)


def _files(root, files: dict[str, str]):
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_a_cgroup_v2_quota_is_read_from_the_process_cgroup(tmp_path):
    from mcrt.core.machine import cgroup_cpu_quota

    proc, root = tmp_path / "cgroup", tmp_path / "fs"
    _files(tmp_path, {"cgroup": "0::/docker/abc\n", "fs/docker/abc/cpu.max": "100000 100000\n",
                      "fs/docker/cpu.max": "max 100000\n"})
    assert cgroup_cpu_quota(str(proc), str(root)) == 1.0
    (root / "docker/abc/cpu.max").write_text("150000 100000\n")
    assert cgroup_cpu_quota(str(proc), str(root)) == 1.5
    (root / "docker/cpu.max").write_text("50000 100000\n")  # an ancestor's, smaller: it holds
    assert cgroup_cpu_quota(str(proc), str(root)) == 0.5
    for text in ("max 100000\n", "", "garbage", "100000"):  # unlimited, unreadable
        (root / "docker/abc/cpu.max").write_text(text)
        (root / "docker/cpu.max").write_text(text)
        assert cgroup_cpu_quota(str(proc), str(root)) is None
    # in a cgroup namespace (docker's default) the process's cgroup is "/": the mount's own
    _files(tmp_path, {"cgroup": "0::/\n", "fs/cpu.max": "200000 100000\n"})
    assert cgroup_cpu_quota(str(proc), str(root)) == 2.0
    _files(tmp_path, {"cgroup": "0::/../../elsewhere\n"})  # outside this view: the mount's
    assert cgroup_cpu_quota(str(proc), str(root)) == 2.0


def test_a_cgroup_v1_quota_is_read_from_the_cpu_controller(tmp_path):
    from mcrt.core.machine import cgroup_cpu_quota

    proc, root = tmp_path / "cgroup", tmp_path / "fs"
    _files(tmp_path, {"cgroup": "12:memory:/docker/abc\n4:cpu,cpuacct:/docker/abc\n0::/\n",
                      "fs/cpu,cpuacct/docker/abc/cpu.cfs_quota_us": "100000\n",
                      "fs/cpu,cpuacct/docker/abc/cpu.cfs_period_us": "100000\n",
                      "fs/memory/docker/abc/cpu.cfs_quota_us": "1000\n"})  # (not cpu's)
    assert cgroup_cpu_quota(str(proc), str(root)) == 1.0
    (root / "cpu,cpuacct/docker/abc/cpu.cfs_quota_us").write_text("-1\n")  # unlimited
    assert cgroup_cpu_quota(str(proc), str(root)) is None
    (root / "cpu,cpuacct/docker/abc/cpu.cfs_period_us").unlink()
    assert cgroup_cpu_quota(str(proc), str(root)) is None
    # the controller mounted on its own, "cpu"
    _files(tmp_path, {"cgroup": "3:cpu:/\n", "fs/cpu/cpu.cfs_quota_us": "50000",
                      "fs/cpu/cpu.cfs_period_us": "100000"})
    assert cgroup_cpu_quota(str(proc), str(root)) == 0.5


def test_missing_or_unreadable_cgroup_files_mean_no_quota(tmp_path):
    from mcrt.core.machine import cgroup_cpu_quota, machine

    assert cgroup_cpu_quota(str(tmp_path / "none"), str(tmp_path / "none")) is None
    _files(tmp_path, {"cgroup": "0::/a\n3:cpu:/a\nnonsense\n"})
    assert cgroup_cpu_quota(str(tmp_path / "cgroup"), str(tmp_path / "fs")) is None
    (tmp_path / "fs/a/cpu.max").mkdir(parents=True)  # a folder where a file should be
    assert cgroup_cpu_quota(str(tmp_path / "cgroup"), str(tmp_path / "fs")) is None
    assert cgroup_cpu_quota(str(tmp_path), str(tmp_path)) is None  # (a folder, not a file)
    quota = machine()["cpu_quota"]  # this machine's, whatever it is
    assert quota is None or quota > 0


def _limited(cpus, usable, quota) -> dict:
    return {"cpus": cpus, "machine": {"cpus_usable": usable, "cpu_quota": quota}}


def test_the_note_names_the_smaller_of_affinity_and_quota():
    quota = cpus_line(_limited(2, 2, 1.0))
    assert quota == ("only 1 of the machine's 2 CPUs were usable (a cgroup CPU quota: docker "
                     "--cpus, cpu.max): the absolute times hold for 1 CPU, not for the whole "
                     "machine; ratios are unaffected")
    assert "only 1.5 of the machine's 4 CPUs were usable (a cgroup CPU quota" in cpus_line(
        _limited(4, 4, 1.5))
    assert "hold for 1.5 CPUs" in cpus_line(_limited(4, 2, 1.5))  # the quota is smaller
    assert cpus_line(_limited(8, 2, 3.0)) == cpus_line(_env(8, 2))  # the affinity is smaller
    both = cpus_line(_limited(8, 2, 2.0))
    assert "(CPU affinity: taskset, a container's cpuset; a cgroup CPU quota" in both
    assert time_note(_limited(2, 2, 1.0)) == f"{TIME_NOTE} Note: {quota}."
    for quiet in (_limited(2, 2, None), _limited(2, 2, 2.0), _limited(2, 2, 4.0),
                  _limited(2, 2, "1"), _limited(2, 2, float("nan")), _limited(None, 2, 1.0)):
        assert cpus_line(quiet) == ""
