"""Worker processes that end with their parent and stay quiet when it is interrupted.

Used by :func:`pkmctl.sim.simulate.precompile` and by local campaigns: both start
``spawn`` processes that compile or run for minutes, and both must leave nothing behind
when Ctrl-C ends the parent at once (``os._exit``, see ``pkmctl.cli``).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.context
import os
import sys
import threading
from concurrent.futures import ProcessPoolExecutor

#: Held while a worker is launched (its start-up data written to it): a process that
#: ended at once (``os._exit``) in the middle left the worker a traceback on the
#: command's stderr ("EOFError: Ran out of input", 2 of 18 SIGTERMs at that moment).
_LAUNCHING = threading.Lock()


class _Process(multiprocessing.context.SpawnProcess):
    def start(self) -> None:
        with _LAUNCHING:
            super().start()


class _SpawnContext(multiprocessing.context.SpawnContext):
    Process = _Process


def settle(timeout: float = 1.0) -> None:
    """For a process about to end at once (``os._exit``): wait (at most ``timeout`` s)
    until no worker is being launched, keep any other from launching, and send each
    worker the SIGTERM it gets when this process ends (:func:`die_with_parent`) now: one
    still importing has not asked for it yet, and held the command's stderr open up to
    1.7 s after a SIGTERM to a campaign whose workers were starting (a tester)."""
    _LAUNCHING.acquire(timeout=timeout)
    for child in multiprocessing.active_children():
        with contextlib.suppress(OSError, ValueError):
            child.terminate()


def die_with_parent(parent: int) -> None:
    """A worker ends when the process that started it does (Ctrl-C, a kill).

    PR_SET_PDEATHSIG only covers a parent that dies after the call: a worker still
    starting up (a second or more on a loaded machine) when Ctrl-C ends the parent would
    be left compiling for minutes, holding the parent's stderr open. Hence the check of
    the parent after the call."""
    import signal

    try:
        import ctypes

        ctypes.CDLL(None).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG (Linux)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the parent is gone already
        os._exit(1)


def _quiet_resource_tracker() -> None:
    """Start multiprocessing's resource tracker with its stderr on /dev/null.

    The tracker outlives a parent that ends by ``os._exit`` and then cleans up the
    pool's semaphores, as it should, but also prints a multi-line warning about them
    after the one line an interrupted command ends with. It inherits file descriptor 2
    when it starts, so that is pointed at /dev/null for the few milliseconds of its
    start; a tracker already running is left as it is."""
    from multiprocessing import resource_tracker

    sys.stderr.flush()
    saved = os.dup(2)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        resource_tracker.ensure_running()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def spawn_pool(workers: int, modules: tuple[str, ...] = ()) -> ProcessPoolExecutor:
    """A pool of ``workers`` fresh (``spawn``) processes that die with this one and
    import ``modules`` (by name) as they start, besides the plugins."""
    _quiet_resource_tracker()
    return ProcessPoolExecutor(
        workers,
        mp_context=_SpawnContext(),
        initializer=_start,
        initargs=(os.getpid(), tuple(modules)),
    )


#: What this worker could not import as it started: module name (a plugin file's stem) →
#: why. A part its half-run module registered is refused with that reason (its runs said
#: the part "raises" the import's error "in the period starting at t = 0 s": a review).
IMPORT_FAILED: dict[str, str] = {}


def _start(parent: int, modules: tuple[str, ...] = ()) -> None:
    """A worker's start: it dies with ``parent``, and imports the user's plugins
    (``pkmctl --plugin``) and ``modules``, whose parts its runs may use. Ctrl-C here (a
    plugin's import can take seconds) ends it quietly: the pool would log the exception
    with a traceback ("Exception in initializer")."""
    import importlib
    from pathlib import Path

    failed = IMPORT_FAILED
    try:
        die_with_parent(parent)
        if os.environ.get("PKMCTL_PLUGINS"):
            from pkmctl.plugins import PluginError, listed, load_plugins

            for spec in listed():
                try:
                    load_plugins([spec])
                except PluginError as exc:  # (it broke the pool: 16 tracebacks, then "a
                    # worker process died 4 times", the cause unsaid: a code reader)
                    failed[Path(spec).stem if spec.endswith(".py") else spec] = str(exc)
                    sys.stderr.write(f"warning: a worker could not import a plugin: {exc}\n")
        for name in modules:  # a module's name, or its file
            if (Path(name).stem if name.endswith(".py") else name) in failed:
                continue  # said once above (it was said twice: a review)
            try:
                if name.endswith(".py"):
                    from pkmctl.plugins import load_plugins

                    load_plugins([name])
                else:
                    importlib.import_module(name)
            except Exception as exc:  # noqa: BLE001 - its runs then say the part is missing
                text = " ".join(str(exc).split())
                failed[Path(name).stem if name.endswith(".py") else name] = (
                    f"{type(exc).__name__}: {text}"
                )
                sys.stderr.write(f"warning: a worker could not import {name}: "
                                 f"{type(exc).__name__}: {text}\n")  # fmt: skip
    except (KeyboardInterrupt, SystemExit):
        os._exit(130)
