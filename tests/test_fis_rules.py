"""The .fis reader on rules at their bounds (NOT of term 1, consequent 0, NumRules, NOT of
a term that does not exist, a negated Sugeno consequent) and on its messages' details
(the binary-file threshold, lines before the first section, long lists shortened)."""

import numpy as np
import pytest

from pkmctl import fuzzy as fz
from pkmctl.fuzzy import fis
from pkmctl.fuzzy.system import FuzzySystem


@pytest.fixture(scope="module")
def flc_text():
    return fis.to_fis_text(fz.FLC())


def _with_rule(text: str, k: int, rule: str) -> tuple[str, int]:
    """``text`` with its k-th rule line (0-based) replaced by ``rule``, and its line number."""
    lines = text.splitlines()
    i = lines.index("[Rules]") + 1 + k
    lines[i] = rule
    return "\n".join(lines) + "\n", i + 1


def _without_rule(text: str, k: int) -> str:
    lines = text.splitlines()
    n = sum(1 for line in lines[lines.index("[Rules]") + 1 :] if line.strip())
    del lines[lines.index("[Rules]") + 1 + k]
    return "\n".join(lines).replace(f"NumRules={n}", f"NumRules={n - 1}") + "\n"


def _inputs(n=500, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.5, 1.5, n), rng.uniform(-15, 15, n)


def test_not_of_term_1_reads_as_a_general_system(flc_text):
    """MATLAB's '-1' (NOT of a variable's first term) in a min/min/max/centroid file: the
    file is outside the fast subset and reads as a FuzzySystem; it was refused as 'term
    index -2 is not an integer in [0, 6]' when the subset test let -1 through."""
    text, _ = _with_rule(flc_text, 0, "-1 1, 7 (1) : 1")
    system = fis.read_fis(text)
    assert isinstance(system, FuzzySystem)
    assert system.rules[0].antecedent == (-1, 1) and system.rules[0].consequent == (7,)
    # a centroid by hand: the other 48 rules' levels (the fast engine's), the NOT rule's
    # min(1 - NB(s), NB(sdot)) joined to output term 7 by max
    rest = fis.read_fis(_without_rule(flc_text, 0))
    nb_s, nb_sdot = system.inputs[0].terms[0], system.inputs[1].terms[0]
    lo, hi = system.outputs[0].universe
    u = np.linspace(lo, hi, 200001)
    for x, y in [(0.3, -9.0), (-0.5, -8.0), (0.9, -9.5), (0.0, -3.0), (0.5, 5.0)]:
        levels = list(rest.clip_levels(x, y))
        levels[6] = max(levels[6], min(1.0 - nb_s(x), nb_sdot(y)))
        terms = system.outputs[0].terms
        agg = np.max([np.minimum(h, t(u)) for h, t in zip(levels, terms, strict=True)], axis=0)
        ref = np.trapezoid(u * agg, u) / np.trapezoid(agg, u)
        assert system(x, y) == pytest.approx(ref, abs=1e-6)


def test_a_rule_with_consequent_0_reads_and_adds_nothing(flc_text):
    """Consequent 0 (the rule says nothing of the output: legal in MATLAB) reads as a
    FuzzySystem whose output is that of the file without the rule; it was refused as
    'term index -1' when the subset test let 0 through."""
    text, _ = _with_rule(flc_text, 0, "1 1, 0 (1) : 1")
    system = fis.read_fis(text)
    assert isinstance(system, FuzzySystem) and system.rules[0].consequent == (0,)
    s, sdot = _inputs()
    rest = fis.read_fis(_without_rule(flc_text, 0))
    np.testing.assert_allclose(system(s, sdot), rest(s, sdot), rtol=0, atol=1e-12)


def _refusal(source) -> fis.FISError:
    with pytest.raises(fis.FISError) as info:
        fis.read_fis(source)
    return info.value


