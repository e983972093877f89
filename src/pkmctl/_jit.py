"""The one place that says how pkmctl compiles its numerical kernels, and where it keeps them.

Options of every kernel:

- ``nogil=True``: kernels release the GIL, so runs can share a process's cores.
- ``error_model="numpy"``: a division by zero gives inf/nan (caught by the loop's
  finiteness check) instead of a Python exception, so no branch guards each division.
- ``fastmath={"contract"}``: lets LLVM fuse a*b + c into one FMA (one rounding instead
  of two). No other fast-math flag: NaN and inf keep their meaning, and no
  reassociation changes results. ``kernel(fastmath=False)`` turns even that off.

``@kernel(refcount=False)`` is for the hot kernels, which only work on arrays their
caller allocated: Numba then emits no reference counting. With it on, every array a
kernel receives or slices costs an atomic increment and decrement; in the closed loop
that was about 40 atomic operations per plant evaluation, 40 % of its time
(docs/performance.md). Such a kernel must not allocate (no ``np.empty``, no copies)
and must not return arrays. The switch is Numba's ``_nrt`` option, which Numba's own
library uses; if a Numba version lacks it, the kernels compile with reference
counting, give the same numbers, and are only slower. Every other kernel says
``_nrt=True`` explicitly: a function compiled while Numba is compiling a refcount-free
caller would otherwise inherit its flags and fail to compile if it allocates.

The disk cache, and why it is not Numba's own (DESIGN.md §6). Numba keys a function's
cache on the modification time of *its own* file: a cached caller does not notice an
edit to a kernel it calls from another file and runs the old code. Here every kernel is
cached in one folder per *content hash of all kernel sources* (every module of pkmctl
that imports this one or Numba), ``<cache root>/<hash>/``: after any edit the hash
changes and everything compiles anew; after a revert the old folder hits again. A loop
specialised for a user's parts (:func:`specialise`) goes into a folder whose hash also
covers the source files of those parts. The cache root is ``$PKMCTL_CACHE_DIR``, else
``$XDG_CACHE_HOME/pkmctl``, else ``~/.cache/pkmctl``; an installed and an editable copy
of the same sources therefore share one cache. If the root cannot be written, kernels
compile in memory on every run (slower, never wrong; :func:`cache_writable`, and the CLI
says so once), except those a read-only cache folder of these sources already holds,
which load from it.

Compilation is announced: inside :func:`announce`, a callback hears when a compilation
starts and ends (the CLI shows "compiling the control loop (once per machine; minutes on
a first run)…" with the elapsed time, on a terminal and as plain lines in a log). For a
library user, whose first call compiled for minutes without a word, each compilation of
a pkmctl function (not of a user's own, even one that calls pkmctl's kernels) is also
logged, in the CLI's words (the logger ``pkmctl``, level INFO: shown once the user asks
for it, e.g. ``logging.basicConfig(level=logging.INFO)``; silent otherwise).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numba
from numba import njit
from numba.core.cpu import CPUTargetOptions

__all__ = [
    "JIT_OPTIONS",
    "NO_REFCOUNT",
    "REFCOUNT",
    "announce",
    "cache_dir",
    "cache_root",
    "cache_writable",
    "compile_note",
    "kernel",
    "settle",
    "source_stamp",
    "specialise",
]

_CAN_SWITCH = hasattr(CPUTargetOptions, "_nrt")
#: Reference counting on, said explicitly (see the module docstring).
REFCOUNT = {"_nrt": True} if _CAN_SWITCH else {}
#: The options of a kernel without reference counting (empty if Numba cannot do that).
NO_REFCOUNT = {"_nrt": False} if _CAN_SWITCH else {}
JIT_OPTIONS = {
    "nogil": True,
    "error_model": "numpy",
    "fastmath": {"contract"},
} | REFCOUNT

_PACKAGE = Path(__file__).resolve().parent


def _hash_files(paths: Iterable[Path], h: hashlib._Hash, root: Path | None = None) -> None:
    for p in sorted(set(paths)):
        h.update(str(p.relative_to(root) if root else p.name).encode())
        h.update(b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")


def _kernel_sources() -> list[Path]:
    """Every module of pkmctl that can hold compiled code (imports this module or Numba)."""
    out = []
    for p in _PACKAGE.rglob("*.py"):
        text = p.read_text(encoding="utf-8", errors="replace")
        if "pkmctl._jit" in text or "import numba" in text or "from numba" in text:
            out.append(p)
    return out


def _package_stamp() -> str:
    h = hashlib.sha256()
    _hash_files(_PACKAGE.rglob("*.py"), h, _PACKAGE)
    return h.hexdigest()[:20]


def _compute_stamp() -> str:
    h = hashlib.sha256()
    h.update(f"numba {numba.__version__} python {sys.version_info[:3]}\0".encode())
    # settings that change the code Numba generates: NUMBA_BOUNDSCHECK=1 had no effect on
    # a cached loop, and a bounds-checked build stayed the cached one after it
    h.update(f"boundscheck {numba.config.BOUNDSCHECK} opt {numba.config.OPT}\0".encode())
    _hash_files(_kernel_sources(), h, _PACKAGE)
    return h.hexdigest()[:20]


_STAMP = _compute_stamp()
_PACKAGE_STAMP = _package_stamp()


def source_stamp() -> str:
    """The content hash of pkmctl's kernel sources (and of Numba's and Python's versions)."""
    return _STAMP


