"""Atomic file writes and the error type of mcrt's image I/O.

Every image mcrt writes goes through :func:`atomic_path`: the writer fills a
temporary file *in the destination's directory* (so the final rename never
crosses a file system), the data are flushed to disk, and ``os.replace`` moves
the file into place in one step. A crash or an exception at any point leaves
either the previous file or the new one at ``path``, never a truncated mix, and
the temporary file is removed when the writer fails.

Temporary files are named ``.<name>.<pid>-<random>.tmp`` (hidden, and without
the image extension, so globs such as ``*.exr`` never pick up a half-written
one). A writer killed with SIGKILL cannot remove its file:
:func:`remove_stale_temporaries` removes those whose writer is gone (its pid is
not a live process and the file was not touched for :data:`STALE_SECONDS`), or
that are older than :data:`ABANDONED_SECONDS` whatever their name says.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import time
from collections.abc import Iterator
from pathlib import Path

from ..errors import McrtError


class ImageIOError(McrtError):
    """An image could not be read or written because of the user's path or
    environment (missing directory, permission denied, disk full, not an EXR, ...).

    The message is one line and names the path; ``errno`` is the cause's
    (``ENOSPC``, ``EROFS``, ``EACCES``, ...) when it came from an ``OSError``.
    """

    errno: int | None = None


#: Causes a writer may give only in words (OpenEXR says ``No space left on
#: device.`` in its own exception), as ``os.strerror`` and :func:`_reason` put them.
_CAUSES_IN_WORDS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM,
                    errno.ENOMEM, errno.EFBIG)
_REASONS_IN_WORDS = {"no space left on device": errno.ENOSPC,
                     "disk quota exceeded": errno.EDQUOT,
                     "read-only file system": errno.EROFS, "permission denied": errno.EACCES}


def cause_of(error: BaseException) -> int | None:
    """The ``errno`` of a failed write: the exception's own, else the one its
    message names (a writer's exception that is not an ``OSError``)."""
    code = getattr(error, "errno", None)
    if isinstance(code, int):
        return code
    text = str(error).lower()
    for candidate in _CAUSES_IN_WORDS:
        if os.strerror(candidate).lower() in text:
            return candidate
    return next((c for words, c in _REASONS_IN_WORDS.items() if words in text), None)


def remedy(error: BaseException) -> str:
    """What the user can do about a failed write, from its real cause."""
    code = cause_of(error)
    if code == errno.ENOMEM:
        return "free some memory or raise the memory limit"
    if code in (errno.ENOSPC, errno.EDQUOT):
        return "free some space"
    if code == errno.EROFS:
        return "make the file system writable (or write elsewhere with -o)"
    if code in (errno.EACCES, errno.EPERM):
        return "fix the permissions (or write elsewhere with -o)"
    if code == errno.EFBIG:
        return "raise the file size limit (ulimit -f)"
    return "fix the cause"


def _reason(exc: OSError) -> str:
    """A short, human-readable reason for an ``OSError``."""
    code = exc.errno
    if code == errno.ENOENT:
        return "the directory does not exist"
    if code in (errno.EACCES, errno.EPERM):
        return "permission denied"
    if code == errno.ENOTDIR:
        return "a component of the path is not a directory"
    if code == errno.EISDIR:
        return "the path is a directory"
    if code == errno.EROFS:
        return "read-only file system"
    if code == errno.ENOSPC:
        return "no space left on device"
    if code == errno.EDQUOT:
        return "disk quota exceeded"
    if code == errno.EFBIG:
        return "file too large (over the file size limit, ulimit -f)"
    return exc.strerror or str(exc)


def special_kind(path: str | os.PathLike) -> str | None:
    """What ``path`` is when it exists but is not a regular file: ``"a
    directory"``, ``"a FIFO (named pipe)"``, ``"a socket"``, ``"a character
    device"``, ``"a block device"``; None for a regular file or nothing there.

    Found with ``stat`` (a symbolic link is followed), never by opening the
    file: opening a FIFO for reading waits for a writer, for ever."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISREG(mode):
        return None
    for test, kind in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device")):
        if test(mode):
            return kind
    return "not a regular file"


def refuse_special(path: str | os.PathLike, role: str, remedy: str = "remove it") -> None:
    """One-line :class:`McrtError` if ``path`` (the command's ``role``: its
    output, checkpoint, saved state...) exists but is not a regular file:
    mcrt neither reads nor replaces a FIFO, socket, device or directory there."""
    kind = special_kind(path)
    if kind is not None:
        raise McrtError(f"{os.fspath(path)} ({role}) is {kind}, not a regular file; {remedy}")


def write_error(path: str | os.PathLike, exc: OSError | str) -> ImageIOError:
    """Build the one-line :class:`ImageIOError` for a failed write of ``path``."""
    reason = exc if isinstance(exc, str) else _reason(exc)
    error = ImageIOError(f"cannot write '{os.fspath(path)}': {reason}")
    error.errno = None if isinstance(exc, str) else exc.errno
    return error


def read_error(path: str | os.PathLike, exc: OSError | str) -> ImageIOError:
    """Build the one-line :class:`ImageIOError` for a failed read of ``path``."""
    if isinstance(exc, OSError) and exc.errno == errno.ENOENT:
        reason = "no such file"
    else:
        reason = exc if isinstance(exc, str) else _reason(exc)
    return ImageIOError(f"cannot read '{os.fspath(path)}': {reason}")


def _fsync_file(path: str) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(directory: str) -> None:
    """Persist a rename (best effort: not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _new_temporary(directory: str, name: str) -> str:
    """Create an empty ``.<name>.<pid>-<random>.tmp`` in ``directory`` (a name no
    other writer holds) and return its path; ``OSError`` if it cannot be made."""
    for _ in range(16):
        candidate = os.path.join(directory, f".{name}.{os.getpid()}-{os.urandom(4).hex()}.tmp")
        try:
            # 0o666 & ~umask: the final file gets ordinary permissions (mkstemp's 0o600 would not).
            fd = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return candidate
    raise OSError(errno.EEXIST, "could not create a temporary file")  # pragma: no cover


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, fsync: bool = True) -> Iterator[str]:
    """Yield a temporary path next to ``path``; move it to ``path`` on success.

    Usage::

        with atomic_path("out/image.exr") as tmp:
            write_something(tmp)      # any writer that takes a file name

    * The temporary file already exists (empty, created with the process umask)
      when the block starts; the writer may overwrite or truncate it.
    * If the block raises, the temporary file is removed and the exception
      propagates; ``path`` is untouched.
    * On success the file is flushed (``fsync``) and renamed over ``path`` with
      ``os.replace``, which is atomic on POSIX and Windows.
    * ``OSError`` from creating, flushing or renaming the file is turned into a
      one-line :class:`ImageIOError` (a :class:`~mcrt.errors.McrtError`);
      ``OSError`` raised by the writer inside the block is converted as well.
    """
    final = os.path.abspath(os.fspath(path))
    directory, name = os.path.split(final)
    if not name:
        raise write_error(path, "the path names a directory, not a file")
    if os.path.isdir(final):
        raise write_error(path, "the path is a directory")
    kind = special_kind(final)
    if kind is not None:  # never replaced: a FIFO, socket or device someone put there
        raise write_error(path, f"the path is {kind}, not a regular file")
    if not os.path.isdir(directory):
        reason = ("a component of the path is not a directory" if os.path.exists(directory)
                  else f"the directory '{directory}' does not exist")
        raise write_error(path, reason)

    try:
        tmp = _new_temporary(directory, name)
    except OSError as exc:
        raise write_error(path, exc) from None

    try:
        try:
            yield tmp
        except OSError as exc:
            raise write_error(path, exc) from exc
        try:
            if fsync:
                _fsync_file(tmp)
            os.replace(tmp, final)
        except OSError as exc:
            raise write_error(path, exc) from exc
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if fsync:
        _fsync_dir(directory)


def ensure_readable(path: str | os.PathLike) -> Path:
    """Return ``path`` as a :class:`Path`; raise :class:`ImageIOError` unless it
    is an existing regular file that can be opened for reading."""
    p = Path(path)
    kind = special_kind(p)
    if kind is not None and kind != "a directory":  # opening a FIFO would wait for ever
        raise read_error(path, f"it is {kind}, not a regular file")
    try:
        with open(p, "rb"):
            pass
    except OSError as exc:
        raise read_error(path, exc) from None
    return p


def ensure_writable_dir(directory: Path) -> Path:
    """Create ``directory`` if needed and prove we can write there, before any work."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise McrtError(f"output directory {directory} is a file, not a directory") from None
    except NotADirectoryError:
        raise McrtError(f"cannot create output directory {directory}: a component of the path "
                        f"is a file, not a directory") from None
    except OSError as error:
        raise McrtError(f"cannot create output directory {directory}: {error.strerror}") from None
    if not directory.is_dir():
        raise McrtError(f"output directory {directory} is not a directory")
    try:
        os.unlink(_new_temporary(os.fspath(directory), "mcrt-write-test"))
    except OSError as error:
        raise McrtError(f"cannot write to output directory {directory}: {error.strerror}") from None
    return directory


#: A temporary file of a writer that is not a live process is removed once it
#: has not been touched for this long (a writer of another machine or container
#: sharing the directory keeps touching its file while it writes).
STALE_SECONDS = 60.0

#: A temporary file untouched for this long is abandoned, whoever wrote it.
ABANDONED_SECONDS = 24 * 3600.0

#: ``.<name>.<pid>-<8 hex>.tmp`` (ours) and ``.<name>.<8 hex>.tmp`` (older mcrt).
_TEMPORARY = re.compile(r"^\..+\.(?:(\d+)-)?[0-9a-f]{8}\.tmp$")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return pid < 2**22  # a process of another user (or not a pid at all)
    return True


def remove_stale_temporaries(directory: str | os.PathLike, now: float | None = None) -> int:
    """Remove the temporary files of killed writers in ``directory``; returns how many.

    Only files named like :func:`atomic_path`'s, and only when no live writer
    can own them: the pid in the name is not a live process here and the file
    has not been modified for :data:`STALE_SECONDS`, or it has not been modified
    for :data:`ABANDONED_SECONDS`. Never raises.
    """
    now = time.time() if now is None else now
    removed = 0
    try:
        entries = list(os.scandir(os.fspath(directory)))
    except OSError:
        return 0
    for entry in entries:
        match = _TEMPORARY.match(entry.name)
        if match is None:
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            age = now - entry.stat(follow_symlinks=False).st_mtime
            pid = match.group(1)
            dead = pid is not None and not _alive(int(pid))
            if (dead and age > STALE_SECONDS) or age > ABANDONED_SECONDS:
                os.unlink(entry.path)
                removed += 1
        except OSError:
            continue
    return removed


def free_bytes(path: str | os.PathLike) -> int:
    """Bytes an unprivileged writer can still use on ``path``'s file system
    (``shutil.disk_usage(path).free``, without importing shutil's archivers)."""
    if not hasattr(os, "statvfs"):  # pragma: no cover - not POSIX
        import shutil

        return shutil.disk_usage(path).free
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize


def _unusable(path: Path) -> str | None:
    """Why files cannot be created in the existing ``path`` (or under it), or None."""
    if not path.is_dir():
        return f"{path} is not a directory"
    try:
        st = os.statvfs(path) if hasattr(os, "statvfs") else None
    except OSError:
        st = None
    if st is not None and st.f_flag & os.ST_RDONLY:
        return f"{path} is on a read-only file system"
    if st is not None and st.f_blocks == 0:  # /proc, /sys: no room for files at all
        return f"{path} is on a file system that cannot hold files"
    if not os.access(path, os.W_OK | os.X_OK):
        return f"{path} is not writable"
    return None


def check_free_space(directory: str | os.PathLike, needed: int, what: str = "the outputs",
                     largest: int = 0) -> None:
    """Refuse to start when ``directory`` (or its nearest existing parent) has
    less than ``needed`` bytes free, when it cannot be created or written
    (naming ``$MCRT_CACHE_DIR`` when the path came from it), or when the file
    size limit (``ulimit -f``) is below ``largest``, the largest file to
    write: one-line :class:`McrtError`."""
    check_file_size_limit(largest, what)
    path = Path(directory).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    problem = _unusable(path)
    if problem is not None:
        from ..cache import cache_variable  # the variable the path came from, if any

        where = ", ".join(filter(None, (what, cache_variable(directory))))
        verb = "write to" if path == Path(directory).absolute() else "create"
        raise McrtError(f"cannot {verb} {directory} ({where}): {problem}")
    try:
        free = free_bytes(path)
    except OSError:
        return  # cannot tell: the writes will report their own failure
    if free < needed:
        raise McrtError(f"not enough free space in {directory}: {what} need about "
                        f"{needed / 2**20:.1f} MiB, {free / 2**20:.1f} MiB are free")


def check_file_size_limit(largest: int, what: str = "the outputs") -> None:
    """Refuse to start when the file size limit (``RLIMIT_FSIZE``, ``ulimit
    -f``) is below ``largest`` bytes: every write of such a file fails with
    ``EFBIG``, the checkpoints that would keep the work included, so the work
    would be done and then lost."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if largest and limit != resource.RLIM_INFINITY and limit < largest + (64 << 10):
        raise McrtError(f"the file size limit (ulimit -f) is {limit / 2**20:.1f} MiB, and "
                        f"{what} include a file of about {largest / 2**20:.1f} MiB: raise "
                        f"it (ulimit -f unlimited), or render a smaller image")
