"""Estimate floating-point operations per control step by counting them in the source.

This machine exposes no hardware counters (``perf stat`` reports them unsupported), so
the count is static: the abstract syntax tree of each compiled kernel is walked with
its loops unrolled (trip counts are known: 3 coordinates, 4 limbs, 9 bodies, 36
parameters), every ``+ - * /`` on floats counts 1, ``sqrt``/``sin``/``cos`` count 1 each,
calls into other kernels are followed, and integer index arithmetic (anything that
can be evaluated from loop indices and constants alone) counts 0. Where a branch
depends on data, the larger branch is counted (an upper bound); data-dependent loops
take the trip count given in ``hints``. A fused multiply-add counts as 2.

The FLC is the exception: how many rules fire and how many output cells it integrates
depend on its inputs, so :func:`flc_flops` counts it as it runs, on random inputs.

The peak: measured by :mod:`benchmarks.peak` (16 independent scalar FMA chains) when
the caller passes it, else 2 FMA units x 2 flops x the nominal clock of /proc/cpuinfo
(which ignores turbo: 10.4 against 14.7 GFLOP/s measured on the Xeon of
docs/performance.md). The yardstick is the scalar peak, as issue 16 states it; the
compiled single run is mostly scalar, but its plant runs the four limbs as 4-wide SIMD
lanes, so a step can count more than 100 % of it (the vector peak is 4-8x higher).
"""

from __future__ import annotations

import ast
import inspect
import textwrap
from functools import cache
from typing import Any

__all__ = ["count", "estimate"]

_FREE_CALLS = {"min", "max", "abs", "range", "float", "int", "len", "isfinite", "empty", "zeros"}
_COUNTED_CALLS = {"sqrt": 1, "sin": 1, "cos": 1, "exp": 1, "tan": 1}


def _constants(fn) -> dict[str, Any]:
    """The module-level numbers a kernel sees (N_BODIES, ...)."""
    return {k: v for k, v in fn.__globals__.items() if isinstance(v, int | float) and k.isupper()}


class _Unknown(Exception):
    pass


def _kernels() -> dict[str, Any]:
    from pkmctl.control import adaptive, baselines, sliding
    from pkmctl.fuzzy import engine as fuzzy  # its kernels live elsewhere: FLC calls count 0
    from pkmctl.model import dynamics, kinematics
    from pkmctl.sim import actuators, loop, plants, sensors

    table: dict[str, Any] = {}
    mods = (kinematics, dynamics, sliding, adaptive, baselines, plants, sensors, actuators, loop)
    for mod in (*mods, fuzzy):
        for name, obj in vars(mod).items():
            fn = getattr(obj, "py_func", None)
            if fn is not None and getattr(fn, "__module__", None) == mod.__name__:
                table[name] = fn
    return table


@cache
def _tree(fn) -> ast.FunctionDef:
    return ast.parse(textwrap.dedent(inspect.getsource(fn))).body[0]


