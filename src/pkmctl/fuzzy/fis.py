"""Read and write MATLAB Fuzzy Logic Toolbox ``.fis`` files (the Mamdani subset pkmctl runs).

Supported: ``Type='mamdani'``, one output, AndMethod='min', ImpMethod='min',
AggMethod='max', DefuzzMethod='centroid'; membership types trimf, trapmf, gaussmf, zmf,
smf; AND rules (connective 1) with any weight in [0, 1] and "don't care" (0) antecedents.
Rejected with :class:`FISError` (naming the line): Sugeno systems, other methods, other
membership types, OR rules (connective 2), negated (NOT) terms, rules without a consequent.
OrMethod is read but unused, since OR rules are rejected.

The text format is MATLAB's (``writefis``)::

    [System]
    Name='paper_flc'
    Type='mamdani'
    ...
    [Input1]
    Name='s'
    Range=[-1 1]
    NumMFs=7
    MF1='NB':'zmf',[-1 -0.6666666666666667]
    ...
    [Rules]
    1 1, 7 (1) : 1

Rule lines are: one term index per input (1-based, 0 = don't care), a comma, the output
term index, the weight in parentheses, a colon and the connective. Note that MATLAB's
gaussmf parameters are [sigma mean]; pkmctl's ``Term`` keeps (mean, sigma).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import NoReturn

from pkmctl.fuzzy.engine import MF_KINDS, MamdaniSystem, Rule, Term, Variable
from pkmctl.io.atomic import atomic_write

__all__ = ["FISError", "read_fis", "to_fis_text", "write_fis"]

_METHODS = {"AndMethod": "min", "ImpMethod": "min", "AggMethod": "max", "DefuzzMethod": "centroid"}
_MF_LINE = re.compile(r"'([^']*)'\s*:\s*'([^']*)'\s*,\s*\[([^\]]*)\]")
_RULE_LINE = re.compile(r"([-+\d\s]+),([-+\d\s]+)\(([^)]*)\)\s*:\s*([-+\d]+)")
_SECTION = re.compile(r"\[(System|Input\d+|Output\d+|Rules)\]")


class FISError(ValueError):
    """A .fis file that is malformed or uses a feature pkmctl does not support.

    Attributes ``source`` (file name or ``"<string>"``), ``lineno`` (1-based) and ``line``.
    """

    def __init__(self, source: str, lineno: int, message: str, line: str = "") -> None:
        self.source, self.lineno, self.line = source, lineno, line
        super().__init__(f"{source}:{lineno}: {message}" + (f" in: {line}" if line else ""))


class _Section:
    def __init__(self, name: str, lineno: int) -> None:
        self.name, self.lineno = name, lineno
        self.keys: dict[str, tuple[str, int, str]] = {}  # key -> (value, lineno, line)
        self.rules: list[tuple[int, str]] = []


class _Reader:
    def __init__(self, text: str, source: str) -> None:
        self.source = source
        self.sections: dict[str, _Section] = {}
        self.nlines = max(1, len(text.splitlines()))
        current: _Section | None = None
        for lineno, raw in enumerate(text.splitlines(), start=1):
            line = raw.strip()
            if not line or line.startswith(("%", "#")):
                continue
            if line.startswith("["):
                m = _SECTION.fullmatch(line)
                if m is None:
                    self.fail(
                        lineno,
                        "unknown section (expected [System], [InputN], [OutputN] or [Rules])",
                        line,
                    )
                if m.group(1) in self.sections:
                    self.fail(lineno, f"duplicate section [{m.group(1)}]", line)
                current = self.sections[m.group(1)] = _Section(m.group(1), lineno)
            elif current is None:
                self.fail(lineno, "text before the first section", line)
            elif current.name == "Rules":
                current.rules.append((lineno, line))
            else:
                key, sep, value = line.partition("=")
                if not sep or not key.strip():
                    self.fail(lineno, "expected Key=Value", line)
                if key.strip() in current.keys:
                    self.fail(lineno, f"duplicate key {key.strip()!r}", line)
                current.keys[key.strip()] = (value.strip(), lineno, line)

    def fail(self, lineno: int, message: str, line: str = "") -> NoReturn:
        raise FISError(self.source, lineno, message, line)

    def section(self, name: str) -> _Section:
        if name not in self.sections:
            self.fail(self.nlines, f"missing section [{name}]")
        return self.sections[name]

    def raw(self, sec: _Section, key: str) -> tuple[str, int, str]:
        if key not in sec.keys:
            self.fail(sec.lineno, f"[{sec.name}] has no {key}")
        return sec.keys[key]

    def string(self, sec: _Section, key: str) -> str:
        value, lineno, line = self.raw(sec, key)
        if len(value) < 2 or value[0] != "'" or value[-1] != "'":
            self.fail(lineno, f"{key} must be a quoted string", line)
        return value[1:-1]

    def integer(self, sec: _Section, key: str, lo: int) -> int:
        value, lineno, line = self.raw(sec, key)
        try:
            n = int(value)
        except ValueError:
            n = lo - 1
        if n < lo:
            self.fail(lineno, f"{key} must be an integer >= {lo}", line)
        return n

    def numbers(self, text: str, lineno: int, line: str) -> list[float]:
        try:
            return [float(v) for v in text.replace(",", " ").split()]
        except ValueError:
            self.fail(lineno, f"not a list of numbers: [{text}]", line)

    def variable(self, name: str) -> Variable:
        sec = self.section(name)
        value, lineno, line = self.raw(sec, "Range")
        if not (value.startswith("[") and value.endswith("]")):
            self.fail(lineno, "Range must be [lo hi]", line)
        rng = self.numbers(value[1:-1], lineno, line)
        if len(rng) != 2 or not rng[0] < rng[1]:
            self.fail(lineno, "Range must be [lo hi] with lo < hi", line)
        n_mf = self.integer(sec, "NumMFs", 1)
        extra = sorted(
            k
            for k in sec.keys
            if k.startswith("MF") and k[2:] not in {str(i) for i in range(1, n_mf + 1)}
        )
        if extra:
            self.fail(
                sec.keys[extra[0]][1], f"{extra[0]} beyond NumMFs={n_mf}", sec.keys[extra[0]][2]
            )
        terms = []
        for i in range(1, n_mf + 1):
            value, lineno, line = self.raw(sec, f"MF{i}")
            m = _MF_LINE.fullmatch(value)
            if m is None:
                self.fail(lineno, "expected MFn='name':'type',[params]", line)
            term_name, kind, params = m.group(1), m.group(2), self.numbers(m.group(3), lineno, line)
            if kind not in MF_KINDS:
                self.fail(
                    lineno,
                    f"unknown membership type {kind!r} (supported: {', '.join(MF_KINDS)})",
                    line,
                )
            if kind == "gaussmf" and len(params) == 2:
                params = [params[1], params[0]]  # MATLAB: [sigma mean]
            try:
                terms.append(Term(term_name, kind, tuple(params)))
            except ValueError as exc:
                self.fail(lineno, str(exc), line)
        try:
            return Variable(self.string(sec, "Name"), (rng[0], rng[1]), tuple(terms))
        except ValueError as exc:
            self.fail(sec.lineno, str(exc))

    def system(self) -> MamdaniSystem:
        sys_ = self.section("System")
        kind = self.string(sys_, "Type")
        if kind.lower() != "mamdani":
            self.fail(
                sys_.keys["Type"][1],
                f"only Mamdani systems are supported, not {kind!r}",
                sys_.keys["Type"][2],
            )
        for key, want in _METHODS.items():
            if self.string(sys_, key) != want:
                self.fail(sys_.keys[key][1], f"only {key}='{want}' is supported", sys_.keys[key][2])
        n_in = self.integer(sys_, "NumInputs", 1)
        if self.integer(sys_, "NumOutputs", 1) != 1:
            self.fail(
                sys_.keys["NumOutputs"][1],
                "only one output is supported",
                sys_.keys["NumOutputs"][2],
            )
        expected = {"System", "Output1", "Rules"} | {f"Input{i}" for i in range(1, n_in + 1)}
        for name, sec in self.sections.items():
            if name not in expected:
                self.fail(sec.lineno, f"section [{name}] beyond NumInputs={n_in}, NumOutputs=1")
        inputs = tuple(self.variable(f"Input{i}") for i in range(1, n_in + 1))
        output = self.variable("Output1")
        rules_sec = self.section("Rules")
        n_rules = self.integer(sys_, "NumRules", 1)
        if len(rules_sec.rules) != n_rules:
            self.fail(
                sys_.keys["NumRules"][1],
                f"NumRules={n_rules} but [Rules] has {len(rules_sec.rules)} lines",
                sys_.keys["NumRules"][2],
            )
        rules = [self.rule(lineno, line, inputs, output) for lineno, line in rules_sec.rules]
        return MamdaniSystem(inputs, output, tuple(rules), name=self.string(sys_, "Name"))

    def rule(self, lineno: int, line: str, inputs: tuple[Variable, ...], output: Variable) -> Rule:
        m = _RULE_LINE.fullmatch(line)
        if m is None:
            self.fail(lineno, "expected a rule 'i1 i2 ..., o (weight) : connective'", line)
        ant = [int(v) for v in m.group(1).split()]
        cons = [int(v) for v in m.group(2).split()]
        weight = self.numbers(m.group(3), lineno, line)
        if len(ant) != len(inputs) or len(cons) != 1 or len(weight) != 1:
            self.fail(lineno, f"expected {len(inputs)} antecedent(s), 1 consequent, 1 weight", line)
        if int(m.group(4)) != 1:
            self.fail(lineno, "only AND rules (connective 1) are supported", line)
        if not 0.0 <= weight[0] <= 1.0:
            self.fail(lineno, "rule weight must be in [0, 1]", line)
        for idx, var in zip(ant + cons, inputs + (output,), strict=True):
            if idx < 0:
                self.fail(lineno, "negated terms (NOT) are not supported", line)
            if idx > len(var.terms) or (idx == 0 and var is output):
                self.fail(
                    lineno,
                    f"term index {idx} out of range for {var.name!r} (1..{len(var.terms)})",
                    line,
                )
        return Rule(tuple(None if a == 0 else a - 1 for a in ant), cons[0] - 1, weight[0])


def read_fis(source: str | os.PathLike[str]) -> MamdaniSystem:
    """Read a MATLAB .fis file into a :class:`~pkmctl.fuzzy.MamdaniSystem`.

    Parameters
    ----------
    source : str or path-like
        A path, or the FIS text itself (a str containing a newline or starting with '[').

    Raises
    ------
    FISError
        ``file:line: message in: line`` for malformed or unsupported content.
    """
    if isinstance(source, str) and ("\n" in source or source.lstrip().startswith("[")):
        return _Reader(source, "<string>").system()
    path = Path(source)
    return _Reader(path.read_text(encoding="utf-8"), str(source)).system()


def _num(x: float) -> str:
    x = float(x)
    return str(int(x)) if x.is_integer() and abs(x) < 1e15 else repr(x)


def to_fis_text(system: MamdaniSystem) -> str:
    """The MATLAB .fis text of a system (floats written exactly, by their repr)."""
    for name in [system.name] + [v.name for v in (*system.inputs, system.output)]:
        if "'" in name or "\n" in name:
            raise ValueError(f"name {name!r} cannot be written to a .fis file")
    out = [
        "[System]",
        f"Name='{system.name}'",
        "Type='mamdani'",
        "Version=2.0",
        f"NumInputs={len(system.inputs)}",
        "NumOutputs=1",
        f"NumRules={len(system.rules)}",
        "AndMethod='min'",
        "OrMethod='max'",
        "ImpMethod='min'",
        "AggMethod='max'",
        "DefuzzMethod='centroid'",
    ]
    sections = [(f"Input{i + 1}", v) for i, v in enumerate(system.inputs)]
    for header, var in sections + [("Output1", system.output)]:
        out += ["", f"[{header}]", f"Name='{var.name}'"]
        out += [f"Range=[{_num(var.universe[0])} {_num(var.universe[1])}]"]
        out += [f"NumMFs={len(var.terms)}"]
        for i, t in enumerate(var.terms, start=1):
            params = (t.params[1], t.params[0]) if t.kind == "gaussmf" else t.params
            out.append(f"MF{i}='{t.name}':'{t.kind}',[{' '.join(_num(p) for p in params)}]")
    out += ["", "[Rules]"]
    for r in system.rules:
        ant = " ".join(str(0 if a is None else a + 1) for a in r.antecedent)
        out.append(f"{ant}, {r.consequent + 1} ({_num(r.weight)}) : 1")
    return "\n".join(out) + "\n"


def write_fis(system: MamdaniSystem, path: str | os.PathLike[str]) -> None:
    """Write a system as a MATLAB .fis file, atomically.

    The text goes to a temporary file in the same directory, which then replaces ``path``
    (``os.replace``), so readers never see a partly written file.
    """
    with atomic_write(path) as f:
        f.write(to_fis_text(system))
