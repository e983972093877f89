"""Users' own parts for the command line: ``pkmctl --plugin my_law.py simulate ...``.

A plugin is a Python file or an importable module that registers parts when it is
imported (``@pkmctl.register_controller(...)``, docs/parts.md). :func:`load_plugins`
imports each one and records them in the environment (``PKMCTL_PLUGINS``), so that the
worker processes pkmctl starts on this machine (a local campaign's) import them too
(:func:`load_from_env`, their initializer). A Dask cluster's workers do not see this
machine's environment: install the module there (e.g. as a package they import).
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import os
import sys
from pathlib import Path

from pkmctl.errors import PkmctlError

__all__ = ["ENV", "PluginError", "load_from_env", "load_plugins"]

#: The environment variable that lists the plugins: a JSON list (a folder's name may hold
#: ``os.pathsep``, which split a path into two that no worker could import: a code
#: reader), or ``os.pathsep``-separated names as set by hand.
ENV = "PKMCTL_PLUGINS"


def listed() -> list[str]:
    """The plugins ``PKMCTL_PLUGINS`` lists."""
    value = os.environ.get(ENV, "")
    if value.startswith("["):
        try:
            names = json.loads(value)
        except ValueError:
            names = None
        if isinstance(names, list) and all(isinstance(n, str) for n in names):
            return [n for n in names if n]
    return [p for p in value.split(os.pathsep) if p]


class PluginError(PkmctlError, ValueError):
    """A plugin that cannot be found or imported (one line: which, and why)."""


def _import(spec: str) -> str:
    """Import one plugin; returns how it is recorded (a file's absolute path, or the
    module name)."""
    path = Path(spec).expanduser()
    if spec.endswith(".py") or path.is_file():
        if not path.is_file():
            raise PluginError(f"--plugin {spec}: no such file")
        path = path.resolve()
        name = path.stem
        if not name.isidentifier():
            raise PluginError(f"--plugin {spec}: {name!r} is not a Python module name")
        module = sys.modules.get(name)
        if module is not None and Path(getattr(module, "__file__", "") or "").resolve() == path:
            return str(path)  # imported already (by this process, or an earlier plugin)
        if module is not None:
            raise PluginError(
                f"--plugin {spec}: a module named {name!r} is imported already "
                f"({getattr(module, '__file__', None) or 'built in'}); rename the file"
            )
        # its folder on the path, as for a script: `from helper import x` beside it works
        folder = str(path.parent)
        if folder not in sys.path:
            sys.path.insert(0, folder)
        loader = importlib.util.spec_from_file_location(name, path)
        if loader is None or loader.loader is None:
            raise PluginError(f"--plugin {spec}: cannot be imported as Python")
        module = importlib.util.module_from_spec(loader)
        sys.modules[name] = module
        try:
            loader.loader.exec_module(module)
        except SystemExit as exc:
            del sys.modules[name]
            raise _exited(spec, exc) from None
        except Exception as exc:
            del sys.modules[name]
            raise PluginError(f"--plugin {spec}: {_why(exc, path)}") from exc
        return str(path)
    try:
        importlib.import_module(spec)
    except SystemExit as exc:
        raise _exited(spec, exc) from None
    except Exception as exc:
        top = spec.split(".")[0]
        here = Path.cwd() / f"{top}.py", Path.cwd() / top / "__init__.py"
        if (
            isinstance(exc, ModuleNotFoundError)
            and exc.name == top
            and any(f.is_file() for f in here)
        ):  # (a console script's path holds its own folder, not the current one)
            raise PluginError(
                f"--plugin {spec}: no module {top!r} on the import path, which does not hold "
                f"the current folder; give the file (--plugin ./{top}.py) or PYTHONPATH=."
            ) from exc
        raise PluginError(f"--plugin {spec}: {_why(exc)}") from exc
    return spec


def _exited(spec: str, exc: SystemExit) -> BaseException:
    """A plugin that called sys.exit while imported: pkmctl exited 0 having done nothing,
    or printed the plugin's argparse usage as its own (a code reader). A worker's Ctrl-C
    (:class:`pkmctl._start.WorkerInterrupted`) goes on as it is."""
    from pkmctl._start import WorkerInterrupted

    if isinstance(exc, WorkerInterrupted):
        return exc
    return PluginError(
        f"--plugin {spec}: the module called sys.exit({exc.code!r}) while it was imported "
        f"(a script's argparse or main code at its top level? put it under "
        f'if __name__ == "__main__":)'
    )


def _why(exc: Exception, own: Path | None = None) -> str:
    """The exception in one line, and where in the user's code it was raised (a
    ZeroDivisionError said no line): the last frame in the plugin's own file ``own``,
    else the last one outside pkmctl, the import machinery and the installed packages
    (not json's decoder.py for a json.loads in the plugin)."""
    import sysconfig
    import traceback

    package = Path(__file__).resolve().parent
    installed = {Path(p).resolve() for p in (sysconfig.get_paths()["stdlib"],
                                             sysconfig.get_paths()["purelib"],
                                             sysconfig.get_paths()["platlib"])}  # fmt: skip
    mine, theirs = None, None
    for frame in traceback.extract_tb(exc.__traceback__):
        if frame.filename.startswith("<"):
            continue
        file = Path(frame.filename).resolve()
        if own is not None and file == own:
            mine = frame
        elif not file.is_relative_to(package) and not any(file.is_relative_to(d)
                                                           for d in installed):  # fmt: skip
            theirs = frame
    frame = mine or theirs
    where = ""
    if frame is not None:
        where = f" ({Path(frame.filename).name}, line {frame.lineno}" + (
            f": {frame.line})" if frame.line else ")"
        )
    text = f"{type(exc).__name__}: {exc}"
    if isinstance(exc, SyntaxError):  # its message names the file and line itself
        return text
    # the place after the message's first line: after a message of several lines it was
    # lost with them, the error being one line (a code reader)
    lines = text.splitlines() or [text]
    return lines[0] + (" [...]" if len(lines) > 1 else "") + where


def load_plugins(specs: list[str]) -> list[str]:
    """Import each plugin (a ``.py`` file or a module name) and add it to ``PKMCTL_PLUGINS``
    for the worker processes started later; returns the recorded names."""
    done = [_import(s) for s in specs]
    os.environ[ENV] = json.dumps(list(dict.fromkeys(listed() + done)))
    return done


def load_from_env() -> None:
    """Import the plugins ``PKMCTL_PLUGINS`` lists (in a worker process)."""
    for spec in listed():
        _import(spec)
