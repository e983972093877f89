"""The fuzzy term of FSMC and AFSMC in compiled code: any two-input, one-output system.

u_f,i = -K_u,i FLC(K_s,i s_i, K_sdot,i sdot_i) (eq. 26) evaluates a fuzzy system with
two inputs (s*, sdot*) and one output once per axis and control period. Which system
runs is the scenario's choice (``[fuzzy]``: the paper's FLC by default, or a MATLAB
``.fis`` file); :func:`term_system` turns it into one of two compiled forms:

1. a :class:`~pkmctl.fuzzy.MamdaniSystem` whose tables qualify for the fast kernel (the
   paper's FLC does; docs/fuzzy.md says when) runs as ever on the fast kernel
   (``flc_grid_eval``, :func:`~pkmctl.fuzzy.flc_eval` without its general path), closed
   form, no allocation, ~0.1-0.2 us;
2. anything else runs on the general engine, :class:`~pkmctl.fuzzy.system.FuzzySystem`
   (Mamdani or Sugeno, every method of the toolbox), through its allocation-free kernel
   ``fis_eval2`` with work arrays made once per run by :func:`term_work`.

:func:`term_eval` is the one call compiled code makes. It is a stub whose Numba overload
picks the kernel from the *type* of the tables at compile time (``FISTables`` or
``SystemTables``), so a loop is specialised to one of them and the fast path compiles
to the same call as before; both kernels are compiled without reference counting.
"""

from __future__ import annotations

import numpy as np
from numba.core import types
from numba.extending import overload

from pkmctl._jit import JIT_OPTIONS, NO_REFCOUNT
from pkmctl.fuzzy.engine import FISTables, MamdaniSystem
from pkmctl.fuzzy.general import fis_eval2, new_work
from pkmctl.fuzzy.kernels import FAST_SLOT, flc_grid_eval
from pkmctl.fuzzy.lanes import grid_eval_lanes
from pkmctl.fuzzy.system import FuzzySystem, SystemTables, as_general

__all__ = ["ENGINES", "term_eval", "term_eval_lanes", "term_system", "term_work"]

#: How the fuzzy term's system is compiled: "auto" (the fast kernel when it applies, the
#: general engine otherwise) or "general" (always the general engine).
ENGINES = ("auto", "general")


def term_system(
    system: MamdaniSystem | FuzzySystem,
    *,
    engine: str = "auto",
    source: str | None = None,
    **options,
) -> MamdaniSystem | FuzzySystem:
    """The system the fuzzy term runs for ``system``: itself if it is a
    :class:`MamdaniSystem` on the fast kernel (and ``engine="auto"``, no ``options``),
    else the same system on the general engine (``options``: FuzzySystem fields such as
    ``input_range``, ``samples``).

    Raises ``ValueError`` (one line, naming ``source``, e.g. the file, or else the
    system) unless it has two inputs and one output.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine = {engine!r}: must be one of {', '.join(ENGINES)}")
    if not isinstance(system, MamdaniSystem | FuzzySystem):
        raise TypeError(
            f"fuzzy system: expected a MamdaniSystem or FuzzySystem, got {type(system).__name__}"
        )
    n_out = 1 if isinstance(system, MamdaniSystem) else len(system.outputs)
    if len(system.inputs) != 2 or n_out != 1:
        raise ValueError(
            f"{source or system.name}: {_count(len(system.inputs), 'input')} and "
            f"{_count(n_out, 'output')}; the fuzzy term of FSMC/AFSMC takes 2 inputs "
            "(s*, sdot*) and 1 output"
        )
    fast = isinstance(system, MamdaniSystem) and system.compiled().ints[4] == 1
    if fast and engine == "auto" and not options:
        return system
    return as_general(system, **options)


def _count(n: int, what: str) -> str:
    return f"{n} {what}{'' if n == 1 else 's'}"


def term_work(tables: FISTables | SystemTables) -> tuple:
    """The work arrays :func:`term_eval` needs for ``tables``, made once per run (the fast
    kernel needs none: a placeholder)."""
    if isinstance(tables, SystemTables):
        return new_work(tables.ints)
    return (np.zeros(1),)


def term_eval(tables, work, x1, x2):
    """The output of a compiled two-input system at (x1, x2), in compiled code only.

    Parameters
    ----------
    tables : FISTables or SystemTables
        ``term_system(...).compiled()``.
    work : tuple of arrays
        ``term_work(tables)``; scratch.
    x1, x2 : float
        The inputs (s*, sdot*).

    Returns
    -------
    float
    """
    raise TypeError("term_eval runs in compiled code only")


def _tables_class(t):
    return getattr(t, "instance_class", None) if isinstance(t, types.BaseNamedTuple) else None


@overload(term_eval, jit_options=JIT_OPTIONS | NO_REFCOUNT, strict=False, inline="always")
def _term_eval(tables, work, x1, x2):
    cls = _tables_class(tables)
    if cls is FISTables:

        def fast(tables, work, x1, x2):
            return flc_grid_eval(tables, x1, x2)

        return fast
    if cls is SystemTables:

        def general(tables, work, x1, x2):
            return fis_eval2(tables, work, x1, x2)

        return general
    return None


def term_eval_lanes(tables, work, x1, x2, out):
    """out[l] = :func:`term_eval` (tables, work, x1[l], x2[l]) for every lane l, in
    compiled code only: on the fast kernel, all lanes at once and bit for bit the same
    (:func:`pkmctl.fuzzy.lanes.grid_eval_lanes`); on the general engine, lane by lane."""
    raise TypeError("term_eval_lanes runs in compiled code only")


@overload(term_eval_lanes, jit_options=JIT_OPTIONS | NO_REFCOUNT, strict=False, inline="always")
def _term_eval_lanes(tables, work, x1, x2, out):
    cls = _tables_class(tables)
    if cls is FISTables:

        def fast(tables, work, x1, x2, out):
            ints, reals = tables
            if ints[FAST_SLOT] != 1:
                out[:] = np.nan
                return
            grid_eval_lanes(ints, reals, x1, x2, out)

        return fast
    if cls is SystemTables:

        def general(tables, work, x1, x2, out):
            for l in range(out.shape[0]):
                out[l] = fis_eval2(tables, work, x1[l], x2[l])

        return general
    return None
