"""Identification's input checks and messages (a code reader's findings): small logs and
direct calls, kept fast; the estimation itself is tested in tests/test_identify.py."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

import pkmctl
from pkmctl.ident.identify import IdentificationError, Log, identify


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
