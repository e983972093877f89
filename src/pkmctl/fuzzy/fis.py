"""Read and write MATLAB Fuzzy Logic Toolbox ``.fis`` files: Mamdani and Sugeno systems.

Supported: ``Type`` mamdani or sugeno; any number of inputs and outputs; AndMethod min
or prod, OrMethod max or probor; Mamdani: ImpMethod min or prod, AggMethod max, sum or
probor, DefuzzMethod centroid, bisector, mom, som or lom; Sugeno: ImpMethod prod,
AggMethod sum, DefuzzMethod wtaver or wtsum, output terms constant or linear; the
membership types of :data:`pkmctl.fuzzy.mf.MF_TYPES` (all thirteen of the toolbox);
AND (connective 1) and OR (2) rules, NOT (negative indices) in antecedents and Mamdani
consequents, don't care (0), weights in [0, 1]. Files in UTF-8 or Latin-1 are read.

Anything else raises :class:`FISError`, which lists *every* problem of the file, one per
line, as ``file:line: message in: line``; a binary file is refused in one line.

A file that fits the subset of :class:`~pkmctl.fuzzy.MamdaniSystem` (one output; min,
min, max, centroid; trimf/trapmf/gaussmf/zmf/smf; AND rules without NOT) is read as one,
which the paper's compiled kernels (``flc_eval``) take; any other (or every file with
``general=True``) as a :class:`~pkmctl.fuzzy.system.FuzzySystem`.

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

Rule lines are: one term index per input (1-based, 0 = don't care, negative = NOT), a
comma, one index per output, the weight in parentheses, a colon and the connective
(1 = AND, 2 = OR). Note that MATLAB's gaussmf parameters are [sigma mean]; pkmctl's
``Term`` keeps (mean, sigma).
"""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

from pkmctl.errors import PkmctlError
from pkmctl.fuzzy.engine import MF_KINDS, MamdaniSystem, Rule, Term, Variable
from pkmctl.fuzzy.mf import MF_TYPES
from pkmctl.fuzzy.system import FuzzyRule, FuzzySystem, SugenoTerm
from pkmctl.io.atomic import atomic_write

__all__ = ["FISError", "read_fis", "to_fis_text", "write_fis"]

_MAMDANI_METHODS = {
    "AndMethod": ("min", "prod"),
    "OrMethod": ("max", "probor"),
    "ImpMethod": ("min", "prod"),
    "AggMethod": ("max", "sum", "probor"),
    "DefuzzMethod": ("centroid", "bisector", "mom", "som", "lom"),
}
_SUGENO_METHODS = _MAMDANI_METHODS | {
    "ImpMethod": ("prod",),
    "AggMethod": ("sum",),
    "DefuzzMethod": ("wtaver", "wtsum"),
}
_FIELDS = {
    "AndMethod": "and_method",
    "OrMethod": "or_method",
    "ImpMethod": "imp_method",
    "AggMethod": "agg_method",
    "DefuzzMethod": "defuzz_method",
}
_MF_LINE = re.compile(r"'([^']*)'\s*:\s*'([^']*)'\s*,\s*\[([^\]]*)\]")
_RULE_LINE = re.compile(r"([-+\d\s]+),([-+\d\s]+)\(([^)]*)\)\s*:\s*([-+\d]+)")
_SECTION = re.compile(r"\[(System|Input\d+|Output\d+|Rules)\]")


# str.splitlines breaks at these too: escaped in messages, which stay one line each
_BREAKS = str.maketrans({c: repr(c)[1:-1] for c in "\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029"})
_BRACKETED = re.compile(r"([\[(])([^\[\]()]*)([\])])")
_MAX_VALUES = 10  # a longer list of numbers is shown as its first 4, last 2 and count
_MAX_CHARS = 300  # a longer message or echoed line is shown as its start, end and length