def package_stamp() -> str:
    """The content hash of every module of pkmctl, as this process found them when it
    imported pkmctl: a campaign's worker that runs other code than the campaign's (another
    pkmctl on a Dask worker, a file edited since) says so by it."""
    return _PACKAGE_STAMP


def cache_root() -> Path:
    """The folder that holds one cache folder per source hash (see the module docstring)."""
    return _cache_root()


def _cache_root() -> Path:
    env = os.environ.get("PKMCTL_CACHE_DIR")
    if env:  # "~/x" from a .env file or a Dockerfile's ENV: a folder "~" here (a tester)
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "pkmctl"


def cache_dir(extra_sources: Iterable[str | os.PathLike[str]] = ()) -> Path:
    """The folder of compiled code for pkmctl's sources (and ``extra_sources``)."""
    extra = [Path(p).resolve() for p in extra_sources]
    if not extra:
        return _cache_root() / _STAMP
    h = hashlib.sha256(_STAMP.encode())
    _hash_files(extra, h)
    return _cache_root() / f"{_STAMP}-{h.hexdigest()[:12]}"


# ---------------------------------------------------------------- the disk cache
try:  # Numba's cache classes (stable since 0.50; checked by tests/test_jit.py)
    from numba.core.caching import (
        CompileResultCacheImpl,
        FunctionCache,
        IndexDataCacheFile,
        _CacheLocator,
    )

    _HAVE_CACHE = True
except ImportError:  # pragma: no cover - a Numba without them: compile in memory
    _HAVE_CACHE = False


if _HAVE_CACHE:

    class _Locator(_CacheLocator):
        """Cache files in one given folder, stamped with the source hash."""

        def __init__(self, path: Path, stamp: str, lineno: int) -> None:
            self._path = str(path)
            self._stamp = stamp
            self._lineno = lineno

        def ensure_cache_path(self) -> None:
            os.makedirs(self._path, exist_ok=True)
            tempfile.TemporaryFile(dir=self._path).close()  # raises if not writable

        def get_cache_path(self) -> str:
            return self._path

        def get_source_stamp(self) -> str:
            return self._stamp

        def get_disambiguator(self) -> str:
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):  # never chosen by Numba's own search
            return None

    class _Impl(CompileResultCacheImpl):
        def __init__(self, py_func, locator: _Locator) -> None:  # no locator search
            self._lineno = py_func.__code__.co_firstlineno
            self._locator = locator
            fullname = f"{py_func.__module__}.{py_func.__qualname__}"
            self._filename_base = self.get_filename_base(fullname, getattr(sys, "abiflags", ""))

    class _Cache(FunctionCache):
        """Numba's function cache with our folder and stamp (see the module docstring)."""

        def __init__(self, py_func, path: Path, stamp: str) -> None:
            self._name = repr(py_func)
            self._py_func = py_func
            self._impl = _Impl(py_func, _Locator(path, stamp, py_func.__code__.co_firstlineno))
            self._cache_path = str(path)
            self._cache_file = IndexDataCacheFile(
                cache_path=self._cache_path,
                filename_base=self._impl.filename_base,
                source_stamp=stamp,
            )
            self.enable()

        def save_overload(self, sig, data):
            if getattr(self._py_func, "__pkmctl_llvm_inline__", False):
                _mark_alwaysinline(data)
            try:
                with _SAVING:  # see settle()
                    super().save_overload(sig, data)
            except OSError:  # an unwritable cache: keep the compiled code in memory only
                self.disable()


#: Held while a compiled function is written to the disk cache (a few ms).
_SAVING = threading.Lock()


def settle(timeout: float = 1.0) -> None:
    """Wait (at most ``timeout`` s) until no compiled function is being written to the disk
    cache, and keep any other from starting: for a process about to end at once (Ctrl-C,
    ``os._exit``), which would otherwise leave a half-written temporary file there."""
    _SAVING.acquire(timeout=timeout)


