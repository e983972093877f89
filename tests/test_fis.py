"""Tests of pkmctl.fuzzy.fis: MATLAB .fis read/write, round trips and error reporting."""

import os
from importlib import resources

import numpy as np
import pytest

from pkmctl import fuzzy as fz
from pkmctl.fuzzy import fis


@pytest.fixture(scope="module")
def flc():
    return fz.FLC()


def random_inputs(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.5, 1.5, n), rng.uniform(-15, 15, n)


def test_round_trip_through_text_gives_identical_system(flc):
    text = fis.to_fis_text(flc)
    back = fis.read_fis(text)
    assert back == flc  # same variables, terms, parameters (bit for bit) and rules
    s, sdot = random_inputs()
    np.testing.assert_allclose(back(s, sdot), flc(s, sdot), rtol=0, atol=1e-12)
    assert fis.to_fis_text(back) == text


def test_shipped_file_is_the_paper_flc(flc):
    path = resources.files("pkmctl") / "fuzzy" / "data" / "paper_flc.fis"
    shipped = fis.read_fis(str(path))
    s, sdot = random_inputs(seed=1)
    np.testing.assert_allclose(shipped(s, sdot), flc(s, sdot), rtol=0, atol=1e-12)
    assert shipped.compiled().ints[4] == 1  # runs on the fast kernel too
    # regenerate with write_fis(FLC(), ...) if FLC() changes
    assert path.read_text(encoding="utf-8") == fis.to_fis_text(flc)
    assert fis.read_fis(str(path)) == shipped  # a str path as well as a Path


def test_matlab_layout(flc):
    lines = fis.to_fis_text(flc).splitlines()
    assert lines[:12] == [
        "[System]", "Name='paper_flc'", "Type='mamdani'", "Version=2.0", "NumInputs=2",
        "NumOutputs=1", "NumRules=49", "AndMethod='min'", "OrMethod='max'", "ImpMethod='min'",
        "AggMethod='max'", "DefuzzMethod='centroid'",
    ]  # fmt: skip
    assert "MF1='NB':'zmf',[-1 -0.6666666666666666]" in lines
    assert "MF7='PB':'smf',[6.666666666666667 10]" in lines
    assert lines[lines.index("[Rules]") + 1] == "1 1, 7 (1) : 1"  # s=NB, ṡ=NB -> PB
    assert lines[-1] == "7 7, 1 (1) : 1"


GENERAL = """\
[System]
Name='mixed'
Type='mamdani'
Version=2.0
NumInputs=3
NumOutputs=1
NumRules=4
AndMethod='min'
OrMethod='probor'
ImpMethod='min'
AggMethod='max'
DefuzzMethod='centroid'

[Input1]
Name='a'
Range=[0 10]
NumMFs=2
MF1='low':'gaussmf',[2.5 0]
MF2='high':'trapmf',[3 6 10 12]

[Input2]
Name='b'
Range=[-1 1]
NumMFs=2
MF1='neg':'zmf',[-1 0.5]
MF2='pos':'smf',[-0.5 1]

[Input3]
Name='c'
Range=[0 1]
NumMFs=1
MF1='any':'trimf',[0 0.5 1]

[Output1]
Name='y'
Range=[0 30]
NumMFs=3
MF1='small':'trimf',[0 5 10]
MF2='medium':'gaussmf',[3 15]
MF3='large':'trapmf',[20 25 30 30]

[Rules]
1 1 0, 1 (1) : 1
2 0 1, 3 (0.5) : 1
0 2 0, 2 (0.75) : 1
2 2 1, 3 (1) : 1
"""


def test_read_general_file_gaussians_dont_care_and_weights(tmp_path):
    system = fis.read_fis(GENERAL)
    a, b, c = system.inputs
    assert a.terms[0] == fz.Term("low", "gaussmf", (0.0, 2.5))  # MATLAB order [sigma mean]
    assert system.rules[1] == fz.Rule((1, None, 0), 2, 0.5)
    assert system.compiled().ints[4] == 0  # general kernel
    x = (np.array([1.0, 7.0, 9.0]), np.array([-0.5, 0.2, 0.9]), np.array([0.5, 0.5, 0.1]))
    y = np.linspace(0, 30, 300001)
    for n in range(3):
        levels = system.clip_levels(*(v[n] for v in x))
        mu_a = [t(x[0][n]) for t in a.terms]
        mu_b = [t(x[1][n]) for t in b.terms]
        mu_c = c.terms[0](x[2][n])
        expect = [
            min(mu_a[0], mu_b[0]),
            max(0.75 * mu_b[1], 0.5 * min(mu_a[1], mu_c), min(mu_a[1], mu_b[1], mu_c)),
        ]
        assert levels[0] == pytest.approx(expect[0], abs=1e-15)
        agg = np.max(
            [np.minimum(h, t(y)) for h, t in zip(levels, system.output.terms, strict=True)], axis=0
        )
        ref = np.trapezoid(y * agg, y) / np.trapezoid(agg, y)
        assert system(*(v[n] for v in x)) == pytest.approx(ref, abs=1e-6)
    # round trip through a file
    path = tmp_path / "mixed.fis"
    fis.write_fis(system, path)
    back = fis.read_fis(path)
    assert back == system
    assert back(*x).tolist() == system(*x).tolist()