def _shorten(text: str, limit: int = _MAX_CHARS) -> str:
    """``text`` for a message: one line, bounded. Lists of more than ``_MAX_VALUES``
    numbers in brackets or parentheses keep their first and last values and the count
    (``[0 1 2 3 ... 9 10] (11 values)``), then a text still over ``limit`` characters its
    start and end (``start ...[N characters]... end``), so that a 200,000-parameter MF
    does not make a 1.4 MB message; line breaks are escaped (``\\u2028``)."""

    def short_list(m: re.Match) -> str:
        values = m.group(2).replace(",", " ").split()
        if len(values) <= _MAX_VALUES:
            return m.group(0)
        try:
            for v in values:
                float(v)
        except ValueError:
            return m.group(0)
        sep = ", " if "," in m.group(2) else " "
        shown = sep.join([*values[:4], "...", *values[-2:]])
        return f"{m.group(1)}{shown}{m.group(3)} ({len(values)} values)"

    text = _BRACKETED.sub(short_list, text).translate(_BREAKS)
    if len(text) > limit:
        text = f"{text[: limit - 80]} ...[{len(text)} characters]... {text[-40:]}"
    return text


class FISError(PkmctlError, ValueError):
    """A .fis file that is malformed or uses a feature pkmctl does not support.

    Attributes ``source`` (file name or ``"<string>"``), ``lineno`` (1-based; 0 when
    no line applies) and ``line`` (its text, as in the file) of the first problem, and
    ``problems``, the list of all ``(lineno, message, line)``; the message has one line
    per problem, long values and lines in it shortened (start, end and size).
    """

    def __init__(
        self, source: str, lineno: int, message: str, line: str = "", more: tuple = ()
    ) -> None:
        self.source, self.lineno, self.line = source, lineno, line
        self.problems = [(n, _shorten(m), t) for n, m, t in [(lineno, message, line), *more]]
        super().__init__(
            "\n".join(
                (f"{source}:{n}: " if n else f"{source}: ")
                + m
                + (f" in: {_shorten(t, 200)}" if t else "")
                for n, m, t in self.problems
            )
        )


class _Fatal(Exception):
    """Stops reading after a problem that leaves nothing sensible to check further."""


class _Section:
    def __init__(self, name: str, lineno: int) -> None:
        self.name, self.lineno = name, lineno
        self.keys: dict[str, tuple[str, int, str]] = {}  # key -> (value, lineno, line)
        self.rules: list[tuple[int, str]] = []