def test_numrules_below_the_rule_lines_is_refused(flc_text):
    """NumRules=48 over 49 rule lines (one too few, as well as too many) names the line."""
    err = _refusal(flc_text.replace("NumRules=49", "NumRules=48"))
    assert str(err) == "<string>:7: NumRules=48 but [Rules] has 49 lines in: NumRules=48"
    assert (err.lineno, err.line) == (7, "NumRules=48")


def test_not_of_a_term_that_does_not_exist_names_its_line_and_range(flc_text):
    """'-8' where the variable has 7 terms: the rule's line, the range, the line echoed."""
    text, lineno = _with_rule(flc_text, 0, "-8 1, 7 (1) : 1")
    err = _refusal(text)
    assert str(err) == (
        f"<string>:{lineno}: term index -8 out of range for 's' (1..7) in: -8 1, 7 (1) : 1"
    )
    assert err.problems == [(lineno, "term index -8 out of range for 's' (1..7)", err.line)]


SUGENO = """\
[System]
Name='sg'
Type='sugeno'
Version=2.0
NumInputs=1
NumOutputs=1
NumRules=2
AndMethod='prod'
OrMethod='probor'
ImpMethod='prod'
AggMethod='sum'
DefuzzMethod='wtaver'

[Input1]
Name='x'
Range=[0 1]
NumMFs=2
MF1='lo':'trimf',[-1 0 1]
MF2='hi':'trimf',[0 1 2]

[Output1]
Name='y'
Range=[0 1]
NumMFs=2
MF1='a':'constant',[0]
MF2='b':'linear',[1 0]

[Rules]
1, 1 (1) : 1
2, 2 (1) : 1
"""


def test_a_negated_sugeno_consequent_names_its_line(tmp_path):
    assert isinstance(fis.read_fis(SUGENO), FuzzySystem)
    path = tmp_path / "sg.fis"
    path.write_text(SUGENO.replace("2, 2 (1) : 1", "2, -2 (1) : 1"))
    err = _refusal(path)
    assert str(err) == (f"{path}:30: a Sugeno consequent cannot be negated (NOT) in: 2, -2 (1) : 1")
    assert (err.lineno, err.line) == (30, "2, -2 (1) : 1")


def test_two_lines_before_the_first_section_are_counted(flc_text):
    err = _refusal("junk one\njunk two\n" + flc_text)
    assert err.problems == [(1, "2 lines of text before the first section", "junk one")]
    err = _refusal("junk one\n" + flc_text)
    assert err.problems == [(1, "text before the first section", "junk one")]


def test_a_list_of_11_values_is_shortened_and_10_are_shown(flc_text):
    """Messages show a list of up to 10 numbers whole; 11 as first 4, last 2 and count."""
    nb = "MF1='NB':'zmf',[-1 -0.6666666666666666]"  # [Input1]'s (line 18)
    err = _refusal(flc_text.replace(nb, "MF1='NB':'zmf',[0 1 2 3 4 5 6 7 8 9 10]", 1))
    assert str(err) == (
        "<string>:18: zmf takes 2 parameters, got 11: (0.0, 1.0, 2.0, 3.0, ..., 9.0, 10.0) "
        "(11 values) in: MF1='NB':'zmf',[0 1 2 3 ... 9 10] (11 values)"
    )
    err = _refusal(flc_text.replace(nb, "MF1='NB':'zmf',[0 1 2 3 4 5 6 7 8 9]", 1))
    assert str(err) == (
        "<string>:18: zmf takes 2 parameters, got 10: (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, "
        "7.0, 8.0, 9.0) in: MF1='NB':'zmf',[0 1 2 3 4 5 6 7 8 9]"
    )


def test_a_file_of_2_percent_control_bytes_is_a_binary_file(tmp_path, flc_text):
    """No NUL, but 2 % of the first 4096 bytes are control characters (over the 1 %
    allowed): one line saying it is binary, not the many lines of a text misread."""
    body = flc_text.encode()
    path = tmp_path / "ctl.fis"
    path.write_bytes(b"\x01" * (len(body[:4096]) // 50 + 1) + body)
    err = _refusal(path)
    assert str(err) == f"{path}: binary file, not a .fis text file"
