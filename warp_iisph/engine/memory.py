"""How much host memory this process may still take, and what limits it: the memory the system
has available, its control group's limit (cgroup v2 or v1) less what the group uses, and the
address-space and data limits (``ulimit -v``, ``ulimit -d``) less what the process maps."""

from __future__ import annotations

import os
from pathlib import Path

CGROUP = Path("/sys/fs/cgroup")
UNLIMITED = 2**60  # cgroup v1 writes "no limit" as a number near 2^63


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except (OSError, ValueError):
        return None
    if not text.isdigit():  # "max": no limit
        return None
    return int(text)


def _meminfo(key: str) -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            name, _, value = line.partition(":")
            if name == key:
                return int(value.split()[0]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_dirs(controller_root: Path, relative: str) -> list[Path]:
    """The process's group and the groups above it, as this mount shows them (a container's own
    group is often the mount's root: then the path /proc names is not under it)."""
    start = controller_root / relative.lstrip("/")
    if not start.is_dir():
        start = controller_root
    dirs = [start]
    while dirs[-1] != controller_root and controller_root in dirs[-1].parents:
        dirs.append(dirs[-1].parent)
    return dirs


def cgroup_room(membership: Path = Path("/proc/self/cgroup"), root: Path = CGROUP) -> int | None:
    """The least room any of the process's memory control groups leaves (limit less use), from
    its ``membership`` (/proc/self/cgroup) and the groups mounted at ``root``."""
    try:
        lines = Path(membership).read_text().splitlines()
    except OSError:
        return None
    room = None
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, relative = parts
        if controllers == "":  # cgroup v2: one unified hierarchy
            for d in _cgroup_dirs(root, relative):
                limit, used = _read_int(d / "memory.max"), _read_int(d / "memory.current")
                if limit is not None and used is not None:
                    room = min(room, limit - used) if room is not None else limit - used
        elif "memory" in controllers.split(","):  # cgroup v1
            for d in _cgroup_dirs(root / "memory", relative):
                limit, used = _read_int(d / "memory.limit_in_bytes"), _read_int(d / "memory.usage_in_bytes")
                if limit is not None and used is not None and limit < UNLIMITED:
                    room = min(room, limit - used) if room is not None else limit - used
    return room


def _rlimit_room() -> tuple[int, str] | None:
    """Room under ``ulimit -v`` (the address space) and ``ulimit -d`` (the data segment)."""
    try:
        import resource
    except ImportError:  # not on POSIX
        return None
    status = {}
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            name, _, value = line.partition(":")
            if name in ("VmSize", "VmData"):
                status[name] = int(value.split()[0]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    best = None
    for limit_name, used_name, what in (
        ("RLIMIT_AS", "VmSize", "the address-space limit (ulimit -v)"),
        ("RLIMIT_DATA", "VmData", "the data-size limit (ulimit -d)"),
    ):
        soft = resource.getrlimit(getattr(resource, limit_name))[0]
        if soft != resource.RLIM_INFINITY and used_name in status:
            room = soft - status[used_name]
            if best is None or room < best[0]:
                best = (room, what)
    return best


def host_memory_room() -> tuple[int, str] | None:
    """The bytes this process may still allocate on the host and what sets that bound (``None``
    where nothing can be read)."""
    candidates = []
    available = _meminfo("MemAvailable")
    if available is None:
        try:
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            available = None
    if available is not None:
        candidates.append((available, "available"))
    group = cgroup_room()
    if group is not None:
        candidates.append((group, "left under the control group's memory limit"))
    limited = _rlimit_room()
    if limited is not None:
        candidates.append((limited[0], f"left under {limited[1]}"))
    if not candidates:
        return None
    room, what = min(candidates)
    return max(room, 0), what
