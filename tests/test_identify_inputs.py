"""Identification's input checks and messages (a code reader's findings): small logs and
direct calls, kept fast; the estimation itself is tested in tests/test_identify.py."""

from __future__ import annotations

import math
import os
import re
import threading

import numpy as np
import pytest

import pkmctl
from pkmctl.ident.identify import IdentificationError, Log, identify
from tests.conftest import run_pkmctl


@pytest.fixture(scope="module")
def proto() -> pkmctl.Scenario:
    return pkmctl.Scenario.builtin("prototype")


def _log(n: int = 200, tau: float = 100.0, **changes) -> Log:
    """n samples at 1 kHz at the prototype's home lengths, constant forces."""
    d = {"t": 1e-3 * np.arange(n), "q": np.full((n, 4), 0.7), "tau": np.full((n, 4), tau)}
    d.update(changes)
    return Log(d["t"], d["q"], d["tau"], "bad.csv")


@pytest.mark.parametrize(("scale", "words"), [(1e-200, "small"), (1e-160, "small"),
                                              (1e300, "large")])  # fmt: skip
def test_forces_at_extreme_scales_are_refused_in_one_line(proto, scale, words):
    """1e-200 x a log's forces raised a ZeroDivisionError (exit 1), 1e-160 x LAPACK's "SVD
    did not converge" naming no log, 1e300 x a timing diagnosis (a code reader)."""
    with pytest.raises(IdentificationError) as info:
        identify(_log(tau=400 * scale), proto, force_lead=None)
    msg = str(info.value)
    assert msg.startswith(
        f"log 'bad.csv': the largest |tau| is {400 * scale:.3g} N, too {words} for the fit "
        "(allowed: 1e-100 to 1e+100 N)"
    ), msg
    assert "\n" not in msg


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_named_like_the_metadata_is_not_read(tmp_path):
    """A FIFO named LOG.json beside the log hung identify for ever: the force lead's
    default read it without the regular-file check the scenario's lookup made (a code
    reader). Read in a thread here, unblocked by a writer if it hangs."""
    from pkmctl.cli_identify import _metadata_scenario, _other_table

    (tmp_path / "log.csv").write_text("t\n")
    os.mkfifo(tmp_path / "log.json")
    for fn in (_metadata_scenario, _other_table):
        got = []
        reader = threading.Thread(target=lambda f=fn, g=got: g.append(f(tmp_path / "log.csv")))
        reader.start()
        reader.join(5.0)
        hung = reader.is_alive()
        if hung:  # open it for writing, and close it: the reader gets an empty file
            os.close(os.open(tmp_path / "log.json", os.O_WRONLY))
            reader.join()
        assert not hung, f"{fn.__name__} blocked on the FIFO"
        assert got == [None]


def _run(*args, cwd):
    return run_pkmctl(*args, cwd=cwd)


