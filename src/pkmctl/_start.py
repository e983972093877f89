"""The ``pkmctl`` command's start-up: Ctrl-C while pkmctl's imports run (about a
second) printed a Python traceback of 20-40 lines. For that command only (not for a
library user's process), an interrupt then exits at once with status 130 and one line;
the command's first step (its options parsed) puts Python's own handler back."""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading


def _quiet_interrupt(signum, frame) -> None:  # (nothing to clean up before the command runs)
    sys.stderr.write("interrupted while starting: nothing done\n")
    os._exit(130)


if (
    os.path.basename(sys.argv[0] if sys.argv else "") == "pkmctl"
    # not in a spawned worker, which imports this as it prepares, with the parent's argv:
    # parent_process() is still None then, but the process has its worker's name (the
    # compile workers of `reproduce` each printed this line after the parent's)
    and multiprocessing.current_process().name == "MainProcess"
    and not getattr(multiprocessing.current_process(), "_inheriting", False)
    and threading.current_thread() is threading.main_thread()
):
    signal.signal(signal.SIGINT, _quiet_interrupt)
