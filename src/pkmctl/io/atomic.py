"""The one atomic writer: a file, or a set of files, appears whole or not at all.

Text or bytes go to a temporary file beside the target, which is flushed, given the
permissions a plain ``open`` would give under the current umask (``mkstemp`` makes
it 0600), and renamed over the target only on success. On any error, Ctrl-C
included, the temporary file is removed and the target is untouched.

Files that describe each other (a result's table and its JSON) are written by
:func:`atomic_files`: all to temporary files first, then renamed together, the earlier
renames undone if a later one fails, so that an old file never sits beside a new one.

A set of files (a run's outputs) is written into a staging folder by
:func:`staged_folder` and moved into place when complete, so an interrupted or failed
run leaves the previous results as they were; :func:`check_output_folder` refuses a bad
location (empty, a file, unwritable, a name too long) before any work starts.
"""

from __future__ import annotations

import errno
import os
import re
import tempfile
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO

__all__ = [
    "atomic_files",
    "atomic_write",
    "check_output_file",
    "check_output_folder",
    "discard",
    "file_mode",
    "publish",
    "staged_folder",
]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """The mode a new regular file gets from ``open``: 0o666 less the process umask."""
    return 0o666 & ~_umask()


#: Folders stopped (:func:`stop`; staging folders :func:`discard` removed): nothing may
#: make them again.
_DISCARDED: set[Path] = set()


def make_folder(folder: Path) -> None:
    """``folder.mkdir(parents=True, exist_ok=True)``, refused (FileNotFoundError) inside a
    staging folder :func:`discard` removed: an interrupted run's thread, still writing (a
    thread cannot be stopped), made it again after its removal, and left it behind in 4
    of 10 interrupted ``reproduce`` runs."""
    folder = Path(folder)
    if _discarded(folder):
        raise FileNotFoundError(f"{folder}: its run was interrupted, its folder removed")
    folder.mkdir(parents=True, exist_ok=True)


def _discarded(folder: Path) -> bool:
    return bool(_DISCARDED) and any(p in _DISCARDED for p in (folder, *folder.parents))


#: Held by :func:`stop` and :func:`unless_stopped`: what the block makes is made whole
#: before the folder's stop, or not at all.
_STAGING = threading.RLock()


def stop(folder: Path) -> None:
    """Let no run make or start ``folder`` after this (:func:`unless_stopped`), as
    :func:`discard` does a staging folder: for a command that is interrupted and says
    what it kept, while the run's thread, which cannot be stopped, goes on until the
    process ends."""
    with _STAGING:
        _DISCARDED.add(Path(folder))


@contextmanager
def unless_stopped(folder: Path) -> Iterator[None]:
    """Make ``folder``'s first files inside the block, which runs whole before a
    :func:`stop` of it or not at all (FileNotFoundError): an interrupted ``campaign run``
    said "nothing written", and its thread then made the campaign folder (a tester)."""
    with _STAGING:
        if _discarded(Path(folder)):
            raise FileNotFoundError(errno.ENOENT, "its run was stopped", str(folder))
        yield


@contextmanager
def atomic_write(path: str | os.PathLike[str], mode: str = "w") -> Iterator[IO]:
    """Open a temporary file beside ``path`` (mode ``"w"`` or ``"wb"``); rename it onto
    ``path`` when the block ends without an error."""
    if mode not in ("w", "wb"):
        raise ValueError(f"mode = {mode!r}: must be 'w' or 'wb'")
    path = Path(path)
    make_folder(path.parent)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        text = "b" not in mode
        with os.fdopen(
            fd, mode, encoding="utf-8" if text else None, newline="\n" if text else None
        ) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, file_mode())
        os.replace(tmp, path)
    except BaseException as exc:
        with suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.filename is None and exc.errno is not None:
            # a full disk's write or fsync names no file: name the one being written
            # ("error: No space left on device" alone, from campaign report: a tester;
            # one made from a message alone keeps it: its str would become "[Errno None]")
            exc.filename = str(path)
        raise