def test_excite_prints_a_cutoff_identify_accepts_at_a_non_round_rate(tmp_path, proto):
    """Logging every 3rd period (333.333 Hz): excite printed --cutoff 6.66667 from the exact
    333.3333... Hz, which identify, reading 333.333 Hz, refused; its error gave the range
    (0, 6.667], which holds 6.66667, and asked for >= 333.3 Hz of a 333.333 Hz log (a code
    reader). Both now round the way that keeps them true."""
    slow = proto.replace(**{"logging.every": 3})
    (tmp_path / "e3.toml").write_text(slow.to_toml())
    r = _run("excite", "--scenario", "e3.toml", "--out", "ex.toml", "--harmonics", "3",
             "--base-frequency", "0.5", "--periods", "1", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    printed = re.search(r"identify DIR/pd\.parquet --cutoff (\S+)", " ".join(r.stdout.split()))
    assert printed, r.stdout
    cut = float(printed[1])
    log = _log(t=3e-3 * np.arange(200))  # 333.333 Hz, too short to identify
    with pytest.raises(IdentificationError, match="too short for cutoff") as info:
        identify(log, slow, cutoff=cut)
    assert "too slowly" not in str(info.value)
    with pytest.raises(IdentificationError) as info:
        identify(log, slow, cutoff=6.66667)
    msg = str(info.value)
    assert "sampled at 333.333 Hz, too slowly for cutoff = 6.66667 Hz, which must be in " in msg
    assert "(0, 6.66666] Hz" in msg and "must be sampled at >= 333.334 Hz" in msg, msg


@pytest.mark.parametrize("cutoff", [10.0, 12.8, 7.3])
def test_minimum_duration_is_what_identify_needs(proto, cutoff):
    """minimum_duration counted the filters' support in seconds, observe in whole samples:
    at 12.8 Hz (a half-length of 156.25 samples, 157 used) a log of the duration it gave
    was refused, 1.5 ms short (a code reader). A log of that span passes the length check
    (and is refused for what follows: it does not move), one sample less does not."""
    from pkmctl.ident.identify import minimum_duration

    n = math.ceil(1000.0 * minimum_duration(cutoff, 30) - 1e-6) + 1  # the fewest spanning it
    home = proto.plant().inverse_kinematics(proto.plant().home)
    for k, short in ((n, False), (n - 1, True)):
        with pytest.raises(IdentificationError) as info:
            identify(_log(n=k, q=np.tile(home, (k, 1))), proto, cutoff=cutoff)
        assert ("too short for cutoff" in str(info.value)) == short, str(info.value)
    # the refusal's numbers say why: it printed "9168 samples (9.167 s) ... needs >= 9.167
    # s" at 7.3 Hz (a review)
    said = re.search(r"(\d+) samples \(([\d.]+) s\).*needs >= ([\d.]+) s, (\d+) samples",
                     str(info.value))  # fmt: skip
    assert said and int(said[1]) == n - 1 and int(said[4]) == n, str(info.value)
    assert float(said[2]) < float(said[3]), str(info.value)


def test_excite_times_the_run_for_the_log_it_gives(tmp_path):
    """A run of D s logs t = 0 .. D - 1 ms: excite said a 6.72631 s design was long enough
    for identify's 6.726 s, and identify refused the run's 6.725 s log (a code reader)."""
    r = _run("excite", "--out", "ex.toml", "--harmonics", "3", "--periods", "1",
             "--base-frequency", "0.14867", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    said = " ".join(r.stderr.split())
    assert (
        "warning: 6.72631 s is too short for pkmctl identify at its default --cutoff 10 Hz, "
        "which needs >= 6.727 s of run" in said
    ), said
    assert "use --periods >= 2" in said, said


def test_timestamps_in_t_are_refused_by_name(tmp_path):
    """ISO times in t (2026-12-07T10:00:00.000, 1 ms apart) were read as nanoseconds since
    1970: 'sampled at 1.00006e-06 Hz ... t in milliseconds?' (a code reader)."""
    from datetime import datetime, timedelta

    from pkmctl.ident.identify import read_log

    t0 = datetime(2026, 12, 7, 10)
    rows = "".join(
        f"{(t0 + timedelta(milliseconds=k)).isoformat(timespec='milliseconds')},"
        "0.7,0.7,0.7,0.7,1,1,1,1\n"
        for k in range(30)
    )
    (tmp_path / "iso.csv").write_text("t,q1,q2,q3,q4,tau1,tau2,tau3,tau4\n" + rows)
    with pytest.raises(IdentificationError) as info:
        read_log(tmp_path / "iso.csv")
    assert str(info.value).startswith(
        f"log {str(tmp_path / 'iso.csv')!r}: column t holds dates or times (timestamp["
    ), str(info.value)
    assert "not numbers: t must be in seconds" in str(info.value)


@pytest.mark.parametrize(
    ("kw", "words"),
    [
        ({"restarts": 0}, "restarts = 0: must be an integer >= 1"),
        ({"base_frequency": 0.0}, r"base_frequency = 0.0: must be in \(0, 10\] Hz"),
        ({"base_frequency": float("nan")}, r"base_frequency = nan: must be in \(0, 10\] Hz"),
        ({"samples": 0}, r"samples = 0: must be an integer >= 20 \(points a period"),
        ({"periods": 0}, "periods = 0: must be an integer >= 1"),
        ({"harmonics": 2}, r"harmonics = 2: must be an integer >= 3 \(rest at both ends"),
        ({"seed": -1}, "seed = -1: must be an integer >= 0"),
        ({"max_iter": 0}, "max_iter = 0: must be an integer >= 1"),
        ({"restarts": 1.5}, "restarts = 1.5: must be an integer >= 1"),
        (
            {"base_frequency": 1e-3, "periods": 4},
            "base_frequency = 0.001: a run of periods = 4 would last 4000 s, over timing",
        ),
    ],
)
def test_design_excitation_checks_each_argument(proto, kw, words):
    """restarts = 0 raised a TypeError, base_frequency = 0 a ZeroDivisionError, samples = 0
    numpy's zero-size reduction, and periods = 0 'designed' a run of 0 s (a code reader):
    each is refused naming the argument, its value and what it must be."""
    from pkmctl.ident.excite import design_excitation

    with pytest.raises(ValueError, match=f"^{words}") as info:
        design_excitation(proto, **kw)
    assert "\n" not in str(info.value)


def test_an_invalid_filtered_pose_is_named_by_its_data_row_and_time(proto, monkeypatch):
    """The pose check runs on rows 4..n-3 (where the differences are defined) and named
    the k-th of them 'sample k', three rows early, with no time (a code reader). No log
    that passes forward kinematics was found to reach it, so forward kinematics is
    replaced here: home, tilting smoothly (0.5 s) to past the condition limit (1.56 rad)."""
    import scipy.signal

    from pkmctl.ident import identify as m
    from pkmctl.model.mechanism import MAX_CONDITION, limbs_batch

    mech = proto.plant()
    n = 700
    X = np.tile(mech.home, (n, 1))
    X[:, 1] = 0.78 * (1.0 - np.cos(np.pi * np.minimum(1e-3 * np.arange(n) / 0.5, 1.0)))
    monkeypatch.setattr(m, "_forward_kinematics", lambda *a, **k: (X.copy(), 0.0))
    log = _log(n=n, q=np.tile(mech.inverse_kinematics(mech.home), (n, 1)))
    with pytest.raises(IdentificationError) as info:
        m.observe(log, mech)
    # the first row whose filtered pose (Butterworth order 4 at 0.1 fs, zero-phase) is
    # past the limit, among those checked
    Xf = scipy.signal.sosfiltfilt(scipy.signal.butter(4, 100.0, fs=1000.0, output="sos"), X,
                                  axis=0)  # fmt: skip
    _, J = limbs_batch(mech.geometry, np.ascontiguousarray(Xf))
    bad = np.flatnonzero(np.linalg.cond(J) >= MAX_CONDITION)
    k = int(bad[bad >= 3][0])
    assert str(info.value) == (
        f"log 'bad.csv': data row {k + 1} (t = {log.t[k]:.6g} s) is at a singular or invalid "
        "pose (its pose filtered for the derivatives)"
    )