class _Reader:
    """Parses the whole file, collecting every problem (``self.problems``)."""

    def __init__(self, text: str, source: str) -> None:
        self.source = source
        self.problems: list[tuple[int, str, str]] = []
        self.sections: dict[str, _Section] = {}
        # line breaks are \n, \r\n and \r only: str.splitlines also breaks at U+0085 (a
        # Windows-1252 "…" read as Latin-1) and U+2028, inside a name or a comment
        lines = re.split(r"\r\n|\r|\n", text)
        if lines and not lines[-1]:
            lines.pop()
        self.nlines = max(1, len(lines))
        current: _Section | None = None
        skipping = False
        before = 0  # lines of text before the first section: one problem, not one a line
        for lineno, raw in enumerate(lines, start=1):
            line = raw.strip()
            if not line or line.startswith(("%", "#")):
                continue
            if line.startswith("["):
                m = _SECTION.fullmatch(line)
                if m is None and _SECTION.fullmatch(line.title()):
                    # [system]: say so, but read on, so that its other problems show too
                    self.note(lineno, f"section names are case-sensitive: {line.title()}", line)
                    m = _SECTION.fullmatch(line.title())
                skipping = m is None or m.group(1) in self.sections
                if m is None:
                    self.note(
                        lineno,
                        "unknown section (expected [System], [InputN], [OutputN] or [Rules])",
                        line,
                    )
                elif m.group(1) in self.sections:
                    self.note(lineno, f"duplicate section [{m.group(1)}]", line)
                else:
                    current = self.sections[m.group(1)] = _Section(m.group(1), lineno)
            elif skipping:
                continue
            elif current is None:
                if not before:
                    at = len(self.problems)
                    self.note(lineno, "text before the first section", line)
                before += 1
            elif current.name == "Rules":
                current.rules.append((lineno, line))
            else:
                key, sep, value = line.partition("=")
                if not sep or not key.strip():
                    self.note(lineno, "expected Key=Value", line)
                elif key.strip() in current.keys:
                    self.note(lineno, f"duplicate key {key.strip()!r}", line)
                else:
                    current.keys[key.strip()] = (value.strip(), lineno, line)
        if before > 1:
            n, _, text = self.problems[at]
            self.problems[at] = (n, f"{before} lines of text before the first section", text)

    def note(self, lineno: int, message: str, line: str = "") -> None:
        self.problems.append((lineno, message, line))

    def fatal(self, lineno: int, message: str, line: str = ""):
        self.note(lineno, message, line)
        raise _Fatal

    def section(self, name: str) -> _Section:
        if name not in self.sections:
            self.fatal(self.nlines, f"missing section [{name}]")
        return self.sections[name]

    def raw(self, sec: _Section, key: str) -> tuple[str, int, str]:
        if key not in sec.keys:
            self.fatal(sec.lineno, f"[{sec.name}] has no {key}")
        return sec.keys[key]

    def string(self, sec: _Section, key: str, name: bool = False) -> str | None:
        """The quoted value of ``key``; a ``name`` must not be empty or blank."""
        value, lineno, line = self.raw(sec, key)
        if len(value) < 2 or value[0] != "'" or value[-1] != "'":
            self.note(lineno, f"{key} must be a quoted string ('...')", line)
            return None
        if name and not value[1:-1].strip():
            self.note(lineno, f"{key} must be a non-empty quoted name ('...'), got {value}", line)
            return None
        return value[1:-1]

    def integer(self, sec: _Section, key: str, lo: int) -> int:
        value, lineno, line = self.raw(sec, key)
        try:
            n = int(value)
        except ValueError:
            n = lo - 1
        if n < lo:
            self.fatal(lineno, f"{key} must be an integer >= {lo}", line)
        return n

    def numbers(self, text: str, lineno: int, line: str) -> list[float] | None:
        try:
            return [float(v) for v in text.replace(",", " ").split()]
        except ValueError:
            self.note(lineno, f"not a list of numbers: [{text}]", line)
            return None

    def variable(self, name: str, sugeno_out: int = 0) -> Variable | None:
        """Input or output section ``name``; ``sugeno_out`` = number of inputs for a
        Sugeno output (its terms are constant or linear), else 0."""
        sec = self.section(name)
        value, lineno, line = self.raw(sec, "Range")
        rng = None
        if not (value.startswith("[") and value.endswith("]")):
            self.note(lineno, "Range must be [lo hi]", line)
        else:
            rng = self.numbers(value[1:-1], lineno, line)
            if rng is not None and (len(rng) != 2 or not rng[0] < rng[1]):
                self.note(lineno, "Range must be [lo hi] with lo < hi", line)
                rng = None
        n_mf = self.integer(sec, "NumMFs", 1)
        mf_keys = [k for k in sec.keys if k.startswith("MF")]
        for k in sorted(k for k in mf_keys if not _numbered(k, "MF", n_mf)):
            self.note(sec.keys[k][1], f"{k} beyond NumMFs={n_mf}", sec.keys[k][2])
        terms: list = []
        if n_mf > len(mf_keys):  # nothing proportional to NumMFs: it may be 99999999999
            _, lineno, line = sec.keys["NumMFs"]
            self.note(
                lineno,
                f"NumMFs={n_mf} but [{sec.name}] has {_count(len(mf_keys), 'MF line')}",
                line,
            )
            terms.append(None)
        else:
            for i in range(1, n_mf + 1):
                if f"MF{i}" not in sec.keys:
                    self.note(sec.lineno, f"[{sec.name}] has no MF{i}")
                    continue
                terms.append(self.term(f"MF{i}", *sec.keys[f"MF{i}"], sugeno_out))
        var_name = self.string(sec, "Name", name=True)
        if rng is None or var_name is None or any(t is None for t in terms):
            return None
        try:
            return Variable(var_name, (rng[0], rng[1]), tuple(terms))
        except ValueError as exc:
            self.note(sec.lineno, str(exc))
            return None

    def term(self, key: str, value: str, lineno: int, line: str, sugeno_out: int):
        m = _MF_LINE.fullmatch(value)
        if m is None:
            self.note(lineno, "expected MFn='name':'type',[params]", line)
            return None
        term_name, kind, params = m.group(1), m.group(2), self.numbers(m.group(3), lineno, line)
        if not term_name.strip():
            self.note(
                lineno, f"{key} has an empty term name '{term_name}' (a term needs a name)", line
            )
            return None
        if params is None:
            return None
        if sugeno_out:
            if kind not in ("constant", "linear"):
                self.note(lineno, f"Sugeno output terms are constant or linear, not {kind!r}", line)
                return None
            if kind == "linear" and len(params) != sugeno_out + 1:
                self.note(
                    lineno,
                    f"linear takes {sugeno_out + 1} parameters (one per input and a constant), "
                    f"got {len(params)}",
                    line,
                )
                return None
            try:
                return SugenoTerm(term_name, kind, tuple(params))
            except ValueError as exc:
                self.note(lineno, str(exc), line)
                return None
        if kind not in MF_TYPES:
            self.note(
                lineno, f"unknown membership type {kind!r} (supported: {', '.join(MF_TYPES)})", line
            )
            return None
        if kind == "gaussmf" and len(params) == 2:
            params = [params[1], params[0]]  # MATLAB: [sigma mean]
        try:
            return Term(term_name, kind, tuple(params))
        except ValueError as exc:
            self.note(lineno, str(exc), line)
            return None

    def system(self, general: bool) -> MamdaniSystem | FuzzySystem | None:
        sys_ = self.section("System")
        kind = (self.string(sys_, "Type") or "").lower()
        if kind not in ("mamdani", "sugeno"):
            value, lineno, line = sys_.keys["Type"]
            self.note(lineno, f"Type must be 'mamdani' or 'sugeno', not {value}", line)
        allowed = _SUGENO_METHODS if kind == "sugeno" else _MAMDANI_METHODS
        methods = {}
        for key, choices in allowed.items():
            method = self.string(sys_, key)
            if method is not None and method not in choices:
                _, lineno, line = sys_.keys[key]
                self.note(
                    lineno,
                    f"{key}={method!r} is not supported for {kind or 'this'} systems "
                    f"(supported: {', '.join(choices)})",
                    line,
                )
            methods[_FIELDS[key]] = method
        n_in = self.integer(sys_, "NumInputs", 1)
        n_out = self.integer(sys_, "NumOutputs", 1)
        for name, sec in self.sections.items():
            if name not in ("System", "Rules") and not (
                _numbered(name, "Input", n_in) or _numbered(name, "Output", n_out)
            ):
                self.note(
                    sec.lineno, f"section [{name}] beyond NumInputs={n_in}, NumOutputs={n_out}"
                )
        for key, base, n in (("NumInputs", "Input", n_in), ("NumOutputs", "Output", n_out)):
            have = sum(1 for name in self.sections if name.startswith(base))
            if n > have:  # nothing proportional to n: it may be 99999999999
                first = next(i for i in range(1, have + 2) if f"{base}{i}" not in self.sections)
                _, lineno, line = sys_.keys[key]
                self.fatal(
                    lineno,
                    f"{key}={n} but the file has {_count(have, f'[{base}N] section')}, "
                    f"first missing section [{base}{first}]",
                    line,
                )
        inputs = [self.variable(f"Input{i}") for i in range(1, n_in + 1)]
        outputs = [
            self.variable(f"Output{i}", n_in if kind == "sugeno" else 0)
            for i in range(1, n_out + 1)
        ]
        rules_sec = self.section("Rules")
        n_rules = self.integer(sys_, "NumRules", 0)
        if len(rules_sec.rules) != n_rules:
            _, lineno, line = sys_.keys["NumRules"]
            self.note(
                lineno, f"NumRules={n_rules} but [Rules] has {len(rules_sec.rules)} lines", line
            )
        self._arity: list[int] = []  # rules with the wrong number of fields: said once
        rules = [self.rule(n, t, inputs, outputs, kind) for n, t in rules_sec.rules]
        if len(self._arity) > 1:  # (a wrong NumInputs gave one line a rule)
            at = next(i for i, p in enumerate(self.problems) if p[0] == self._arity[0])
            n, message, text = self.problems[at]
            more = len(self._arity) - 1
            self.problems[at] = (n, f"{message}; the same in {_count(more, 'more rule')} "
                                 f"(lines {self._arity[1]}-{self._arity[-1]})", text)  # fmt: skip
        name = self.string(sys_, "Name")
        if self.problems:
            return None
        if not general and _mamdani_subset(kind, methods, inputs, outputs, rules):
            try:
                return MamdaniSystem(
                    tuple(inputs),
                    outputs[0],
                    tuple(
                        Rule(tuple(None if a == 0 else a - 1 for a in r.antecedent),
                             r.consequent[0] - 1, r.weight)
                        for r in rules
                    ),
                    name=name,
                )  # fmt: skip
            except ValueError as exc:  # e.g. NumRules=0: named with the file, as the rest
                self.note(rules_sec.lineno, str(exc))
                return None
        try:
            return FuzzySystem(
                tuple(inputs), tuple(outputs), tuple(rules), kind=kind, name=name, **methods
            )
        except ValueError as exc:
            self.note(sys_.lineno, str(exc))
            return None

    def rule(self, lineno, line, inputs, outputs, kind) -> FuzzyRule | None:
        m = _RULE_LINE.fullmatch(line)
        if m is None:
            self.note(lineno, "expected a rule 'i1 i2 ..., o1 ... (weight) : connective'", line)
            return None
        try:
            ant = [int(v) for v in m.group(1).split()]
            cons = [int(v) for v in m.group(2).split()]
            connective = int(m.group(4))
        except ValueError:  # '-' or '+-1': the pattern admits signs, int() does not
            self.note(lineno, "term indices and the connective must be integers", line)
            return None
        weight = self.numbers(m.group(3), lineno, line) or []
        if len(ant) != len(inputs) or len(cons) != len(outputs) or len(weight) != 1:
            if not self._arity:
                self.note(
                    lineno,
                    f"expected {len(inputs)} antecedent(s), {len(outputs)} consequent(s), 1 weight",
                    line,
                )
            self._arity.append(lineno)
            return None
        ok = True
        if connective not in (1, 2):
            self.note(lineno, f"connective must be 1 (AND) or 2 (OR), got {connective}", line)
            ok = False
        if not 0.0 <= weight[0] <= 1.0:
            self.note(lineno, "rule weight must be in [0, 1]", line)
            ok = False
        for idx, var, is_out in zip(
            ant + cons, inputs + outputs, [False] * len(ant) + [True] * len(cons), strict=True
        ):
            if var is not None and abs(idx) > len(var.terms):
                self.note(
                    lineno,
                    f"term index {idx} out of range for {var.name!r} (1..{len(var.terms)})",
                    line,
                )
                ok = False
            if is_out and idx < 0 and kind == "sugeno":
                self.note(lineno, "a Sugeno consequent cannot be negated (NOT)", line)
                ok = False
        if not ok:
            return None
        return FuzzyRule(tuple(ant), tuple(cons), weight[0], "and" if connective == 1 else "or")


