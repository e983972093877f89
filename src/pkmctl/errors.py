"""Exceptions raised by pkmctl.

Every error a user can provoke is a :class:`PkmctlError`; the ones caused by a bad
value also derive from :class:`ValueError`, so ``except ValueError`` keeps working.
"""

from __future__ import annotations

__all__ = [
    "ConvergenceError",
    "InsufficientMemory",
    "InvalidPoseError",
    "NonFiniteInputError",
    "NonFiniteOutputError",
    "OutputError",
    "PkmctlError",
    "SimulationDiverged",
]


class PkmctlError(Exception):
    """Base class of every pkmctl error."""


class InvalidPoseError(PkmctlError, ValueError):
    """A pose X = [z, alpha, beta] outside the valid set (z <= 0, |angle| >= pi/2, singular J)."""


class NonFiniteInputError(PkmctlError, ValueError):
    """An input holding NaN or inf (e.g. to :meth:`Controller.step`); nothing was changed."""


class NonFiniteOutputError(PkmctlError, ValueError):
    """Finite inputs that gave a force of NaN or inf (e.g. :meth:`Controller.step` at an
    absurd velocity); the controller's state was restored."""


class OutputError(PkmctlError, OSError):
    """An output location that cannot be written (one line: the path and why)."""


class InsufficientMemory(PkmctlError, MemoryError):
    """A run whose arrays would not fit in the memory available (one line: needs, has)."""


class ConvergenceError(PkmctlError, RuntimeError):
    """An iterative solver did not converge; ``residual`` holds its last residual."""

    def __init__(self, message: str, *, residual: float) -> None:
        super().__init__(message)
        self.residual = residual


class SimulationDiverged(PkmctlError, RuntimeError):
    """A closed-loop run left the valid set or produced a non-finite state.

    ``time`` and ``state`` name where it happened; ``partial`` holds the result computed so far.
    """

    def __init__(self, message: str, *, time: float, state, partial=None) -> None:
        super().__init__(message)
        self.time = time
        self.state = state
        self.partial = partial


def short_repr(value, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters ("..." at the end) for a one-line
    message: a 100,000-character value made a line of 100,200 (a fuzzer)."""
    shown = repr(value)
    return shown if len(shown) <= limit else shown[: limit - 3] + "..."


def toml_error(exc: Exception, text: str) -> str:
    """A TOML parse error with the line it points at: Python's "Cannot overwrite a value
    (at line 84, column 11)" named no key (a duplicated ``eps = ...``: a fuzzer)."""
    import re

    message = str(exc)
    m = re.search(r"at line (\d+)", message)
    lines = text.splitlines()
    if m is None or not 1 <= int(m.group(1)) <= len(lines):
        return message
    line = lines[int(m.group(1)) - 1].strip()
    return f"{message}: {short_repr(line)}" if line else message