def _replace(text, old, new):
    assert old in text
    return text.replace(old, new, 1)


def _lineno(text, needle):
    return next(n for n, line in enumerate(text.splitlines(), 1) if needle in line)


MALFORMED = [
    ("MF2='high':'trapmf',[3 6 10 12]", "MF2='high':'custommf',[3 6 10 12]",
     "unknown membership type 'custommf' (supported: trimf, trapmf, gaussmf, zmf, smf, gauss2mf"),
    ("Type='mamdani'", "Type='tsk'", "Type must be 'mamdani' or 'sugeno'"),
    ("DefuzzMethod='centroid'", "DefuzzMethod='wtaver'", "DefuzzMethod='wtaver' is not supported"),
    ("AndMethod='min'", "AndMethod='mymin'", "AndMethod='mymin' is not supported"),
    ("2 2 1, 3 (1) : 1", "2 2 1, 3 (1) : 3", "connective must be 1 (AND) or 2 (OR)"),
    ("2 2 1, 3 (1) : 1", "2 3 1, 3 (1) : 1", "term index 3 out of range for 'b'"),
    ("2 2 1, 3 (1) : 1", "2 2, 3 (1) : 1", "expected 3 antecedent(s)"),
    ("2 2 1, 3 (1) : 1", "2 2 1 3 1 1", "expected a rule"),
    ("2 2 1, 3 (1) : 1", "2 2 1, 3 (1.5) : 1", "rule weight must be in [0, 1]"),
    ("MF1='neg':'zmf',[-1 0.5]", "MF1='neg':'zmf',[0.5 -1]", "non-decreasing"),
    ("MF1='neg':'zmf',[-1 0.5]", "MF1='neg':'zmf',[-1 x]", "not a list of numbers"),
    ("MF1='neg':'zmf',[-1 0.5]", "MF1='neg':'zmf',[-1 0.5 2]", "zmf takes 2 parameters"),
    ("MF1='neg':'zmf',[-1 0.5]", "MF1=neg:zmf,[-1 0.5]", "expected MFn='name':'type',[params]"),
    ("Range=[-1 1]", "Range=[1 -1]", "lo < hi"),
    ("NumMFs=2\nMF1='neg'", "NumMFs=1\nMF1='neg'", "MF2 beyond NumMFs=1"),
    ("[Input3]", "[Input 3]", "unknown section"),
    ("Name='c'", "Name 'c'", "expected Key=Value"),
    # signs the rule pattern admits but int() does not (was a bare ValueError, no line)
    ("2 2 1, 3 (1) : 1", "- 2 1, 3 (1) : 1", "term indices and the connective must be integers"),
    ("2 2 1, 3 (1) : 1", "+-2 2 1, 3 (1) : 1", "term indices and the connective must be int"),
    ("2 2 1, 3 (1) : 1", "2 2 1, 3 (1) : -", "term indices and the connective must be integers"),
]  # fmt: skip


@pytest.mark.parametrize(("old", "new", "message"), MALFORMED)
def test_malformed_files_name_the_line(tmp_path, old, new, message):
    text = _replace(GENERAL, old, new)
    path = tmp_path / "bad.fis"
    path.write_text(text, encoding="utf-8")
    lineno = _lineno(text, new.splitlines()[-1] if "\n" in new else new)
    if "beyond NumMFs" in message:
        lineno = _lineno(text, "MF2='pos'")
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(path)
    err = info.value
    assert str(err).startswith(f"{path}:{lineno}: "), str(err)
    assert message in str(err)
    assert err.lineno == lineno and err.line == text.splitlines()[lineno - 1].strip()
    assert isinstance(err, ValueError)