@contextmanager
def atomic_files(*paths: str | os.PathLike[str]) -> Iterator[tuple[Path, ...]]:
    """Yield a temporary file beside each of ``paths`` (empty, to write by path); when the
    block ends without an error, rename them onto ``paths`` together, with Ctrl-C held off.

    If a rename fails, those made are undone (each target gets its previous file back, or
    is removed where there was none): the targets stay a set written together, never an
    old file beside a new one. On any error, Ctrl-C included, the temporary files are
    removed. A target that is a folder raises :class:`~pkmctl.errors.OutputError` before
    anything is written.
    """
    from pkmctl.errors import OutputError

    targets = [Path(p) for p in paths]
    for target in targets:
        if _is_folder(target):
            raise OutputError(
                f"{str(target)!r}: is a folder, where a file is to be written: move it away "
                f"or choose another name"
            )
    tmps: list[Path] = []
    try:
        for target in targets:
            make_folder(target.parent)
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
            os.close(fd)
            tmps.append(Path(tmp))
        yield tuple(tmps)
        for tmp in tmps:
            _fsync(tmp)
            os.chmod(tmp, file_mode())
        with _sigint_deferred():
            _replace_together(tmps, targets)
    except BaseException:
        for tmp in tmps:
            with suppress(OSError):
                os.unlink(tmp)
        raise


