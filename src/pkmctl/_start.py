"""The ``pkmctl`` command's start-up: Ctrl-C while pkmctl's imports run (about a
second) printed a Python traceback of 20-40 lines. For that command only (not for a
library user's process), an interrupt then exits at once with status 130 and one line;
the command's first step (its options parsed) puts Python's own handler back.

The command's spawned workers (campaigns, ``reproduce``'s compile workers, a Dask
cluster's) import this too, as they prepare. Ctrl-C reaches every process of the
terminal's group, and a worker then printed a KeyboardInterrupt traceback below the
command's one line (while it started, or idle between tasks). In a worker an interrupt
is ``SystemExit(130)`` instead: it unwinds as KeyboardInterrupt would (``finally``
blocks run, a task returns it to its pool), but ends the process without a word."""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading


def _quiet_interrupt(signum, frame) -> None:  # (nothing to clean up before the command runs)
    sys.stderr.write("interrupted while starting: nothing done\n")
    os._exit(130)


class WorkerInterrupted(SystemExit):
    """A worker's Ctrl-C (exit 130): not a plugin's own sys.exit, which an import names."""


def _quiet_worker_interrupt(signum, frame) -> None:
    raise WorkerInterrupted(130)


def _the_command() -> bool:
    """Whether this process is the ``pkmctl`` command (or one of the workers it spawned,
    which have its argv): its console script, or ``python -m pkmctl``, whose argv[0] is
    "-m" while the package is imported, and its __main__.py's path in a worker (-m took
    Python's handler: a 40-line traceback on Ctrl-C while starting: a code reader)."""
    first = sys.argv[0] if sys.argv else ""
    if os.path.basename(first) == "pkmctl":
        return True
    if first.endswith(os.path.join("pkmctl", "__main__.py")):
        return True
    orig = getattr(sys, "orig_argv", [])
    pairs = zip(orig, orig[1:], strict=False)
    return first == "-m" and any(a == "-m" and b == "pkmctl" for a, b in pairs)


if (
    _the_command()
    and threading.current_thread() is threading.main_thread()
    # an ignored Ctrl-C stays ignored: a script's background job (POSIX starts it so) died
    # of a SIGINT that a plain Python process survives (a code reader)
    and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN
):
    # A spawned worker imports this as it prepares, with the parent's argv:
    # parent_process() is still None then, but the process has its worker's name (the
    # compile workers of `reproduce` each printed the command's line after the parent's).
    _me = multiprocessing.current_process()
    if _me.name == "MainProcess" and not getattr(_me, "_inheriting", False):
        signal.signal(signal.SIGINT, _quiet_interrupt)
    else:
        signal.signal(signal.SIGINT, _quiet_worker_interrupt)