def test_structural_errors_name_a_line():
    cases = [
        (_replace(GENERAL, "NumRules=4", "NumRules=5"), "NumRules=5 but [Rules] has 4 lines", 7),
        (GENERAL.split("[Rules]")[0], "missing section [Rules]", None),
        (_replace(GENERAL, "NumInputs=3", "NumInputs=2"), "beyond NumInputs=2", None),
        (_replace(GENERAL, "Range=[0 1]\n", ""), "[Input3] has no Range", None),
        ("Name='x'\n[System]\n", "text before the first section", 1),
        (_replace(GENERAL, "NumOutputs=1", "NumOutputs=2"), "missing section [Output2]", None),
        (GENERAL + "[Rules]\n", "duplicate section [Rules]", None),
    ]
    for text, message, lineno in cases:
        with pytest.raises(fis.FISError, match=r"^<string>:\d+: ") as info:
            fis.read_fis(text)
        assert message in str(info.value)
        if lineno is not None:
            assert info.value.lineno == lineno, str(info.value)


def test_a_cause_repeated_on_many_lines_is_one_problem():
    """A wrong NumInputs gave one problem a rule (26 lines), and text before [System] one
    a line (12 lines, then "missing section [System]"): each cause is said once, with
    how many lines it covers."""
    wrong = _replace(GENERAL, "NumInputs=3", "NumInputs=2")
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(wrong)
    rules = wrong.split("[Rules]")[1].strip().splitlines()
    first = _lineno(wrong, rules[0])
    arity = [p for p in info.value.problems if "antecedent(s)" in p[1]]
    last = first + len(rules) - 1
    said = (
        f"expected 2 antecedent(s), 1 consequent(s), 1 weight; the same in {len(rules) - 1} more "
        f"rules (lines {first + 1}-{last})"
    )
    assert arity == [(first, said, rules[0])]
    headless = GENERAL.replace("[System]\n", "", 1)
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(headless)
    n_before = GENERAL.split("[System]")[1].split("[")[0].strip().count("\n") + 1
    problems = info.value.problems
    assert problems[0][:2] == (1, f"{n_before} lines of text before the first section")
    assert [m for _, m, _ in problems[1:]] == ["missing section [System]"], problems


def test_write_is_atomic(tmp_path, monkeypatch, flc):
    path = tmp_path / "flc.fis"
    path.write_text("old contents\n")
    seen = []
    real_replace = os.replace

    def spy(src, dst):
        seen.append((os.path.dirname(src), os.path.basename(src)))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", spy)
    fis.write_fis(flc, path)
    assert seen and seen[0][0] == str(tmp_path)  # temporary file in the same directory
    assert path.read_text() == fis.to_fis_text(flc)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flc.fis"]

    def failing(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing)
    system = fis.read_fis(GENERAL)
    with pytest.raises(OSError, match="disk full"):
        fis.write_fis(system, path)
    assert path.read_text() == fis.to_fis_text(flc)  # untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flc.fis"]  # no temporary left


def test_write_fis_and_unwritable_names(tmp_path, flc):
    fis.write_fis(flc, tmp_path / "x.fis")
    assert fis.read_fis(tmp_path / "x.fis") == flc
    x = fz.Variable("it's", (0.0, 1.0), (fz.Term("a", "trimf", (0, 0.5, 1)),))
    with pytest.raises(ValueError, match="cannot be written"):
        fis.to_fis_text(fz.MamdaniSystem((x,), x, [fz.Rule((0,), 0)]))
    # a term's name too: it was written, and the file could not be read back
    for bad in ("it's low", "two\nlines", "", " "):  # (an empty one too; a tester)
        y = fz.Variable("y", (0.0, 1.0), (fz.Term(bad, "trimf", (0, 0.5, 1)),))
        with pytest.raises(ValueError, match="cannot be written"):
            fis.to_fis_text(fz.MamdaniSystem((y,), y, [fz.Rule((0,), 0)]))
    for bad in ("", " "):  # an input or output with no name
        z = fz.Variable(bad, (0.0, 1.0), (fz.Term("a", "trimf", (0, 0.5, 1)),))
        y = fz.Variable("y", (0.0, 1.0), (fz.Term("a", "trimf", (0, 0.5, 1)),))
        for system in (fz.MamdaniSystem((z,), y, [fz.Rule((0,), 0)]),
                       fz.MamdaniSystem((y,), z, [fz.Rule((0,), 0)])):  # fmt: skip
            with pytest.raises(ValueError, match="no name cannot be written"):
                fis.write_fis(system, tmp_path / "nameless.fis")
    assert not (tmp_path / "nameless.fis").exists()