def _fsync(path: Path) -> None:
    """Flush a file written by path to disk, before it is renamed over an old one."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _replace_together(tmps: list[Path], targets: list[Path]) -> None:
    """Rename each of ``tmps`` onto its target; if one fails, put back what was replaced."""
    done: list[tuple[Path, Path | None]] = []  # (target replaced, its previous file aside)
    try:
        for tmp, target in zip(tmps, targets, strict=True):
            there = target.exists() or target.is_symlink()
            old, linked = _aside(target) if there else (None, False)
            try:
                os.replace(tmp, target)
            except BaseException:
                with suppress(OSError):  # this target not replaced: drop the link, or undo
                    if linked:
                        os.unlink(old)
                    elif old is not None:
                        os.rename(old, target)
                raise
            done.append((target, old))
    except BaseException:
        for target, old in reversed(done):
            with suppress(OSError):
                if old is None:
                    os.unlink(target)
                else:
                    os.rename(old, target)
        raise
    for _, old in done:
        if old is not None:
            with suppress(OSError):
                os.unlink(old)


def _aside(target: Path) -> tuple[Path, bool]:
    """A second name for ``target``'s file, to put it back by, and whether it is a hard
    link (the target stays in place meanwhile) or, where the file system has none, the
    file renamed."""
    import secrets

    while True:
        # no longer than atomic_write's temporary name (TEMP_EXTRA): a file whose name
        # just fitted was written once and then could not be replaced (a tester)
        old = target.with_name(f".{target.name}.old{secrets.token_hex(3)[:5]}.tmp")
        try:
            os.link(target, old, follow_symlinks=False)
        except FileExistsError:
            continue  # (another writer's name: never rename over it)
        except OSError:
            if old.exists() or old.is_symlink():
                continue
            os.rename(target, old)
            return old, False
        return old, True


# ---------------------------------------------------------------- a set of files at once
_STAGE_PREFIX = ".pkmctl-"


#: What atomic_write's temporary name adds to a file's: "." + name + "." + 8 + ".tmp";
#: the name a replaced file is kept by meanwhile adds as much (``_aside``).
TEMP_EXTRA = 14


def _name_max(folder: Path) -> int:
    """The longest file name (bytes) in ``folder``, or in the nearest folder above it
    that exists: the file system the path is on (it was read from "/", whose limit a
    mounted file system, 143 bytes on eCryptfs, need not share)."""
    folder = Path(os.path.abspath(folder))
    while not os.path.isdir(folder) and folder != folder.parent:  # (False if too long)
        folder = folder.parent
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


def check_output_folder(
    path: str | os.PathLike[str], *, what: str = "output folder", writes: Iterable[str] = ()
) -> Path:
    """Check, before any work, that ``path`` can be an output folder: not empty, not an
    existing file nor a link to nothing, no component too long, and the folder (or the
    nearest existing folder above it) writable; and that none of ``writes`` (the paths,
    relative to it, that the run will write; a folder's ends in "/") is there as the
    other kind, a folder where a file goes or a file where a folder goes, which
    :func:`publish` would refuse only at the end, the work lost. Returns ``path`` as a
    :class:`~pathlib.Path`.

    Raises :class:`~pkmctl.errors.OutputError` with one line naming the path and why.
    """
    from pkmctl.errors import OutputError

    text = os.fspath(path)
    if not str(text).strip():
        raise OutputError(f"{what} = {text!r}: empty path (name a folder, e.g. pkmctl-out)")
    path = Path(text).expanduser()  # ("--out=~/x", which the shell leaves: a folder "~")
    shown = repr(text if len(text) <= 80 else text[:60] + "..." + text[-10:])
    limit = _name_max(path)
    for part in path.parts:
        if len(os.fsencode(part)) > limit:  # before any stat(), which would fail unclearly
            raise OutputError(
                f"{what} {shown}: the name {part[:20] + '...'!r} is longer than {limit} bytes"
            )
    if path.is_symlink() and not path.exists():  # the run's folder could not be put there
        raise OutputError(
            f"{what} {shown}: a symbolic link to {os.readlink(path)!r}, which does not exist: "
            "create that folder, or choose another output folder"
        )
    if path.exists() and not path.is_dir():
        raise OutputError(f"{what} {shown}: exists and is not a folder")
    if path.is_dir():
        for rel in writes:
            _check_kind(path, rel)
    probe = path.absolute()
    while not probe.exists():
        if probe.is_symlink():  # a link to nothing above it: makedirs would fail there
            raise OutputError(
                f"{what} {shown}: {str(probe)!r} is a symbolic link to "
                f"{os.readlink(probe)!r}, which does not exist: create that folder, or "
                "choose another output folder"
            )
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{what} {shown}: {str(probe)!r} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {shown}: {str(probe)!r} is not writable{_read_only(probe)}")
    try:  # and try it: access() says yes to root, also where nothing can be made (/proc)
        _probe(probe)
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        raise OutputError(  # (/proc says "No such file or directory": say what was tried)
            f"{what} {shown}: {str(probe)!r} is not writable (creating a folder there failed: "
            f"{why})"
        ) from None
    return path


#: Held while a probe folder exists (:func:`_probe`); :func:`settle` takes it for good.
_PROBE_LOCK = threading.Lock()


def _probe(folder: Path) -> None:
    """Make a folder in ``folder`` and remove it (raises OSError if either fails).

    A Ctrl-C between the two left an empty probe folder in the user's output folder (once
    in a full run): in the main thread it is held until both are done; a worker thread's
    probe is waited for by :func:`settle`, which the CLI calls before its hard exit. The
    name is a staging folder's (:func:`_own_prefix`), so that a later run removes one a
    killed process left (:func:`_sweep`)."""
    with _sigint_deferred(), _PROBE_LOCK:
        # (no "-" after the host's name: _OWNED reads the host up to the last one, and
        # "...@vm-probe-x.tmp" was host "vm-probe", never swept: a reviewer)
        os.rmdir(tempfile.mkdtemp(prefix=_own_prefix(), suffix=".probe.tmp", dir=folder))


def settle(timeout: float = 2.0) -> None:
    """Wait (up to ``timeout`` s) until no probe folder of this process exists, and let
    none be made after: for a process about to exit, abandoning its threads."""
    _PROBE_LOCK.acquire(timeout=timeout)


def _read_only(folder: Path) -> str:
    """ " (a read-only file system)" where ``folder`` is on one (a tester's read-only mount
    was only "not writable", which sends a user to the permissions), else ""."""
    try:
        return " (a read-only file system)" if os.statvfs(folder).f_flag & os.ST_RDONLY else ""
    except (OSError, AttributeError):
        return ""


def _check_kind(dest: Path, rel: str) -> None:
    """Refuse an entry on the way to ``dest / rel`` of the other kind than the run writes
    there (as :func:`_check_kinds` does at the end; a symbolic link is replaced)."""
    from pkmctl.errors import OutputError

    parts = Path(rel.rstrip("/")).parts
    here = dest
    for i, part in enumerate(parts):
        here = here / part
        if here.is_symlink() or not here.exists():
            return
        folder = rel.endswith("/") or i < len(parts) - 1
        if _is_folder(here) != folder:
            mine, theirs = ("a folder", "file") if folder else ("a file", "folder")
            raise OutputError(  # (a name this run writes, or removes as an earlier run's)
                f"output folder: {str(here)!r} is a {theirs}, where pkmctl puts {mine} of "
                "that name: move it away or choose another output folder"
            )


def _stage_parent(dest: Path) -> Path:
    # An existing folder holds its own staging folder (the same file system as the files
    # it replaces, and its parent need not be writable); a new one is staged beside it.
    return dest if dest.is_dir() else dest.absolute().parent


@contextmanager
def staged_folder(dest: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield an empty temporary folder to write a set of files into; when the block ends
    without an error, its files replace those of the same name in ``dest`` (created if
    needed) in a few renames, its folders merged into those of ``dest`` (:func:`publish`).
    On an error or Ctrl-C the temporary folder is removed and ``dest`` is untouched: never
    a mix of old and new files.

    ``dest`` is checked first (:func:`check_output_folder`), so a bad location fails
    before any work. Other entries of an existing ``dest`` are left alone.
    """
    dest = given = check_output_folder(dest)
    # "x/../y" as the system resolves it: made on the way as written, x stayed behind
    # (a failed run removed "x/..", the non-empty current folder, and stopped there)
    dest = Path(os.path.realpath(dest))
    parent = _stage_parent(dest)
    made = [f for f in (parent, *parent.parents) if not f.exists()]  # to remove on failure
    prefix = _own_prefix()
    stage = None
    try:
        # a Ctrl-C between making the folder and the cleanup's knowing of it left the
        # folder behind (one interrupted test in a full run): held until both are done
        with _sigint_deferred():
            try:
                _sweep(parent)  # (not under the lock: it may remove a killed run's 286 MB)
                # not inside a staging folder discard() removed (the run's thread goes on
                # after a Ctrl-C): made before the removal, or not at all
                with unless_stopped(dest):
                    parent.mkdir(parents=True, exist_ok=True)
                    stage = Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=parent))
                os.chmod(stage, 0o777 & ~_umask())  # mkdtemp's 0700 would become dest's mode
            except OSError as exc:
                from pkmctl.errors import OutputError

                _remove_empty(made)
                raise OutputError(f"output folder {str(given)!r}: {exc.strerror}") from None
            _MADE[stage] = made  # discard(stage) removes them too (the CLI's Ctrl-C calls it)
        yield stage
        publish(stage, dest)
    except BaseException:
        if stage is not None:
            discard(stage)
        raise
    finally:
        if stage is not None:
            _MADE.pop(stage, None)


