"""CPU threads: how many this process may run on (its affinity within a container's quota)."""

from __future__ import annotations

import math
import os

import numpy as np

from .errors import WarpStokesError

__all__ = ["cgroup_cpu_limit", "cpu_threads"]


def cgroup_cpu_limit(root: str = "/sys/fs/cgroup", membership: str = "/proc/self/cgroup") -> int | None:
    """The cores a container's CPU quota allows this process (Linux control groups: ``cpu.max`` of v2, the CFS
    quota and period of v1; the tightest along the process's group and its parents), rounded up; None without a
    quota. A container limited to 2 CPUs on a 64-core host still has all 64 in its affinity: threads beyond the
    quota only wait.

    Examples
    --------
    >>> cgroup_cpu_limit(root="/nonexistent") is None
    True
    """
    def words(path):
        try:
            with open(path, encoding="ascii") as fh:
                return fh.read().split()
        except (OSError, UnicodeDecodeError):
            return []

    def upwards(folder, group):  # the group's folder and its parents' up to the hierarchy's root
        path = group.strip("/")
        while True:
            yield os.path.join(folder, path)
            if not path:
                return
            path = os.path.dirname(path)

    groups = {}  # controllers ("" for the v2 hierarchy, "cpu,cpuacct" for v1's) -> the process's group
    try:
        with open(membership, encoding="utf-8") as fh:
            lines = fh.read().splitlines()
    except (OSError, UnicodeDecodeError):
        lines = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) == 3:
            groups[parts[1]] = parts[2]
    limits = []
    if "" in groups:
        for here in upwards(root, groups[""]):
            values = words(os.path.join(here, "cpu.max"))
            if len(values) == 2 and values[0] != "max":
                limits.append(int(values[0]) / int(values[1]))
    v1 = next((group for controllers, group in groups.items() if "cpu" in controllers.split(",")), None)
    if v1 is not None:
        for here in upwards(os.path.join(root, "cpu"), v1):
            quota = words(os.path.join(here, "cpu.cfs_quota_us"))
            period = words(os.path.join(here, "cpu.cfs_period_us"))
            if quota and period and int(quota[0]) > 0 and int(period[0]) > 0:
                limits.append(int(quota[0]) / int(period[0]))
    return max(1, math.ceil(min(limits))) if limits else None


def cpu_threads(threads: int | None = None) -> int:
    """Threads a CPU bind solves with: ``threads`` when given, else every core this process may run on (its CPU
    affinity, which a batch's workers and containers narrow, within a container's CPU quota:
    :func:`cgroup_cpu_limit`).

    Examples
    --------
    >>> cpu_threads(3), cpu_threads() >= 1
    (3, True)
    """
    if threads is not None:
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
            raise WarpStokesError(f"threads must be a positive number of threads, got {threads!r}")
        return int(threads)
    try:
        cores = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)
    try:
        quota = cgroup_cpu_limit()
    except (OSError, ValueError, ZeroDivisionError):  # an unreadable or malformed group: the affinity alone
        quota = None
    return cores if quota is None else min(cores, quota)