class _Counter:
    def __init__(self, hints: dict[str, int]):
        self.kernels = _kernels()
        self.hints = hints

    # -- evaluation of integer/boolean expressions from known values --------------------
    def value(self, node: ast.AST, env: dict) -> Any:
        src = ast.unparse(node)
        if src in self.hints:
            return self.hints[src]
        try:
            return eval(compile(ast.Expression(node), "<flops>", "eval"), {"__builtins__": {}}, env)
        except Exception as exc:  # noqa: BLE001 - anything unknown is data
            raise _Unknown(src) from exc

    def known(self, node: ast.AST, env: dict) -> bool:
        try:
            self.value(node, env)
            return True
        except _Unknown:
            return False

    # -- expressions --------------------------------------------------------------------
    def expr(self, node: ast.AST, env: dict) -> int:
        if node is None:
            return 0
        if isinstance(node, ast.BinOp | ast.UnaryOp | ast.BoolOp | ast.Compare) and self.known(
            node, env
        ):
            return 0  # index arithmetic or a constant
        if isinstance(node, ast.BinOp):
            own = 1 if isinstance(node.op, ast.Add | ast.Sub | ast.Mult | ast.Div | ast.Pow) else 0
            return own + self.expr(node.left, env) + self.expr(node.right, env)
        if isinstance(node, ast.Subscript):
            return self.expr(node.value, env)  # the index is integer arithmetic
        if isinstance(node, ast.Call):
            name = (
                node.func.attr
                if isinstance(node.func, ast.Attribute)
                else getattr(node.func, "id", "")
            )
            args = sum(self.expr(a, env) for a in node.args)
            if name in self.kernels:
                return args + self.function(name, node.args, env)
            if name in _COUNTED_CALLS:
                return args + _COUNTED_CALLS[name]
            return args
        if isinstance(node, ast.IfExp):
            return max(self.expr(node.body, env), self.expr(node.orelse, env))
        return sum(self.expr(c, env) for c in ast.iter_child_nodes(node))

    def function(self, name: str, args: list[ast.AST], env: dict) -> int:
        tree = _tree(self.kernels[name])
        inner = _constants(self.kernels[name])
        for param, arg in zip(tree.args.args, args, strict=False):
            try:
                inner[param.arg] = self.value(arg, env)
            except _Unknown:
                pass
        return self.block(tree.body, inner)[0]

    # -- statements ---------------------------------------------------------------------
    def block(self, stmts: list[ast.stmt], env: dict) -> tuple[int, str | None]:
        total = 0
        for st in stmts:
            n, flow = self.stmt(st, env)
            total += n
            if flow:
                return total, flow
        return total, None

    def stmt(self, st: ast.stmt, env: dict) -> tuple[int, str | None]:
        if isinstance(st, ast.Assign):
            n = self.expr(st.value, env)
            for target in st.targets:
                if isinstance(target, ast.Name):
                    try:
                        env[target.id] = self.value(st.value, env)
                    except _Unknown:
                        env.pop(target.id, None)
            return n, None
        if isinstance(st, ast.AugAssign):
            own = 1 if isinstance(st.op, ast.Add | ast.Sub | ast.Mult | ast.Div) else 0
            return own + self.expr(st.value, env), None
        if isinstance(st, ast.Expr | ast.Return):
            return self.expr(st.value, env), ("return" if isinstance(st, ast.Return) else None)
        if isinstance(st, ast.If):
            test = self.expr(st.test, env)
            try:
                branch = st.body if self.value(st.test, env) else st.orelse
                n, flow = self.block(branch, dict(env) | {})
                return test + n, flow
            except _Unknown:
                a, _ = self.block(st.body, dict(env))
                b, _ = self.block(st.orelse, dict(env))
                return test + max(a, b), None
        if isinstance(st, ast.For):
            it = st.iter
            if isinstance(it, ast.Call) and getattr(it.func, "id", "") == "range":
                values = range(*[self.value(a, env) for a in it.args])
            elif isinstance(it, ast.Tuple):
                values = []
                for e in it.elts:
                    try:
                        values.append(self.value(e, env))
                    except _Unknown:
                        values.append(None)
            else:
                values = range(self.value(ast.parse(f"len({ast.unparse(it)})").body[0].value, env))
            total = 0
            for v in values:
                if isinstance(st.target, ast.Name):
                    if v is None:
                        env.pop(st.target.id, None)
                    else:
                        env[st.target.id] = v
                n, flow = self.block(st.body, env)
                total += n
                if flow == "break" or flow == "return":
                    break
            else:
                total += self.block(st.orelse, env)[0]
            return total, None
        if isinstance(st, ast.While):
            raise _Unknown("while loop: give its trip count in hints")
        if isinstance(st, ast.Continue):
            return 0, "continue"
        if isinstance(st, ast.Break):
            return 0, "break"
        return 0, None


def count(kernel: str, *, hints: dict[str, int] | None = None, **known: Any) -> int:
    """Floating-point operations of one call of a compiled kernel (by name).

    ``known`` gives values of its integer arguments (e.g. ``kind=2``); ``hints`` maps
    source text of data-dependent trip counts or shapes to numbers.
    """
    counter = _Counter(hints or {})
    fn = counter.kernels[kernel]
    return counter.block(_tree(fn).body, _constants(fn) | known)[0]


def _clock_ghz() -> float:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.lower().startswith("cpu mhz"):
                    return float(line.split(":")[1]) / 1000.0
    except OSError:
        pass
    return 3.0


#: Flops of the loop's own RK4 bookkeeping per sub-step: 6 plant states, 3 stage
#: updates (a * k + x: 2 flops) and the final h / 6 (k1 + 2 k2 + 2 k3 + k4) (7 flops).
RK4_FLOPS = 6 * (3 * 2 + 7)


class _Counted(float):
    """A float that counts the arithmetic done on it (each result is one too)."""

    ops = 0

    def _new(self, v: float) -> _Counted:
        _Counted.ops += 1
        return _Counted(v)

    def __add__(self, o):
        return self._new(float(self) + float(o))

    __radd__ = __add__

    def __sub__(self, o):
        return self._new(float(self) - float(o))

    def __rsub__(self, o):
        return self._new(float(o) - float(self))

    def __mul__(self, o):
        return self._new(float(self) * float(o))

    __rmul__ = __mul__

    def __truediv__(self, o):
        return self._new(float(self) / float(o))

    def __rtruediv__(self, o):
        return self._new(float(o) / float(self))

    def __pow__(self, o):
        return self._new(float(self) ** float(o))

    def __neg__(self):
        return _Counted(-float(self))  # a sign flip, free as in the static count