def _own_prefix() -> str:
    """A staging folder's name names its process: ``.pkmctl-<pid>@<host>-``, so that a
    later run can tell one whose process was killed (kill -9, the out-of-memory killer:
    nothing ran to remove it, 286 MB a tester's stayed) from one being written."""
    import platform

    host = re.sub(r"[^A-Za-z0-9.-]", "", platform.node())[:32] or "host"
    return f"{_STAGE_PREFIX}{os.getpid()}@{host}-"


_OWNED = re.compile(r"^\.pkmctl-(\d+)@([A-Za-z0-9.-]*)-[^/]*\.tmp$")
#: A dead process's staging folder is removed once this old (s): never one being made.
STALE_AFTER_S = 60.0


def _sweep(parent: Path) -> None:
    """Remove the staging folders in ``parent`` of processes of this host that are gone
    (never raises): those a killed run left."""
    import shutil
    import time

    host = _own_prefix().rsplit("@", 1)[1][:-1]
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return
    for entry in entries:
        m = _OWNED.match(entry.name)
        if m is None or m.group(2) != host or int(m.group(1)) == os.getpid():
            continue
        try:
            if time.time() - entry.stat(follow_symlinks=False).st_mtime < STALE_AFTER_S:
                continue
            os.kill(int(m.group(1)), 0)  # alive (or another user's): keep it
            continue
        except ProcessLookupError:
            shutil.rmtree(entry.path, ignore_errors=True)
        except (OSError, ValueError, OverflowError):
            continue