def test_odd_text_reads_with_its_line_numbers(tmp_path):
    """U+0085 (a Windows-1252 "…" read as Latin-1) and U+2028 are not line breaks in a
    .fis (str.splitlines broke lines there: bogus errors, shifted line numbers); a BOM
    before text given as a string is skipped, as in a file; a subset file with no rules
    is one FISError naming the file, not a bare ValueError."""
    cp1252 = _replace(GENERAL, "Name='mixed'", "Name='mixed\u2026'").replace(
        "[Input1]", "% tuned\u2026 by hand\n[Input1]"
    )
    path = tmp_path / "cp.fis"
    path.write_bytes(cp1252.encode("cp1252"))
    assert fis.read_fis(path).name == "mixed\x85"
    bad = _replace(cp1252, "MF2='high':'trapmf',[3 6 10 12]", "MF2='high':'foomf',[3 6 10 12]")
    path.write_bytes(bad.encode("cp1252"))
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(path)
    assert info.value.lineno == _lineno(bad, "foomf") and len(info.value.problems) == 1
    assert fis.read_fis("\ufeff" + GENERAL) == fis.read_fis(GENERAL)
    text = fis.to_fis_text(fz.FLC())
    head, _ = text.split("[Rules]")
    import re

    empty = re.sub(r"NumRules=\d+", "NumRules=0", head) + "[Rules]\n"
    with pytest.raises(fis.FISError, match=r"^<string>:\d+: a Mamdani system needs at least one"):
        fis.read_fis(empty)


HUGE = "99999999999"
HUGE_COUNTS = [
    ("NumMFs=2\nMF1='neg'", f"NumMFs={HUGE}\nMF1='neg'",
     f"NumMFs={HUGE} but [Input2] has 2 MF lines"),
    ("NumMFs=1\nMF1='any'", f"NumMFs={HUGE}\nMF1='any'",
     f"NumMFs={HUGE} but [Input3] has 1 MF line"),
    ("NumMFs=3\nMF1='small'", f"NumMFs={HUGE}\nMF1='small'",
     f"NumMFs={HUGE} but [Output1] has 3 MF lines"),
    ("NumInputs=3", f"NumInputs={HUGE}",
     f"NumInputs={HUGE} but the file has 3 [InputN] sections, first missing section [Input4]"),
    ("NumOutputs=1", f"NumOutputs={HUGE}",
     f"NumOutputs={HUGE} but the file has 1 [OutputN] section, first missing section [Output2]"),
    ("NumRules=4", f"NumRules={HUGE}", f"NumRules={HUGE} but [Rules] has 4 lines"),
    # a small excess too: one line at NumMFs, not one per missing MF
    ("NumMFs=2\nMF1='neg'", "NumMFs=3\nMF1='neg'", "NumMFs=3 but [Input2] has 2 MF lines"),
]  # fmt: skip


@pytest.mark.parametrize(("old", "new", "message"), HUGE_COUNTS)
def test_huge_declared_counts_are_one_line_and_quick(tmp_path, old, new, message):
    """NumMFs, NumInputs, NumOutputs or NumRules = 99999999999: the count was turned into
    a set and a loop of that many names (memory exhausted); now one problem, at once,
    with the value and what the file has."""
    import time

    text = _replace(GENERAL, old, new)
    path = tmp_path / "huge.fis"
    path.write_text(text, encoding="utf-8")
    key_line = new.splitlines()[0]
    lineno = _lineno(text, key_line)
    start = time.perf_counter()
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(path)
    assert time.perf_counter() - start < 1.0
    assert str(info.value) == f"{path}:{lineno}: {message} in: {key_line}"
    assert len(info.value.problems) == 1


def test_section_and_mf_numbers_must_be_written_exactly():
    """[Input03], [Input0], MF01 and a 5000-digit MF number are not among 1..n (as when
    the n names were listed)."""
    digits = "9" * 5000
    cases = [
        (_replace(GENERAL, "[Input3]", "[Input03]"), "section [Input03] beyond NumInputs=3"),
        (GENERAL + "[Input0]\n", "section [Input0] beyond NumInputs=3"),
        (_replace(GENERAL, "MF2='pos'", "MF02='pos'"), "MF02 beyond NumMFs=2"),
        (_replace(GENERAL, "MF2='pos'", f"MF{digits}='pos'"), f"MF{digits[:100]}"),
    ]
    for text, message in cases:
        with pytest.raises(fis.FISError) as info:
            fis.read_fis(text)
        assert message in str(info.value)


