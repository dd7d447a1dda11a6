"""Advisory locks between mcrt processes: an exclusive ``flock`` on a file.

:func:`waiting_lock` serialises one piece of work between processes (e.g. two
renders of the same reference: the second waits for the first, then finds its
result in the cache). The kernel drops a ``flock`` when its holder ends, however
it ends (a crash, SIGKILL), so a dead holder never blocks anyone; the lock file
is removed by the holder that lets go, and a waiter that finds its file gone or
replaced locks the new one (no two holders at once, no stale files left by
orderly runs; one left by a killed holder is simply locked again).
:func:`hold_directory` locks a directory itself without waiting (a study's
report directory: a second run is refused, :class:`LockBusy`) until
:func:`release`. :func:`lock_owner` names the process that holds a lock, where
the system says (``/proc/locks``). Either lock is shared within a process
(counted) and closed in a forked child (it ends with its holder).

Where ``flock`` is missing (Windows) or refused (some network file systems), the
work goes on unlocked: a lock only saves repeated work here, the results are
written atomically either way.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shlex
import threading
from collections.abc import Iterator
from pathlib import Path

log = logging.getLogger("mcrt.lock")

#: Locks held by this process: key (a lock file's path, or a directory's
#: "dir:device:inode") -> [descriptor, holders].
_HELD: dict[str, list[int]] = {}
_GUARD = threading.Lock()


@contextlib.contextmanager
def waiting_lock(path: str | os.PathLike[str], waiting: str) -> Iterator[None]:
    """Hold the lock of ``path`` (created if missing) for the block, waiting
    while another process holds it. Before waiting, a note: ``waiting`` with
    ``{holder}`` replaced by who holds it (``PID n: its command line`` where
    known, else ``pid unknown``).

    Shared within this process (a block nested in another of the same path, or
    on another thread, does not wait for it). Ctrl-C while waiting raises
    :class:`KeyboardInterrupt` as anywhere else."""
    name = os.path.abspath(os.fspath(path))
    with _GUARD:
        entry = _HELD.get(name)
        if entry is not None:
            entry[1] += 1
    if entry is None:
        fd = _acquire(Path(name), waiting)
        if fd is not None:
            with _GUARD:
                entry = _HELD.setdefault(name, [fd, 0])
                entry[1] += 1
                if entry[0] != fd:  # another thread got there first; share its lock
                    os.close(fd)
    try:
        yield
    finally:
        if entry is not None:
            release(name)


def _acquire(path: Path, waiting: str) -> int | None:
    """A descriptor of ``path`` that holds its exclusive lock; None where this
    file system cannot lock (the work then goes on unlocked)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: no flock
        return None
    said = False
    while True:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:  # an unwritable cache: its writers say so themselves
            log.debug("cannot lock %s (%s)", path, error.strerror)
            return None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                if not said:
                    log.info(waiting.replace("{holder}",
                                             lock_owner(os.fstat(fd)) or "pid unknown"))
                    said = True
                fcntl.flock(fd, fcntl.LOCK_EX)
        except BaseException as error:
            os.close(fd)
            if isinstance(error, OSError):
                log.warning("cannot lock %s (%s): another mcrt doing the same work at the same "
                            "time would not wait for this one", path, error.strerror)
                return None
            raise  # Ctrl-C while waiting
        try:  # the lock is this file's only while it is still the one at ``path``
            if os.path.samestat(os.fstat(fd), os.stat(path)):
                return fd
        except OSError:
            pass
        os.close(fd)  # its holder removed it as it let go: lock the next one


class LockBusy(Exception):
    """Another process holds the lock; ``holder`` says who (see :func:`lock_owner`)."""

    def __init__(self, holder: str) -> None:
        super().__init__(holder)
        self.holder = holder


def hold_directory(directory: str | os.PathLike[str], unlocked: str) -> str | None:
    """Lock ``directory`` itself for this process, without waiting: an exclusive
    ``flock`` on the directory (no file is written; the kernel drops it when the
    process ends). Returns the key to :func:`release`; raises :class:`LockBusy`
    when another process holds it; None, with a warning ending in ``unlocked``
    (what then goes unguarded), where the file system cannot lock. A directory
    this process holds already is shared (counted)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: no flock
        return None
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError as error:
        log.warning("cannot lock %s (%s): %s", directory, error.strerror, unlocked)
        return None
    info = os.fstat(fd)
    key = f"dir:{info.st_dev}:{info.st_ino}"
    with _GUARD:
        if key in _HELD:
            os.close(fd)
            _HELD[key][1] += 1
            return key
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            os.close(fd)
            if isinstance(error, BlockingIOError):
                raise LockBusy(lock_owner(info) or "another process") from None
            log.warning("cannot lock %s (%s): %s", directory, error.strerror, unlocked)
            return None
        _HELD[key] = [fd, 1]
    return key


def release(key: str) -> None:
    """One holder in this process lets go of the lock ``key``; the last one
    unlocks it, and removes a lock file first (while still holding it, so that
    no waiter takes a file about to go)."""
    with _GUARD:
        entry = _HELD.get(key)
        if entry is None:
            return
        entry[1] -= 1
        if entry[1] > 0:
            return
        del _HELD[key]
    if not key.startswith("dir:"):
        with contextlib.suppress(OSError):
            os.unlink(key)
    os.close(entry[0])


def _forget_locks() -> None:
    """In a forked child: close the inherited descriptors (the parent's lock must
    end with the parent, not live on in its children)."""
    for fd, _ in _HELD.values():
        with contextlib.suppress(OSError):
            os.close(fd)
    _HELD.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_locks)


def lock_owner(info: os.stat_result) -> str | None:
    """Who holds a ``flock`` of the file ``info`` describes: "PID n: its command
    line" from ``/proc/locks`` (Linux); None where unknown."""
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    device = f"{os.major(info.st_dev):02x}:{os.minor(info.st_dev):02x}:{info.st_ino}"
    pids = []
    for line in lines:  # "1: FLOCK  ADVISORY  WRITE 4242 fe:00:2146865 0 EOF"
        words = line.split()
        if len(words) >= 6 and words[1] == "FLOCK" and words[5].endswith(f":{info.st_ino}"):
            pids.append((words[5] == device, words[4]))
    if not pids:
        return None
    pid = max(pids)[1]
    return f"PID {pid}: {_command_line(pid)}" if pid.isdigit() else None


def _command_line(pid: str) -> str:
    """The command line of process ``pid`` (interpreter left out), shortened."""
    try:
        words = [w.decode(errors="replace")
                 for w in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") if w]
    except OSError:
        return "command unknown"
    if len(words) > 1 and Path(words[0]).name.startswith("python"):
        words = words[2:] if words[1] == "-m" else words[1:]  # python [-m] mcrt ...
    if not words:
        return "command unknown"
    text = shlex.join([Path(words[0]).name, *words[1:]])
    return text if len(text) <= 300 else text[:297] + "..."


__all__ = ["LockBusy", "hold_directory", "lock_owner", "release", "waiting_lock"]