#: The folders each live staging folder's run made above it (:func:`staged_folder`).
_MADE: dict[Path, list[Path]] = {}


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders a failed run made above its output, deepest first, as long as
    they are empty (never raises): "OUT was not created" leaves nothing of its path."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            return


def discard(stage: Path) -> None:
    """Remove a staging folder and what it holds, and the folders its run made above it
    (:func:`staged_folder`) that are left empty (never raises)."""
    import shutil
    import time

    # a run's thread or process may still write into it (interrupted: it cannot be
    # stopped): a file made while rmtree walked left the folder behind, about 1 in 6
    # interrupted reproduce runs; so again until it stays gone for a moment
    stop(stage)  # after this, no staging folder is made inside it (staged_folder)
    for _ in range(_DISCARD_TRIES):
        shutil.rmtree(stage, ignore_errors=True)
        time.sleep(0.02)
        if not stage.exists():
            break
    _remove_empty(_MADE.pop(stage, []))


#: How many times :func:`discard` removes a staging folder that comes back (20 ms apart).
_DISCARD_TRIES = 5


def publish(stage: Path, dest: Path) -> None:
    """Move every entry of ``stage`` into ``dest``, replacing files of the same name, then
    remove ``stage``. A folder of ``stage`` (``figures/``) is merged into a folder of
    the same name in ``dest`` file by file, so what else that folder holds stays. A new
    ``dest`` is one rename; an existing one two renames per file, with Ctrl-C held off
    until the set is in place.

    Raises :class:`~pkmctl.errors.OutputError`, before anything is moved, where a file
    would replace a folder of ``dest`` or a folder a file (a run's ``pd.parquet`` where
    ``dest`` has a folder ``pd.parquet/``): such an entry is not one of ours to replace.
    A symbolic link of ``dest`` is replaced, never followed.
    """
    import shutil

    if dest.exists():
        _check_kinds(stage, dest)
    with _sigint_deferred():  # (a Ctrl-C held here is raised once the set is in place)
        if not dest.exists():
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.rename(stage, dest)
            _PUBLISHED.add(stage)
            return
        trash = Path(tempfile.mkdtemp(prefix=_STAGE_PREFIX + "old-", suffix=".tmp", dir=dest))
        done: list[tuple[Path, Path]] = []  # each rename (from, to), to undo on an error
        try:
            _merge(stage, dest, trash, done)
        except BaseException:
            # a rename failed midway (e.g. a nested folder on another file system): put
            # every file back where it was, so dest keeps its previous set, not a mix
            for source, moved in reversed(done):
                with suppress(OSError):
                    os.rename(moved, source)
            shutil.rmtree(trash, ignore_errors=True)
            raise
        _PUBLISHED.add(stage)
        # (inside: a held Ctrl-C raised at the block's end left the old files in dest)
        shutil.rmtree(trash, ignore_errors=True)
        shutil.rmtree(stage, ignore_errors=True)  # its emptied folders


#: The staging folders whose set :func:`publish` has put in place, in this process.
_PUBLISHED: set[Path] = set()