def _mark_alwaysinline(cres) -> None:
    """Ask LLVM to inline this compiled function into every compiled caller.

    Numba links a callee's LLVM module into each caller's before optimising it; the
    attribute set here travels with that module (and with the disk cache), so LLVM's
    inliner puts the body in the caller, where Numba itself would only emit a call.
    """
    fn = cres.library._final_module.get_function(cres.fndesc.llvm_func_name)
    if "noinline" not in str(fn.attributes):
        fn.add_function_attribute("alwaysinline")


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


def cache_writable() -> bool:
    """Whether compiled code is kept on disk: the cache folder of pkmctl's sources can be
    written (else every process compiles again; the CLI says so once, and
    :func:`pkmctl.sim.simulate.precompile` does not compile in worker processes whose
    work could not be shared). Checked once per cache folder and process."""
    return _writable_once(cache_dir())


@functools.cache
def _writable_once(path: Path) -> bool:
    return _writable(path)


def _attach_cache(disp, path: Path, stamp: str):
    if _HAVE_CACHE:
        disp._cache = _Cache(disp.py_func, path, stamp)
        # A folder that cannot be written but exists (a cache made read-only: a container
        # image, a shared site folder) is still read: what it holds loads, and what it
        # lacks compiles in memory (its save fails, and disables it). Everything compiled
        # again (22 s for simulate, 60 s for reproduce: a tester). With no folder at all,
        # the cache is off: compile in memory; _Cache still marks LLVM inlining.
        if not _writable(path) and not path.is_dir():
            disp._cache.disable()
    return disp


def kernel(
    fn=None, *, refcount: bool = True, fastmath: bool = True, llvm_inline: bool = False, **extra
):
    """``@kernel`` = ``@numba.njit`` with :data:`JIT_OPTIONS`, cached as the module says.

    ``refcount=False``: compile without reference counting; ``fastmath=False``: no FMA
    contraction; ``llvm_inline=True``: compiled once, but inlined by LLVM into its
    compiled callers (the heavy model kernels: Numba's own ``inline="always"`` would
    type-infer their large bodies again in every caller, minutes of compile time, while
    a plain call passes every array of the work tuple as separate scalars, a fifth of the
    loop's speed); other keyword arguments are passed to ``njit``.
    """
    options = JIT_OPTIONS | (REFCOUNT if refcount else NO_REFCOUNT) | extra
    if not fastmath:
        options = options | {"fastmath": False}

    def wrap(f):
        if llvm_inline:
            f.__pkmctl_llvm_inline__ = True
        return _attach_cache(njit(**options)(f), cache_dir(), _STAMP)

    return wrap if fn is None else wrap(fn)


_SPECIALISED: dict[tuple, object] = {}
_SPECIALISED_LOCK = threading.Lock()


def specialise(
    py_func: Callable,
    key: tuple,
    sources: Iterable[str],
    *,
    refcount: bool = True,
    values: str = "",
):
    """A dispatcher of ``py_func`` of its own for ``key`` (e.g. a combination of part types).

    Its cache folder's hash covers pkmctl's kernel sources, ``sources`` (the files that
    define the parts in ``key``) and ``values`` (a digest of the global values they
    compile in, :func:`pkmctl.parts.global_values`), so an edit to a user's part, or
    another value of a setting it reads, is never run stale. One dispatcher per key,
    values and process.
    """
    with _SPECIALISED_LOCK:
        disp = _SPECIALISED.get((py_func, key, values))
        if disp is None:
            options = JIT_OPTIONS | (REFCOUNT if refcount else NO_REFCOUNT)
            disp = njit(**options)(py_func)
            folder = specialised_dir(py_func, key, sources, values)
            disp = _attach_cache(disp, folder, folder.parent.name)
            disp.__pkmctl_key__ = key  # for messages
            _SPECIALISED[(py_func, key, values)] = disp
        return disp


def ready(dispatcher, *args) -> None:
    """Compile ``dispatcher`` for ``args``, or load it from the disk cache, without
    running it: what its first call with them would do first (Numba's own dispatch path,
    ``_compile_for_args``), so that the call itself can be timed alone. Only for a
    dispatcher with no compiled signature yet: typing the ~30 arguments costs ~0.9 ms,
    which every later run of a campaign would pay (its runs have the same types). Anything
    else callable (a wrapper) has nothing to compile here."""
    compile_for = getattr(dispatcher, "_compile_for_args", None)
    if compile_for is not None and not dispatcher.signatures:
        compile_for(*args)


