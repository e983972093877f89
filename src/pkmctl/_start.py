"""The ``pkmctl`` command's start-up: Ctrl-C while pkmctl's imports run (about a
second) printed a Python traceback of 20-40 lines. For that command only (not for a
library user's process), an interrupt then exits at once with status 130 and one line,
as do SIGTERM (143) and SIGHUP (129), which killed it without a word; the command's
first step (its options parsed) puts its own handlers in place (cli.py).

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
import time

#: When pkmctl's first import began (``time.perf_counter()``): the start of a ``pkmctl``
#: command, whose "interrupted after X s" counts from it (cli.py)
T0 = time.perf_counter()


def _quiet_interrupt(signum, frame) -> None:  # (nothing to clean up before the command runs)
    word = {signal.SIGTERM: "terminated (SIGTERM)", signal.SIGHUP: "hung up (SIGHUP)"}
    sys.stderr.write(f"{word.get(signum, 'interrupted')} while starting: nothing done\n")
    os._exit(128 + signum)


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


if _the_command() and threading.current_thread() is threading.main_thread():
    # A spawned worker imports this as it prepares, with the parent's argv:
    # parent_process() is still None then, but the process has its worker's name (the
    # compile workers of `reproduce` each printed the command's line after the parent's).
    _me = multiprocessing.current_process()
    _command = _me.name == "MainProcess" and not getattr(_me, "_inheriting", False)
    # SIGTERM and SIGHUP as the command handles them later (cli.py), but said while it
    # starts: they killed it without a word (a tester's random signals, 17 of 97)
    for _sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP) if _command else (signal.SIGINT,):
        # an ignored signal stays ignored: a script's background job (POSIX starts it so)
        # died of a SIGINT that a plain Python process survives (a code reader); nohup
        if signal.getsignal(_sig) is not signal.SIG_IGN:
            signal.signal(_sig, _quiet_interrupt if _command else _quiet_worker_interrupt)
