import atexit
import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen, before anything imports MuJoCo

import numpy as np
import pytest

import pkmctl

#: The 30 real .fis files (../shared/fis-corpus; test data, not in the repository).
CORPUS = Path(__file__).resolve().parents[2] / "shared" / "fis-corpus"
if not CORPUS.is_dir():
    CORPUS = Path("/work/shared/fis-corpus")


def seeded_cache(folder: Path) -> Path:
    """A cache root of a test's own (for ``PKMCTL_CACHE_DIR``) holding a copy of this
    machine's compiled kernels (``cache_root()/source_stamp()``: the model's, the fuzzy
    engine's) and none of its loops, which are kept in folders beside that one. What a
    test is about still compiles (a loop, a user's part); the kernels it calls load. An
    empty cache compiled them all again, a minute of each of the suite's slowest tests.
    What the machine's cache lacks yet (the suite's first run) the test compiles itself."""
    from pkmctl._jit import cache_root, source_stamp

    source = cache_root() / source_stamp()
    target = folder / source_stamp()
    target.mkdir(parents=True)
    for file in source.glob("*.nb[ic]") if source.is_dir() else ():
        try:  # (another worker may be writing the cache: a file replaced as it is read)
            (target / file.name).write_bytes(file.read_bytes())
        except FileNotFoundError:
            continue
    return folder


_SERVER = r"""
import atexit, json, os, signal, sys, traceback
signal.signal(signal.SIGINT, signal.SIG_DFL)  # as a terminal starts a command
import pkmctl.cli, pkmctl.ident.excite, pkmctl.ident.identify  # what commands import late
for line in sys.stdin:
    case = json.loads(line)
    pid = os.fork()
    if pid == 0:  # the command, in a process of its own that has imported pkmctl
        code = 1
        try:
            os.setpgid(0, 0)  # (its group: a command that times out is killed whole)
            os.chdir(case["cwd"])
            for fd, name, flags in ((0, os.devnull, os.O_RDONLY),
                                    (1, case["stdout"], os.O_WRONLY | os.O_CREAT),
                                    (2, case["stderr"], os.O_WRONLY | os.O_CREAT)):
                os.dup2(os.open(name, flags, 0o600), fd)
            sys.argv = ["pkmctl", *case["args"]]
            try:
                pkmctl.cli.main()
                code = 0
            except SystemExit as exc:  # as the interpreter ends a process with it
                if exc.code is None or isinstance(exc.code, int):
                    code = exc.code or 0
                else:
                    print(exc.code, file=sys.stderr)
            except BaseException:
                traceback.print_exc()
            atexit._run_exitfuncs()
        finally:
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except Exception:
                    pass
            os._exit(code)
    print(pid, flush=True)
    _, status = os.waitpid(pid, 0)
    print(os.waitstatus_to_exitcode(status), flush=True)
"""
_SERVERS: dict = {}


def run_pkmctl(*args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    """``python -m pkmctl ARGS`` in ``cwd``, as ``subprocess.run(..., capture_output=True,
    text=True)`` gives it back, with the imports done once: each command is a fork of a
    server that has imported pkmctl's CLI and identification (a single thread, started
    from this process's environment, that has run nothing), so it costs its own work
    alone. Importing took 2-4 s of each of the identification tests' 40-odd commands. A
    test that changed the environment since the server started gets a plain subprocess."""
    env = dict(os.environ)
    server = _SERVERS.get("server")
    if server is None or server.poll() is not None or _SERVERS.get("env") != env:
        if server is not None and server.poll() is None:
            return subprocess.run([sys.executable, "-m", "pkmctl", *args], cwd=cwd,
                                  capture_output=True, text=True, timeout=timeout)  # fmt: skip
        server = subprocess.Popen([sys.executable, "-c", _SERVER], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True)  # fmt: skip
        _SERVERS.update(server=server, env=env)
        atexit.register(server.stdin.close)
    with tempfile.TemporaryDirectory() as tmp:
        out, err = Path(tmp) / "stdout", Path(tmp) / "stderr"
        case = {"args": list(args), "cwd": str(cwd), "stdout": str(out), "stderr": str(err)}
        server.stdin.write(json.dumps(case) + "\n")
        server.stdin.flush()
        pid = int(server.stdout.readline())
        ready, _, _ = select.select([server.stdout], [], [], timeout)
        if not ready:  # the command and what it started, then the server (a reviewer)
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pid, signal.SIGKILL)
            server.kill()
            raise subprocess.TimeoutExpired(["pkmctl", *args], timeout)
        code = int(server.stdout.readline())
        return subprocess.CompletedProcess(["pkmctl", *args], code, out.read_text(),
                                           err.read_text())  # fmt: skip


@pytest.fixture(scope="session", autouse=True)
def _validation_kernels_compiled() -> None:
    """Loading a scenario checks its poses with compiled kinematics; on an empty cache that
    compiles first, and the CLI says so on stderr. The one-line error tests of every file
    are about the error, on a machine that has compiled them (as after any first run)."""
    pkmctl.Scenario.builtin("paper")


@pytest.fixture(scope="session")
def robot() -> pkmctl.Mechanism:
    return pkmctl.Mechanism.paper()


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    """Valid poses spanning the paper's workspace (z 0.55-0.85 m, |angles| <= 0.6 rad)."""
    return np.column_stack(
        [rng.uniform(0.55, 0.85, n), rng.uniform(-0.6, 0.6, n), rng.uniform(-0.6, 0.6, n)]
    )
