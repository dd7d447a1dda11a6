"""mcrt.core.file_lock between real processes: a second process waits for the
holder (and says for whom, by PID), goes on when the holder lets go or is killed
(SIGKILL: the kernel drops its lock), and no lock file stays behind.

The processes load the module from its file (it needs only the standard
library), so each starts in milliseconds; they hold and let go when the test
says, on their stdin: no step depends on timing.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from mcrt.core import file_lock
from mcrt.core.file_lock import waiting_lock
from tests.conftest import end_holder, stream_lines

#: A process that loads file_lock.py and runs ``BODY`` with ``lock`` (waiting_lock)
#: and the lock file's path ``path``; its notes go to stderr.
PRELUDE = f"""
import importlib.util, logging, sys
logging.basicConfig(level=logging.INFO, format="note: %(message)s", stream=sys.stderr)
spec = importlib.util.spec_from_file_location("file_lock", {str(file_lock.__file__)!r})
module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)
lock, path = module.waiting_lock, sys.argv[1]
"""

HOLDER = PRELUDE + """
with lock(path, "waiting for {holder}"):
    print("holding", flush=True)
    sys.stdin.readline()
print("let go", flush=True)
"""

WAITER = PRELUDE + """
with lock(path, "waiting for {holder}"):
    print("got it", flush=True)
"""


def _start(code: str, path: Path) -> subprocess.Popen:
    """A process running ``code`` from a script file beside ``path`` (its command
    line: ``python holder.py PATH``)."""
    script = path.parent / ("holder.py" if code == HOLDER else
                            "waiter.py" if code == WAITER else "holder_with_child.py")
    script.parent.mkdir(parents=True, exist_ok=True)
    script.write_text(code)
    return subprocess.Popen([sys.executable, str(script), str(path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _next(lines: queue.Queue) -> str | None:
    return lines.get(timeout=60)  # (a bound against a hang, not a measurement)


@pytest.mark.parametrize("end", ["let go", "killed"])
def test_a_second_process_waits_for_the_holder(tmp_path, end):
    path = tmp_path / "locks" / "key.lock"
    holder = _start(HOLDER, path)
    waiter = None
    try:
        assert holder.stdout.readline() == "holding\n", holder.stderr.read()
        assert path.is_file()
        waiter = _start(WAITER, path)
        notes = stream_lines(waiter.stderr)
        note = _next(notes)
        assert note == f"note: waiting for PID {holder.pid}: holder.py {path}\n", note
        assert waiter.poll() is None  # blocked on the lock
        end_holder(holder, end)
        waiter.wait(timeout=60)
        rest = list(iter(lambda: _next(notes), None))
        assert waiter.returncode == 0 and not rest, rest  # one note, no error
        assert waiter.stdout.read() == "got it\n"
        holder.communicate(timeout=60)
        assert holder.returncode == (-signal.SIGKILL if end == "killed" else 0)
    finally:
        for process in (holder, waiter):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()
    assert not path.exists()  # the last holder removes it (the killed one's too)


def test_no_note_when_free_and_shared_within_a_process(tmp_path, caplog):
    """A free lock is taken without a note; a block nested in another of the same
    path (or on another thread) shares it instead of waiting for itself."""
    path = tmp_path / "key.lock"
    with waiting_lock(path, "waiting for {holder}"):
        with waiting_lock(path, "waiting for {holder}"):
            assert path.is_file()
        assert path.is_file()  # still held by the outer block
    assert not path.exists() and not caplog.records


HOLDER_WITH_CHILD = PRELUDE + """
import os
with lock(path, "waiting for {holder}"):
    child = os.fork()
    if child == 0:  # outlives its parent, until the test ends it
        sys.stdin.readline()
        os._exit(0)
    print(child, flush=True)
    sys.stdin.readline()
"""


def test_a_killed_holder_s_children_do_not_keep_its_lock(tmp_path):
    """A child forked while its parent held the lock closes its copy of the lock
    file: when the parent is killed (its lock file left in place), the next
    process takes the lock though the child still runs."""
    path = tmp_path / "key.lock"
    holder = _start(HOLDER_WITH_CHILD, path)
    child = 0
    try:
        child = int(holder.stdout.readline())
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=60)
        assert path.is_file()
        waiter = _start(WAITER, path)
        out, err = waiter.communicate(timeout=60)
        assert waiter.returncode == 0 and out == "got it\n" and not err, err
        os.kill(child, 0)  # (still running)
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()
        if child:
            os.kill(child, signal.SIGKILL)