def published(stage: Path | None) -> bool:
    """Whether :func:`publish` has put ``stage``'s set in place (a Ctrl-C it held until
    then is raised after it: the CLI then says the results are there)."""
    return stage in _PUBLISHED


def _is_folder(path: Path) -> bool:
    return path.is_dir() and not path.is_symlink()


def _check_kinds(stage: Path, dest: Path) -> None:
    from pkmctl.errors import OutputError

    for entry in stage.iterdir():
        target = dest / entry.name
        if target.is_symlink() or not target.exists():  # a link is replaced, not followed
            continue
        if _is_folder(entry) and _is_folder(target):
            _check_kinds(entry, target)
        elif _is_folder(entry) != _is_folder(target):
            mine, theirs = ("a folder", "file") if _is_folder(entry) else ("a file", "folder")
            raise OutputError(
                f"output folder: {str(target)!r} is a {theirs}, where this run writes "
                f"{mine}: move it away or choose another output folder"
            )


def _merge(stage: Path, dest: Path, trash: Path, done: list[tuple[Path, Path]]) -> None:
    """Move ``stage``'s entries into the existing folder ``dest`` (see :func:`publish`);
    replaced files go to ``trash`` under numbered names. Each rename is appended to
    ``done`` as (from, to) once made; ``stage``'s folders are left, emptied."""
    for entry in sorted(stage.iterdir()):
        target = dest / entry.name
        if _is_folder(entry) and _is_folder(target):
            _merge(entry, target, trash, done)
            continue
        if target.exists() or target.is_symlink():
            old = trash / f"{len(done)}-{entry.name}"
            os.rename(target, old)
            done.append((target, old))
        os.rename(entry, target)
        done.append((entry, target))


@contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold a Ctrl-C (or a SIGTERM, a SIGHUP) that arrives inside the block until its end
    (main thread only), then give it to the handler that was there."""
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list = []
    held = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    previous = {s: signal.signal(s, lambda *a: caught.append(a)) for s in held}
    try:
        yield
    finally:
        for s in held:
            signal.signal(s, signal.SIG_DFL if previous[s] is None else previous[s])
    if caught:  # to the handler that was there (a library user's own, or none at all)
        signum = caught[0][0]
        handler = previous[signum]
        if callable(handler):
            handler(*caught[0])
        elif handler == signal.SIG_DFL and signum != signal.SIGINT:
            os.kill(os.getpid(), signum)  # the default action, now that the set is whole
        elif handler != signal.SIG_IGN:
            raise KeyboardInterrupt


def check_output_file(path: str | os.PathLike[str], *, what: str = "output file") -> Path:
    """Check, before any work, that a file can be written at ``path`` (not empty, not a
    folder, its folder creatable and writable). Raises :class:`~pkmctl.errors.OutputError`."""
    from pkmctl.errors import OutputError

    text = os.fspath(path)
    if not str(text).strip():
        raise OutputError(f"{what} = {text!r}: empty path")
    path = Path(text).expanduser()  # ("--out=~/x", which the shell leaves)
    longest = _name_max(path.parent) - TEMP_EXTRA
    if len(os.fsencode(path.name)) > longest:  # (242-255 bytes: a traceback after the work)
        raise OutputError(
            f"{what} {text[:60]!r}...: the name is too long (at most {longest} bytes: the "
            f"file is written under a temporary name {TEMP_EXTRA} bytes longer first)"
        )
    if path.is_dir():
        raise OutputError(f"{what} {str(path)!r}: is a folder, not a file")
    if path.exists() and not path.is_file():  # /dev/null, a pipe: replaced by a file
        raise OutputError(
            f"{what} {str(path)!r}: not a regular file (a device, pipe or socket), which "
            "pkmctl would replace with one: give a file's path"
        )
    if path.exists() and not os.access(path, os.W_OK):
        raise OutputError(f"{what} {str(path)!r}: not writable")
    check_output_folder(path.absolute().parent, what=f"{what} {str(path)!r}: its folder")
    return path