def specialised_dir(
    py_func: Callable, key: tuple, sources: Iterable[str], values: str = ""
) -> Path:
    """The cache folder of :func:`specialise`'s dispatcher for ``key``: one per key (and
    ``values``), so that processes compiling different combinations never share an index
    file."""
    sources = sorted({str(Path(s).resolve()) for s in sources if s} - _builtin())
    names = ",".join(f"{getattr(k, '__module__', '')}.{getattr(k, '__qualname__', k)}" for k in key)
    tag = hashlib.sha256(f"{py_func.__module__}.{py_func.__qualname__}|{names}|{values}".encode())
    return cache_dir(sources) / f"{py_func.__name__.strip('_')}-{tag.hexdigest()[:12]}"


@functools.cache
def _builtin() -> frozenset[str]:
    return frozenset(str(p) for p in _kernel_sources())


# ---------------------------------------------------------------- compile announcements
_LOOP_NAMES = {"_run_loop": "the control loop", "_entry": "a controller step"}
#: other kernels by their subpackage (a first reproduce said "compiling the model
#: kernels" for the fuzzy engine's too, three times over)
_GROUP_NAMES = {"fuzzy": "the fuzzy kernels", "ident": "the identification kernels"}


class _Announcer(numba.core.event.Listener):
    """Hears Numba's compile events; reports the outermost compilation of each thread."""

    def __init__(self, callback: Callable[[str, str, float], None], *, own: bool = False) -> None:
        self._callback = callback
        self._own = own  # only compilations whose outermost function is pkmctl's
        self._local = threading.local()

    @staticmethod
    def _function(event) -> tuple[str, list[str]]:
        """The compiled function's name and its module's dotted path."""
        func = getattr(event.data.get("dispatcher"), "py_func", None)
        return getattr(func, "__name__", "kernels"), (getattr(func, "__module__", "") or "").split(
            "."
        )

    def _ours(self, event) -> bool:
        return self._function(event)[1][0] == "pkmctl"

    def _what(self, event) -> str:
        name, package = self._function(event)
        group = package[1] if len(package) > 2 and package[0] == "pkmctl" else ""
        return _LOOP_NAMES.get(name) or _GROUP_NAMES.get(group, "the model kernels")

    def on_start(self, event) -> None:
        depth = getattr(self._local, "depth", 0)
        self._local.depth = depth + 1
        if depth == 0:
            self._local.t0 = time.perf_counter()
            self._local.heard = not self._own or self._ours(event)
            if self._local.heard:
                self._callback("start", self._what(event), 0.0)

    def on_end(self, event) -> None:
        # (getattr: a compilation that began before this listener was in place ends
        # without a start; it must not fail in a listener that is always installed)
        depth = getattr(self._local, "depth", 0)
        if depth == 0:
            return
        self._local.depth = depth - 1
        if depth == 1 and self._local.heard:
            # (Numba's own ``is_failed`` is inverted in 0.58-0.61: read the details)
            failed = getattr(event, "_exc_details", None) is not None
            dt = time.perf_counter() - self._local.t0
            self._callback("failed" if failed else "end", self._what(event), dt)


@contextlib.contextmanager
def announce(callback: Callable[[str, str, float], None]) -> Iterator[None]:
    """Call ``callback(event, what, seconds)`` when a compilation starts ("start") and
    ends ("end", or "failed" for one that raised) inside this block, in any thread;
    ``what`` is e.g. "the control loop".

    A cache hit compiles nothing and says nothing. The CLI shows "compiling the control
    loop (once per machine; minutes on a first run)…" with the elapsed time from it.
    """
    with numba.core.event.install_listener("numba:compile", _Announcer(callback)):
        yield


def compile_note(event: str, kept: bool) -> str:
    """What the CLI and the log say in brackets after "compiling X" (``event`` "start")
    or "compiled X in S s" ("end"): where the code goes, by :func:`cache_writable`."""
    if not kept:
        return "not cached"
    if event == "start":
        return "once per machine; minutes on a first run"
    return "saved in the cache for later runs"


_LOG = logging.getLogger("pkmctl")


def _log_compile(event: str, what: str, seconds: float) -> None:
    if event == "failed":
        _LOG.info("compiling %s failed after %.1f s", what, seconds)
        return
    note = compile_note(event, cache_writable())
    if event == "start":
        _LOG.info("compiling %s (%s)", what, note)
    else:
        _LOG.info("compiled %s in %.1f s (%s)", what, seconds, note)


# every compilation whose outermost function is pkmctl's, in every thread, logged (not a
# user's own Numba function, even one that calls pkmctl's kernels)
numba.core.event.register("numba:compile", _Announcer(_log_compile, own=True))