def flc_flops(samples: int = 2000, seed: int = 0) -> float:
    """Mean flops of one evaluation of the paper's FLC on the fast kernel, counted as it
    runs (its work depends on how many rules fire and output cells it integrates, which
    the static count cannot know) at ``samples`` uniform random points of its input square.

    The kernels' Python sources run with floats that count their arithmetic (``+ - * /``
    and powers count 1; comparisons, min, max and sign flips 0, as in :func:`count`); each
    result is checked against the compiled kernel's.
    """
    import math

    import numpy as np

    from pkmctl.fuzzy import FLC
    from pkmctl.fuzzy import kernels as K

    ints, reals = tables = FLC().compiled()
    points = np.random.default_rng(seed).uniform(-1.0, 1.0, (samples, 2))
    compiled = [K.flc_grid_eval(tables, a, b) for a, b in points]
    saved = {k: v for k, v in vars(K).items() if hasattr(v, "py_func")}
    saved["_u"] = K._u  # an intrinsic (no Python form): the index itself, as an int
    counts = []
    try:  # the kernels call each other through the module: point it at the sources
        for k, v in saved.items():
            setattr(K, k, int if k == "_u" else v.py_func)
        wrapped = [_Counted(v) for v in reals]
        for (a, b), want in zip(points, compiled, strict=True):
            _Counted.ops = 0
            got = float(K._grid_eval2(ints, wrapped, _Counted(a), _Counted(b)))
            if not math.isclose(got, want, rel_tol=1e-12, abs_tol=1e-15):
                raise AssertionError(f"FLC({a}, {b}): counted run {got} != compiled {want}")
            counts.append(_Counted.ops)
    finally:
        for k, v in saved.items():
            setattr(K, k, v)
    return float(np.mean(counts))


#: The compiled step of each built-in controller, and how many FLC evaluations it makes.
CONTROLLER_KERNELS = {
    "smc": ("smc_step", 0),
    "fsmc": ("fsmc_step", 3),
    "afsmc": ("afsmc_step", 3),
    "pd": ("pd_step", 0),
    "ctc": ("ctc_step", 0),
}

_HINTS = {
    "theta_hat.shape[0]": 36,
    "p.theta0.shape[0]": 36,
    "Y.shape[1]": 36,
    "Y.shape[0]": 3,
    "n": 36,
    "_limbs(q)": 4,  # the limb loops of the dynamics kernels (the four limbs as SIMD lanes)
}


def controller_flops(name: str, flc: float | None = None) -> float:
    """Flops of one step of a built-in controller: its kernel counted statically, plus
    its FLC evaluations at :func:`flc_flops` each (pass ``flc`` to reuse a count)."""
    kernel, n_flc = CONTROLLER_KERNELS[name]
    if n_flc and flc is None:
        flc = flc_flops()
    return float(count(kernel, hints=_HINTS)) + n_flc * (flc or 0.0)


def plant_stage_flops() -> float:
    """Flops of one evaluation of the rigid plant's derivative (one RK4 stage)."""
    return float(count("rigid_derivative", hints=_HINTS))


def estimate(steps_per_s: float, peak_gflops: float | None = None) -> dict[str, float]:
    """Flops per AFSMC control step (paper scenario, 1 RK4 sub-step) and share of peak.

    The loop calls its parts through compile-time dispatch, which this counter cannot
    follow, so a step is counted part by part: 4 plant stages (``rigid_derivative``),
    the controller (``afsmc_step`` and its 3 FLC evaluations), the actuator
    (``ideal_command``) and the RK4 bookkeeping (:data:`RK4_FLOPS`). ``peak_gflops``:
    the measured scalar peak (:func:`benchmarks.peak.scalar_fma_peak`); None takes the
    nominal clock's.
    """
    plant = plant_stage_flops()
    flc = flc_flops()
    controller = controller_flops("afsmc", flc)
    actuator = count("ideal_command", hints=_HINTS)
    per_step = 4 * plant + controller + actuator + RK4_FLOPS
    ghz = _clock_ghz()
    nominal = 2 * 2 * ghz  # 2 FMA pipes x 2 flops, scalar double, at the nominal clock
    peak = nominal if peak_gflops is None else peak_gflops
    gflops = per_step * steps_per_s / 1e9
    return {
        "flops_per_step": float(per_step),
        "plant_eval_flops": float(plant),
        "controller_flops": float(controller),
        "flc_flops": flc,
        "actuator_flops": float(actuator),
        "clock_ghz": ghz,
        "nominal_peak_gflops": nominal,
        "peak_gflops": peak,
        "peak_measured": peak_gflops is not None,
        "gflops": gflops,
        "fraction_of_peak": gflops / peak,
    }