def _numbered(name: str, prefix: str, n: int) -> bool:
    """Whether ``name`` is ``prefix`` and one of 1..n written as str(i) does (``MF7``),
    without converting its digits (there may be thousands) or building the n names."""
    digits, top = name[len(prefix) :], str(n)
    return (
        name.startswith(prefix)
        and digits.isascii()
        and digits.isdigit()
        and digits[0] != "0"
        and (len(digits), digits) <= (len(top), top)
    )


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _mamdani_subset(kind, methods, inputs, outputs, rules) -> bool:
    """Whether a parsed file is a :class:`MamdaniSystem` (see the module docstring)."""
    return (
        kind == "mamdani"
        and len(outputs) == 1
        and (methods["and_method"], methods["imp_method"], methods["agg_method"],
             methods["defuzz_method"]) == ("min", "min", "max", "centroid")
        and all(t.kind in MF_KINDS and len(t.params) == MF_KINDS[t.kind][1]
                for v in inputs + outputs for t in v.terms)
        and all(r.connective == "and" and min(r.antecedent) >= 0 and r.consequent[0] > 0
                for r in rules)
    )  # fmt: skip


def _decode(data: bytes, source: str) -> str:
    """The text of a file: UTF-8 (with or without BOM), else Latin-1; binary refused."""
    controls = sum(1 for b in data[:4096] if b < 32 and b not in (9, 10, 12, 13))
    if b"\0" in data or controls > 0.01 * max(1, len(data[:4096])):
        raise FISError(source, 0, "binary file, not a .fis text file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def read_fis(
    source: str | os.PathLike[str], *, general: bool = False, **options
) -> MamdaniSystem | FuzzySystem:
    """Read a MATLAB .fis file.

    Parameters
    ----------
    source : str or path-like
        A path, or the FIS text itself (a str containing a newline or starting with '[').
    general : bool
        Always return a :class:`~pkmctl.fuzzy.system.FuzzySystem` (else a
        :class:`~pkmctl.fuzzy.MamdaniSystem` when the file fits its subset).
    **options
        ``input_range`` ("clip" or "raw"), ``samples`` (None or an int): the
        :class:`~pkmctl.fuzzy.system.FuzzySystem` fields; giving any implies general.

    Raises
    ------
    FISError
        ``file:line: message in: line``, one line per problem, for malformed or
        unsupported content; ``file: binary file...`` for a binary file.
    """
    unknown = set(options) - {"input_range", "samples"}
    if unknown:
        raise TypeError(f"read_fis got unknown options {sorted(unknown)}")
    if isinstance(source, str) and ("\n" in source or source.lstrip("\ufeff \t\r").startswith("[")):
        text, name = source.removeprefix("\ufeff"), "<string>"  # a BOM, as in a file
    else:
        name = str(source)
        try:
            data = Path(source).read_bytes()
        except OSError as exc:  # missing, a folder, unreadable: one line with the name
            raise FISError(name, 0, exc.strerror or str(exc)) from None
        text = _decode(data, name)
    reader = _Reader(text, name)
    system = None
    with contextlib.suppress(_Fatal):
        system = reader.system(general or bool(options))
    if reader.problems or system is None:
        # in the order found: a cause comes before what follows from it
        first, *more = reader.problems or [(0, "unreadable", "")]
        raise FISError(name, *first, more=tuple(more))
    if options:
        system = system.replace(**options)
    return system


