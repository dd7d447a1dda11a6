"""The machine a study times on: CPU model, the CPUs this process may use (CPU
affinity, a cgroup's CPU quota), load averages and other runnable processes.

Recorded with every study (``environment["machine"]``) so that its times can be
read against the machine that took them; the timing protocol itself is
:mod:`mcrt.core.timing`.
"""

from __future__ import annotations

import math
import os
from typing import Any

from .timing import others_running


def _read_text(path: str) -> str | None:
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return f.read()
    except (OSError, ValueError):
        return None


def _cgroup_dirs(root: str, path: str) -> list[str]:
    """``root`` joined with the cgroup ``path`` and each of its ancestors, down to
    ``root`` itself (a limit set on any of them holds; a path outside this view of
    the hierarchy, with ``..`` in it as seen from another cgroup namespace: ``root``
    only)."""
    parts = [p for p in path.strip().split("/") if p]
    if ".." in parts:
        parts = []
    return [os.path.join(root, *parts[:n]) for n in range(len(parts), -1, -1)]


def _quota(quota: str | None, period: str | None) -> float | None:
    """CPUs a CFS quota allows (``quota / period``); None when unlimited (``max``,
    ``-1``) or not a number."""
    try:
        q, p = float((quota or "").strip()), float((period or "").strip())
    except ValueError:
        return None
    return q / p if q > 0 and p > 0 and math.isfinite(q / p) else None


def cgroup_cpu_quota(proc_cgroup: str = "/proc/self/cgroup",
                     root: str = "/sys/fs/cgroup") -> float | None:
    """The CPUs this process's cgroup CPU quota allows (``docker --cpus=1``: 1.0;
    1.5 where it allows one and a half), the smallest over its cgroup and their
    ancestors; None when no quota is set or nothing can be read (not Linux, no
    cgroup filesystem). ``proc_cgroup`` names the process's cgroups (lines
    ``id:controllers:path``), ``root`` the cgroup mount: cgroup v2's ``cpu.max``
    (``"100000 100000"``, or ``"max 100000"``: none) under ``root``; cgroup v1's
    ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us`` (-1: none) under the ``cpu``
    controller's mount, ``root/cpu`` or ``root/cpu,cpuacct``. CPU affinity
    (taskset, a cpuset) is apart: :func:`machine`'s ``cpus_usable``."""
    text = _read_text(proc_cgroup)
    if text is None:
        return None
    found: list[float] = []
    for line in text.splitlines():
        fields = line.split(":", 2)
        if len(fields) != 3:
            continue
        controllers, path = fields[1], fields[2]
        if fields[0] == "0" and controllers == "":  # cgroup v2, the unified hierarchy
            for directory in _cgroup_dirs(root, path):
                parts = (_read_text(os.path.join(directory, "cpu.max")) or "").split()
                if len(parts) == 2:
                    allowed = _quota(*parts)
                    if allowed is not None:
                        found.append(allowed)
        elif "cpu" in controllers.split(","):  # cgroup v1's cpu controller
            mounts = dict.fromkeys([controllers, "cpu", "cpu,cpuacct", "cpuacct,cpu"])
            for mount in mounts:
                if not os.path.isdir(os.path.join(root, mount)):
                    continue
                for directory in _cgroup_dirs(os.path.join(root, mount), path):
                    allowed = _quota(_read_text(os.path.join(directory, "cpu.cfs_quota_us")),
                                     _read_text(os.path.join(directory, "cpu.cfs_period_us")))
                    if allowed is not None:
                        found.append(allowed)
                break
    return min(found) if found else None


def machine() -> dict[str, Any]:
    """Machine facts that bear on timing: CPU model, CPUs usable (CPU affinity),
    the CPUs a cgroup's CPU quota allows (:func:`cgroup_cpu_quota`; None: no
    quota), load averages."""
    model = ""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        usable = os.cpu_count() or 1
    try:
        load = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = []
    quota = cgroup_cpu_quota()
    return {"cpu_model": model, "cpus_usable": usable,
            "cpu_quota": None if quota is None else round(quota, 3), "loadavg": load,
            "others_running": others_running()}


__all__ = ["cgroup_cpu_quota", "machine"]