def test_long_values_are_shortened_in_messages():
    """A trimf with 200,000 parameters was one 3 MB message line (the parameters twice:
    in the message and in the echoed line); every message stays one short line."""
    params = " ".join(str(i) for i in range(200_000))
    text = _replace(GENERAL, "MF1='any':'trimf',[0 0.5 1]", f"MF1='any':'trimf',[{params}]")
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(text)
    msg = str(info.value)
    lineno = _lineno(text, "MF1='any'")
    assert msg == (
        f"<string>:{lineno}: trimf takes 3 or 4 parameters, got 200000: "
        "(0.0, 1.0, 2.0, 3.0, ..., 199998.0, 199999.0) (200000 values) "
        "in: MF1='any':'trimf',[0 1 2 3 ... 199998 199999] (200000 values)"
    )
    assert info.value.line == f"MF1='any':'trimf',[{params}]"  # the attribute: as in the file
    # not numbers, or not a list: start and end of the text, and its length
    long_type = "x" * 100_000
    for bad in (f"MF1='any':'trimf',[{params} x]", f"MF1='any':'{long_type}',[0 0.5 1]"):
        with pytest.raises(fis.FISError) as info:
            fis.read_fis(_replace(GENERAL, "MF1='any':'trimf',[0 0.5 1]", bad))
        msg = str(info.value)
        assert "\n" not in msg and len(msg) < 700, len(msg)
        assert "characters]..." in msg
    # every message, from any check: a long Type, a long method, a long rule weight
    for old, new in [
        ("Type='mamdani'", f"Type='{long_type}'"),
        ("AndMethod='min'", f"AndMethod='{long_type}'"),
        ("2 2 1, 3 (1) : 1", f"2 2 1, 3 ({params}) : 1"),
    ]:
        with pytest.raises(fis.FISError) as info:
            fis.read_fis(_replace(GENERAL, old, new))
        assert all(len(line) < 700 for line in str(info.value).splitlines())
    # line breaks other than \n and \r (kept inside a line by the reader) are escaped
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(_replace(GENERAL, "Type='mamdani'", "Type='mam\u2028dani'"))
    assert str(info.value).splitlines() == [
        "<string>:3: Type must be 'mamdani' or 'sugeno', not 'mam\\u2028dani' "
        "in: Type='mam\\u2028dani'"
    ]


EMPTY_NAMES = [
    ("MF1='any':'trimf',[0 0.5 1]", "MF1='':'trimf',[0 0.5 1]",
     "MF1 has an empty term name '' (a term needs a name)"),
    ("MF3='large':'trapmf',[20 25 30 30]", "MF3=' ':'trapmf',[20 25 30 30]",
     "MF3 has an empty term name ' ' (a term needs a name)"),
    ("Name='b'", "Name=''", "Name must be a non-empty quoted name ('...'), got ''"),
    ("Name='y'", "Name='  '", "Name must be a non-empty quoted name ('...'), got '  '"),
]  # fmt: skip


@pytest.mark.parametrize(("old", "new", "message"), EMPTY_NAMES)
def test_empty_term_and_variable_names_are_refused(old, new, message):
    text = _replace(GENERAL, old, new)
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(text)
    assert str(info.value) == f"<string>:{_lineno(text, new)}: {message} in: {new}"


def test_degenerate_linear_ramps_are_matlabs():
    """MATLAB's linzmf [a a] is 1 below a and 0 from a on, linsmf [a a] 0 below a and 1
    from a on; linzmf gave 1 at x = a (a tester: an output of 3.386 where MATLAB's is 8)."""
    from pkmctl.fuzzy.mf import MF_TYPES, mf_value

    z, s = MF_TYPES["linzmf"][0], MF_TYPES["linsmf"][0]
    x = (4.999, 5.0, 5.001)
    assert [mf_value(z, 5.0, 5.0, 0.0, 0.0, v) for v in x] == [1.0, 0.0, 0.0]
    assert [mf_value(s, 5.0, 5.0, 0.0, 0.0, v) for v in x] == [0.0, 1.0, 1.0]
    # a proper ramp is unchanged: ends and middle
    assert [mf_value(z, 4.0, 6.0, 0.0, 0.0, v) for v in (4.0, 5.0, 6.0)] == [1.0, 0.5, 0.0]