def _num(x: float) -> str:
    x = float(x)
    return str(int(x)) if x.is_integer() and abs(x) < 1e15 else repr(x)


def to_fis_text(system: MamdaniSystem | FuzzySystem) -> str:
    """The MATLAB .fis text of a system (floats written exactly, by their repr)."""
    g = system if isinstance(system, FuzzySystem) else FuzzySystem.from_mamdani(system)
    names = [g.name] + [v.name for v in (*g.inputs, *g.outputs)]
    names += [t.name for v in (*g.inputs, *g.outputs) for t in v.terms]
    for i, name in enumerate(names):  # read_fis could not read them back
        if "'" in name or any(c in name for c in "\n\r\x85\u2028\u2029"):
            raise ValueError(
                f"name {name!r} cannot be written to a .fis file (no quote or line break)"
            )
        if i and not name.strip():  # (a system's name may be empty; a tester)
            raise ValueError(
                f"name {name!r}: a variable or term with no name cannot be written to a "
                ".fis file (read_fis refuses it)"
            )
    out = [
        "[System]",
        f"Name='{g.name}'",
        f"Type='{g.kind}'",
        "Version=2.0",
        f"NumInputs={len(g.inputs)}",
        f"NumOutputs={len(g.outputs)}",
        f"NumRules={len(g.rules)}",
        f"AndMethod='{g.and_method}'",
        f"OrMethod='{g.or_method}'",
        f"ImpMethod='{g.imp_method}'",
        f"AggMethod='{g.agg_method}'",
        f"DefuzzMethod='{g.defuzz_method}'",
    ]
    sections = [(f"Input{i + 1}", v) for i, v in enumerate(g.inputs)]
    sections += [(f"Output{i + 1}", v) for i, v in enumerate(g.outputs)]
    for header, var in sections:
        out += ["", f"[{header}]", f"Name='{var.name}'"]
        out += [f"Range=[{_num(var.universe[0])} {_num(var.universe[1])}]"]
        out += [f"NumMFs={len(var.terms)}"]
        for i, t in enumerate(var.terms, start=1):
            params = (t.params[1], t.params[0]) if t.kind == "gaussmf" else t.params
            out.append(f"MF{i}='{t.name}':'{t.kind}',[{' '.join(_num(p) for p in params)}]")
    out += ["", "[Rules]"]
    for r in g.rules:
        ant = " ".join(str(a) for a in r.antecedent)
        cons = " ".join(str(c) for c in r.consequent)
        out.append(f"{ant}, {cons} ({_num(r.weight)}) : {1 if r.connective == 'and' else 2}")
    return "\n".join(out) + "\n"


def write_fis(system: MamdaniSystem | FuzzySystem, path: str | os.PathLike[str]) -> None:
    """Write a system as a MATLAB .fis file, atomically.

    The text goes to a temporary file in the same directory, which then replaces ``path``
    (``os.replace``), so readers never see a partly written file.
    """
    with atomic_write(path) as f:
        f.write(to_fis_text(system))
