"""The console script ends its process without tearing the interpreter down
(mcrt._exit.leave): what a normal exit guarantees must still hold."""

from __future__ import annotations

import subprocess
import sys
import textwrap

from tests.conftest import ROOT

CORNELL = str(ROOT / "scenes" / "cornell_box.xml")


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=300, cwd=ROOT)


def _console(*argv: str) -> str:
    """Run ``mcrt ARGV`` the way the console script does, with an atexit
    handler registered before mcrt is imported."""
    return f"""
        import atexit, sys
        atexit.register(lambda: print("atexit handler ran", flush=True))
        sys.argv = ["mcrt", *{list(argv)!r}]
        from mcrt.cli import main
        sys.exit(main())
    """


def test_console_script_output_status_and_exit_handlers():
    """stdout arrives whole (it is buffered: a pipe), the exit handlers run,
    the status is the command's."""
    done = _python(_console("plan", CORNELL))
    assert done.returncode == 0, done.stderr
    assert "dimensions per camera path" in done.stdout
    assert done.stdout.rstrip().endswith("atexit handler ran")
    failed = _python(_console("plan", "no-such-scene.xml"))
    assert failed.returncode == 2
    assert failed.stderr.strip() == "mcrt: error: scene file not found: no-such-scene.xml"
    assert "atexit handler ran" in failed.stdout


def test_leave_waits_for_non_daemon_threads():
    """With another non-daemon thread running, leave() returns and the process
    exits the usual way, after that thread; without one, nothing after it runs."""
    done = _python("""
        import threading, time
        from mcrt._exit import leave
        threading.Thread(target=lambda: (time.sleep(0.3), print("thread done"))).start()
        leave(3)
        print("returned", flush=True)
    """)
    assert done.returncode == 0
    assert done.stdout.split() == ["returned", "thread", "done"]
    ended = _python("""
        import sys
        from mcrt._exit import leave
        print("buffered", end="")
        leave(5)
        print("after")
    """)
    assert ended.returncode == 5
    assert ended.stdout == "buffered"


def test_main_with_argv_returns():
    """main(argv), called from Python, returns its status (no exit)."""
    done = _python("""
        from mcrt.cli import main
        code = main(["plan", "no-such-scene.xml"])
        print("returned", code)
    """)
    assert done.returncode == 0 and done.stdout.strip() == "returned 2"
