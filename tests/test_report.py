"""Tests of pkmctl.report: Table 4 (CSV, markdown), figures 10-26 and report.md."""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pkmctl
from pkmctl.report import (
    FIGURES,
    PAPER_TABLE4,
    make_figures,
    render_report,
    table4_csv,
    table4_markdown,
)
from pkmctl.report.tables import rmse_after
from pkmctl.sim.metrics import RMSE_KEYS
from pkmctl.sim.result import Result

CONTROLLERS = ("smc", "fsmc", "afsmc")
EXPECTED_FIGURES = [f"fig{n}.png" for n in range(10, 27)]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def results() -> dict[str, Result]:
    """Short runs of the paper scenario: long enough to cover the 0.2 s transient."""
    return {c: pkmctl.simulate("paper", controller=c, duration=0.3) for c in CONTROLLERS}


@pytest.fixture(scope="module")
def figure_dir(results, tmp_path_factory) -> tuple[Path, list[Path]]:
    outdir = tmp_path_factory.mktemp("figures")
    return outdir, make_figures(results, outdir, dpi=60)


class _FixedRMSE(Result):
    """A result whose whole-run RMSE is given (in ``info["rmse"]``), to steer rankings."""

    def rmse(self) -> dict[str, float]:
        return dict(self.info["rmse"])


def _with_rmse(result: Result, values: dict[str, float]) -> Result:
    fields = {f.name: getattr(result, f.name) for f in dataclasses.fields(Result)}
    fields["info"] = {"rmse": values}
    return _FixedRMSE(**fields)


# ---------------------------------------------------------------- tables
def test_paper_table4_is_complete() -> None:
    assert list(PAPER_TABLE4) == list(CONTROLLERS)
    for row in PAPER_TABLE4.values():
        assert tuple(row) == RMSE_KEYS
        assert all(v > 0 for v in row.values())
    assert PAPER_TABLE4["smc"]["beta_deg"] == 6.12032
    assert PAPER_TABLE4["afsmc"]["q4_m"] == 0.0075560


def test_table4_csv_parses_and_matches_rmse(results) -> None:
    rows = list(csv.reader(io.StringIO(table4_csv(results))))
    assert rows[0] == [
        "controller",
        "z_mm",
        "alpha_deg",
        "beta_deg",
        "q1_m",
        "q2_m",
        "q3_m",
        "q4_m",
    ]
    assert [r[0] for r in rows[1:]] == list(CONTROLLERS)
    for row in rows[1:]:
        expected = results[row[0]].rmse()
        assert [float(v) for v in row[1:]] == [expected[k] for k in RMSE_KEYS]  # exact


def test_table4_csv_orders_and_filters_rows(results) -> None:
    text = table4_csv({"afsmc": results["afsmc"], "smc": results["smc"], "other": None})
    assert [r[0] for r in csv.reader(io.StringIO(text))][1:] == ["smc", "afsmc"]
    assert table4_csv({}).strip() == "controller,z_mm,alpha_deg,beta_deg,q1_m,q2_m,q3_m,q4_m"


def test_table4_markdown_shows_ours_and_the_papers(results) -> None:
    md = table4_markdown(results)
    for row in PAPER_TABLE4.values():
        for value in row.values():
            assert repr(value) in md
    for literal in ("0.545968", "6.12032", "2.66612", "0.00061928"):
        assert literal in md
    for header in ("z (mm)", "α (°)", "β (°)", "q1 (m)", "(N)", "(N/s)"):
        assert header in md
    for label in ("SMC", "FSMC", "AFSMC"):
        assert f"| {label} | ours |" in md
        assert f"| {label} | paper |" in md
    assert "after the first 1 s" in md
    # every table row has as many cells as its header
    for block in md.split("\n\n"):
        rows = [line for line in block.splitlines() if line.startswith("|")]
        if rows:
            assert len({r.count("|") for r in rows}) == 1


# ---------------------------------------------------------------- figures
def test_make_figures_writes_17_pngs_and_nothing_else(figure_dir) -> None:
    outdir, paths = figure_dir
    assert [p.name for p in paths] == EXPECTED_FIGURES
    assert sorted(os.listdir(outdir)) == sorted(EXPECTED_FIGURES)  # no temporary files left
    for p in paths:
        assert p.parent == outdir
        data = p.read_bytes()
        assert len(data) > len(PNG_SIGNATURE)
        assert data.startswith(PNG_SIGNATURE)


def _drawn(number: int, pairs: list[tuple[str, Result]]):
    """Figure ``number`` drawn (not saved): its Figure and renderer."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from pkmctl.report.figures import _DRAW, _FIGSIZE

    spec = next(s for s in FIGURES if s.number == number)
    fig = Figure(figsize=_FIGSIZE.get(spec.kind, (8.0, 6.0)))
    FigureCanvasAgg(fig)
    _DRAW[spec.kind](fig, spec, pairs)
    return fig, fig.canvas.get_renderer()


def test_curves_on_one_another_share_their_line_in_turns() -> None:
    """Fig. 24: AFSMC's force lies within 0.3 N of FSMC's and was drawn under it, 0 of its
    pixels visible in the middle panel (a tester), so the paper's comparison of the two
    could not be seen. Two equal curves now alternate, dashed, and the legend shows every
    controller's line solid."""
    import matplotlib.colors

    from pkmctl.report.figures import _color

    r = pkmctl.simulate("paper", controller="fsmc", duration=0.3)
    other = pkmctl.simulate("paper", controller="pd", duration=0.3)
    fig, _ = _drawn(24, [("fsmc", r), ("afsmc", r), ("pd", other)])
    for ax in fig.axes:
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        assert lines["FSMC"].get_linestyle() != lines["AFSMC"].get_linestyle()  # one dashed
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    box = fig.axes[2].get_window_extent()  # the detail panel, in pixels from the bottom
    h = rgb.shape[0]
    panel = rgb[int(h - box.y1) : int(h - box.y0), int(box.x0) : int(box.x1)]
    for name in ("fsmc", "afsmc"):
        color = np.array(matplotlib.colors.to_rgb(_color(name))) * 255
        assert (np.abs(panel - color).sum(-1) < 30).sum() > 100, name  # both seen
    legend = fig.axes[0].get_legend()
    assert all(ln.get_linestyle() == "-" for ln in legend.get_lines()[:3])


def test_box_figures_keep_each_label_off_the_other_panel() -> None:
    """Figs. 21-22: the right panel's y label ran over the left panel's frame, pushed
    left by long symlog tick labels ("-5x10^-4", in runs past 1 s)."""
    pairs = [("smc", pkmctl.simulate("paper", controller="smc", duration=2.0))]  # -8 px
    for number in (20, 21, 22):
        fig, renderer = _drawn(number, pairs)
        fig.canvas.draw()  # places the labels
        left, right = fig.axes[:2]
        label = right.yaxis.label.get_window_extent(renderer)
        assert label.x0 > left.get_window_extent(renderer).x1, number


def test_figure_window_is_the_samples_between_its_ends() -> None:
    import numpy as np

    from pkmctl.report.figures import _window

    t = np.arange(0, 20001) * 5e-5  # a run's sample times
    y = np.sin(t)
    for lo, hi in [
        (0.0, np.inf),
        (1.0, np.inf),
        (0.0, 0.3),
        (0.3, 0.30005),
        (2.0, 1.0),
        (5.0, 9.0),
    ]:
        sel = (t >= lo - 1e-12) & (t <= hi + 1e-12)
        tw, yw = _window(t, y, lo, hi)
        assert np.array_equal(tw, t[sel]) and np.array_equal(yw, y[sel]), (lo, hi)


def test_figure_specs_follow_the_paper_numbering() -> None:
    assert [s.filename for s in FIGURES] == EXPECTED_FIGURES
    assert [s.kind for s in FIGURES] == ["tracking"] * 7 + ["error"] * 3 + ["box"] * 3 + [
        "force"
    ] * 4
    assert all(s.title.startswith(f"Fig. {s.number} — ") for s in FIGURES)
    # a figure draws every controller that ran (reproduce: five), so no caption counts them
    assert not [s.caption for s in FIGURES if "three" in s.caption]


def test_make_figures_leaves_no_temporary_file_on_failure(results, tmp_path, monkeypatch) -> None:
    from matplotlib.figure import Figure

    def broken_savefig(self, fname, **kwargs):
        fname.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken_savefig)
    with pytest.raises(OSError, match="disk full"):
        make_figures(results, tmp_path)
    assert os.listdir(tmp_path) == []


needs_fork = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forks on Linux")


@needs_fork
def test_figures_drawn_in_processes_are_the_same_files(results, figure_dir, tmp_path) -> None:
    """reproduce draws in forked processes: the same PNGs, byte for byte, as drawn here."""
    outdir, paths = figure_dir
    forked = make_figures(results, tmp_path, dpi=60, workers=3)
    assert [p.name for p in forked] == EXPECTED_FIGURES
    for a, b in zip(paths, forked, strict=True):
        assert a.read_bytes() == b.read_bytes(), a.name
    assert sorted(os.listdir(tmp_path)) == sorted(EXPECTED_FIGURES)


@needs_fork
def test_a_failure_in_a_drawing_process_reaches_the_caller(results, tmp_path, monkeypatch):
    """The children are forked with this process's memory, monkeypatch included."""
    import multiprocessing

    from matplotlib.figure import Figure

    def broken_savefig(self, fname, **kwargs):
        fname.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken_savefig)
    with pytest.raises(OSError, match="disk full"):
        make_figures(results, tmp_path, workers=2)
    assert os.listdir(tmp_path) == []
    assert multiprocessing.active_children() == []  # the drawing processes are gone


@needs_fork
def test_drawing_processes_see_the_parents_objects_frozen(results, tmp_path, monkeypatch):
    """A child's full collection must not walk (and copy) the heap it was forked with;
    the caller's collector is left as it was found."""
    import gc

    from pkmctl.report import figures

    def record(spec, pairs, outdir, dpi):  # runs in the child
        path = outdir / spec.filename
        path.write_text(str(gc.get_freeze_count()))
        return path

    monkeypatch.setattr(figures, "_draw_one", record)
    gc.unfreeze()  # as a fresh process finds it, whatever a test before did
    paths = make_figures(results, tmp_path, workers=2)
    assert gc.get_freeze_count() == 0
    assert all(int(p.read_text()) > 1000 for p in paths)
    gc.freeze()  # a caller that froze its objects itself keeps them frozen
    try:
        make_figures(results, tmp_path, workers=2)
        assert gc.get_freeze_count() > 1000
    finally:
        gc.unfreeze()


def test_make_figures_rejects_empty_input(tmp_path) -> None:
    with pytest.raises(ValueError, match="no known controller"):
        make_figures({}, tmp_path)


def test_report_package_does_not_import_pyplot() -> None:
    code = "import sys, pkmctl.report; sys.exit('matplotlib.pyplot' in sys.modules)"
    env = {**os.environ, "PYTHONPATH": str(Path(pkmctl.__file__).parents[1])}
    assert subprocess.run([sys.executable, "-c", code], env=env, timeout=120).returncode == 0


# ---------------------------------------------------------------- report.md
def test_render_report_links_every_figure_and_contains_the_table(results, figure_dir) -> None:
    _, paths = figure_dir
    text = render_report(results, figures=paths, scenario_name="paper", wall_time_s=12.5)
    for name in EXPECTED_FIGURES:
        assert f"](figures/{name})" in text
    assert table4_markdown(results).strip() in text
    assert "T_c = 50 µs" in text
    assert "duration 0.3 s" in text
    assert "seed 0" in text
    assert "12.5 s" in text
    assert "## Discussion" in text
    assert "continuous time" in text
    assert "unbounded" in text
    assert "not directly comparable" in text  # 0.3 s against the paper's 10 s
    said = "Plant `rigid`: the closed-form rigid machine (docs/model.md; options: "
    assert said + "docs/machine.md); sensor `ideal`, actuator `ideal`." in text  # which machine ran


def test_render_report_gives_a_drives_force_limit() -> None:
    """The prototype's drive limits the force to its peak torque through the screw
    (2 pi 0.9 3.82 / 0.01 = 2160.2 N) though its scenario has no actuators.force_limit."""
    sc = pkmctl.Scenario.builtin("prototype")
    assert sc.actuators.kind == "drive" and sc.actuators.force_limit is None
    runs = {"pd": pkmctl.simulate(sc, controller="pd", duration=0.02)}
    text = render_report(runs, figures=[], scenario_name="prototype")
    limit = 2 * math.pi * 0.9 * 3.82 / 0.01
    assert f"actuators limited to ±{round(limit, 1):g} N;" in text
    assert f"the actuators are limited to ±{round(limit, 1):g} N in this scenario" in text
    assert "unbounded" not in text
    assert "every T_c = 1 ms from the `encoder` sensor's measurement and its force " in text
    assert "applied through the `drive` actuator's own dynamics" in text


def test_render_report_names_the_fis_file_fsmc_and_afsmc_ran_on(tmp_path) -> None:
    """A scenario whose [fuzzy] fis is another file ran FSMC and AFSMC on it, and the
    report set them beside the paper's Table 4 without a word of it (a tester's)."""
    from importlib import resources

    fis = tmp_path / "mine.fis"
    fis.write_text((resources.files("pkmctl") / "fuzzy" / "data" / "paper_flc.fis").read_text())
    sc = pkmctl.Scenario.builtin("paper").replace(**{"fuzzy.fis": str(fis)})
    runs = {c: pkmctl.simulate(sc, controller=c, duration=0.02) for c in ("smc", "fsmc")}
    text = " ".join(render_report(runs, figures=[], scenario_name="mine").split())
    assert f"FSMC and AFSMC's fuzzy term: the `.fis` file `{fis}` (inputs clip), in place" in text
    plain = {"smc": pkmctl.simulate("paper", controller="smc", duration=0.02)}
    assert ".fis" not in render_report(plain, figures=[], scenario_name="paper")


def test_render_report_says_what_an_edited_scenario_changed() -> None:
    """An edited file that kept `name = "prototype"` (5 kg payload, another PD gain) gave
    the built-in's report word for word; a report on excite's trajectory set the paper's
    Table 4 beside it unsaid (a tester)."""
    proto = pkmctl.Scenario.builtin("prototype")
    edited = proto.replace(**{"payload.mass": 5.0, "gains.pd_kp": [20000.0, 2000.0, 2000.0]})
    run = {"pd": pkmctl.simulate(edited, controller="pd", duration=0.02)}
    text = " ".join(render_report(run, figures=[], scenario_name="prototype").split())
    assert (
        "It differs from the built-in “prototype” in gains.pd_kp = [20000, 2000, 2000] "
        "(built-in: [50000, 4000, 4000]); payload.mass = 5 (built-in: 0)." in text
    )
    assert "not the paper's" not in text
    plain = {"pd": pkmctl.simulate(proto, controller="pd", duration=0.02)}
    assert "differs from the built-in" not in render_report(plain, figures=[], scenario_name="p")
    # another trajectory, under another name: against the built-in it differs least from
    fourier = proto.replace(
        name="mine",
        trajectory={"kind": "fourier", "base_frequency": 0.2, "offset": [0.7, 0.0, 0.0],
                    "a": [[0.01, -0.01, 0.0]] * 3, "b": [[0.0, 0.0, 0.0]] * 3},
    )  # fmt: skip
    run = {"pd": pkmctl.simulate(fourier, controller="pd", duration=0.02)}
    text = " ".join(render_report(run, figures=[], scenario_name="mine").split())
    assert (
        "It differs from the built-in “prototype” in trajectory.kind = fourier (built-in: "
        "sinusoid). **Warning**: its trajectory is not the paper's (eq. 54, from rest at "
        "z = 0.7 m): Table 4's paper rows, and our ratios to them, come from another "
        "experiment." in text
    )


def test_render_report_says_when_the_drives_saturate_and_overspeed() -> None:
    """A prototype start saturates limbs 2 and 4 for milliseconds and drives the limbs
    past the drives' 0.833 m/s; the report gave the instant of one rounding's maximum
    and neither the time at the limit nor the speed until 2026-12-06."""
    from pkmctl.sim.metrics import limb_speed, time_at_force_limit, time_over_speed_limit

    sc = pkmctl.Scenario.builtin("prototype")
    r = pkmctl.simulate(sc, controller="pd", duration=0.1)
    text = render_report({"pd": r}, figures=[], scenario_name="prototype")
    limit = 2 * math.pi * 0.9 * 3.82 / 0.01
    at = np.flatnonzero(np.any(np.abs(r.tau) >= limit * (1 - 1e-9), axis=1))
    assert at.size >= 2  # the case this test is about
    t0, t1 = (f"{1e3 * r.t[k]:.0f} ms" for k in at[[0, -1]])
    assert f"at the limit from {t0} to {t1})" in text
    assert f"at the limit for {1e3 * time_at_force_limit(r):.0f} ms (PD)" in text
    speed, over = float(np.max(limb_speed(r))), time_over_speed_limit(r)
    assert speed > 0.833 and over > 0
    assert f"peak true limb speed is {speed:.3g} m/s (PD) against the drives' 0.833 m/s" in text
    assert f"exceeded for {1e3 * over:.0f} ms (PD)" in text


def test_render_report_of_the_prototype_is_true_to_its_runs() -> None:
    """On the machine as built the gravity estimate misses in sign and size (rotor inertia,
    friction, the drive): the report must not say "as predicted"; CTC spends most of its
    beta error after the start, so "the whole-run RMSE measures the start" is not said of
    it. A decimated log (logging.every = 20) keeps the run's times: no peak time read off
    the kept rows (it said t = 1.78 s for a peak at 9 ms), T and "after 1 s" from the
    run's end, not the last kept row."""
    from pkmctl.sim.metrics import last_time

    sc = pkmctl.Scenario.builtin("prototype", 1.5)
    runs = {c: pkmctl.simulate(sc, controller=c) for c in ("smc", "fsmc", "pd", "ctc")}
    text = render_report(runs, figures=[], scenario_name="prototype")
    assert "as predicted" not in text
    assert "do not have the predicted sign and size" in text
    assert "rotor inertia, joint friction and the `drive` actuator's dynamics" in text
    assert "for CTC mostly the tracking" in text
    thin = sc.replace(**{"logging.every": 20})
    decimated = {c: pkmctl.simulate(thin, controller=c) for c in ("smc", "pd")}
    r = decimated["smc"]
    assert r.t[-1] < last_time(r) == pytest.approx(1.5 - 1e-3)
    text = render_report(decimated, figures=[], scenario_name="prototype")
    forces = next(line for line in text.splitlines() if line.startswith("- **Forces**"))
    assert " at t = " not in forces and "at the logged periods (one in 20)" in forces
    assert "over T = 1.5 s" in text
    assert rmse_after(r) is not None and "too short" not in text


def test_render_report_says_which_plant_ran(results) -> None:
    on_mujoco = {c: dataclasses.replace(r, parts={**r.parts, "plant": "mujoco"})
                 for c, r in results.items()}  # fmt: skip
    text = render_report(on_mujoco, figures=[], scenario_name="paper")
    assert "Plant `mujoco`: the same machine in MuJoCo" in text


def test_render_report_accepts_relative_paths(results) -> None:
    rel = [Path("figures") / n for n in EXPECTED_FIGURES]
    text = render_report(results, figures=rel, scenario_name="paper")
    assert text.count("](figures/fig") == len(EXPECTED_FIGURES)
    assert "figures/figures" not in text


def test_render_report_ranking_claims_follow_the_numbers(results) -> None:
    """The discussion says "matches" only when the ranking does, and "differs" otherwise."""
    like_paper = {c: _with_rmse(r, dict(PAPER_TABLE4[c])) for c, r in results.items()}
    text = render_report(like_paper, figures=[], scenario_name="paper")
    assert "does for all of the 7 quantities" in text
    assert "It differs" not in text

    reversed_ = {
        c: _with_rmse(r, {k: 1.0 / PAPER_TABLE4[c][k] for k in RMSE_KEYS})
        for c, r in results.items()
    }
    text = render_report(reversed_, figures=[], scenario_name="paper")
    assert "does for none of the 7 quantities" in text
    assert "It differs for z (ours" in text


def test_render_report_counts_two_within_one_percent_as_either_order(results) -> None:
    """q2 measured SMC and AFSMC 0.07 % apart, ordered against the paper: the order was
    said to differ. Pair by pair, two within 1 % are a tie; all three within 1 %: no order."""
    changed = {}
    for c, r in results.items():
        values = dict(PAPER_TABLE4[c])
        if c in ("smc", "afsmc"):  # the paper: AFSMC < SMC on every quantity
            values["z_mm"] = 1.0 if c == "smc" else 1.005  # ours: SMC 0.5 % below AFSMC
        values["beta_deg"] = 2.0 * (1.0 + 0.001 * len(c))  # all three within 0.2 %
        changed[c] = _with_rmse(r, values)
    text = render_report(changed, figures=[], scenario_name="paper")
    assert "does for all of the 6 quantities ours order" in text
    assert "on z SMC and AFSMC are 0.5 % apart" in text
    assert "It differs" not in text
    assert "On β (±0.1 %) ours are all within 1 % of each other: no order" in text


def test_render_report_estimates_the_beta_transient(results) -> None:
    text = render_report(results, figures=[], scenario_name="paper")
    # 30° / sqrt(2 * 20 * 0.3 s) = 8.66°
    assert "β starts 30° off its trajectory" in text
    assert "= 8.66°" in text


def test_render_report_names_every_coordinate_that_starts_off() -> None:
    """Until 2026-12-06 only β was checked: a run starting 50 mm and 23° off in z and α,
    on its trajectory in β, was said to have "no initial transient"."""
    start = {"initial.X": [0.75, 0.4, 0.5235987755982988], "timing.duration": 0.3}
    sc = pkmctl.Scenario.builtin("paper").replace(**start)
    runs = {c: pkmctl.simulate(sc, controller=c) for c in ("smc", "afsmc")}
    text = render_report(runs, figures=[], scenario_name="custom")
    assert "no initial transient" not in text and "β starts" not in text
    assert "starts z 50 mm and α 22.9° off its trajectory" in text
    for q in ("z", "α"):
        shares = re.search(rf"The first 0.2 s hold (.*?) of the squared {q} error", text)
        assert shares and all(float(v) > 90 for v in re.findall(r"([\d.]+) % \(", shares[1]))
    on_track = sc.replace(**{"initial.X": [0.7, 0.0, 0.5235987755982988]})
    runs = {c: pkmctl.simulate(on_track, controller=c) for c in ("smc", "afsmc")}
    text = render_report(runs, figures=[], scenario_name="custom")
    assert "the run starts on its trajectory, so no initial transient dominates" in text


def test_render_report_explains_the_z_errors_and_says_when_one_swings() -> None:
    """SMC's steady z error ~ dG / (gain lam), measured as its mean after 1 s; PD's error
    follows the trajectory (no feedforward), so its mean is not a steady value: said."""
    from pkmctl.sim.metrics import _errors

    sc = pkmctl.Scenario.builtin("paper", 4.2)  # a period of the trajectory (pi s) after 1 s
    runs = {c: pkmctl.simulate(sc, controller=c) for c in ("smc", "pd")}
    text = render_report(runs, figures=[], scenario_name="paper")
    assert "(each measured as its mean z error after 1 s)" in text
    smc = re.search(
        r"SMC \(gain near s = 0: [^)]*\) predicts ([\d.]+) mm and shows ([\d.]+) mm;", text
    )
    assert smc and 0.8 < float(smc[2]) / float(smc[1]) < 1.2  # measured 0.0303 for 0.0315
    e = _errors(runs["pd"], 1.0)[:, 0]
    assert np.ptp(e) > abs(e.mean())
    assert f"(its error swings from {e.min():.3g} to {e.max():.3g} mm with the trajectory)" in text


def test_render_report_rejects_empty_input() -> None:
    with pytest.raises(ValueError, match=r"results: no run among \[\] \(a Result for each"):
        render_report({}, figures=[], scenario_name="paper")


def test_render_report_of_a_controller_with_no_surface_gain_on_z() -> None:
    """gains.pd_kp = [0, ...] is valid: every run of `reproduce` finished, then the report
    divided by PD's zero gain and the command lost them all with an internal error (a code
    reader). It also said "SMC and FSMC meet it" whatever ran."""
    sc = pkmctl.Scenario.builtin("paper", 1.2).replace(**{"gains.pd_kp": [0.0, 4e3, 4e3]})
    runs = {c: pkmctl.simulate(sc, controller=c) for c in ("smc", "pd", "ctc")}
    text = render_report(runs, figures=[], scenario_name="custom")
    assert "PD has no gain from s to F on z near s = 0, so nothing there meets" in text
    assert "of gravity on z. SMC meets it with the gain from s to F" in text
    assert re.search(r"SMC \(gain near s = 0: [^)]*\) predicts [\d.]+ mm and shows", text)
    # two runs of the paper's three: SMC alone is no ranking, and not "one controller"
    assert (
        "- Rankings: only one of the paper's controllers (SMC, FSMC and AFSMC) was run, so "
        "there is nothing to rank against its Table 4." in text
    )


@pytest.mark.parametrize(("reach", "lin"), [(0.27, 0.5), (0.5, 0.5), (2.3e-4, 5e-4), (0.11, 0.2),
                                            (1.0, 1.0)])  # fmt: skip
def test_symlog_box_axes_put_no_decade_tick_inside_their_linear_part(reach, lin):
    from matplotlib.figure import Figure

    from pkmctl.report.figures import _symlog

    ax = Figure().subplots()
    ax.plot([0, 1], [-30 * reach, 60 * reach])
    assert _symlog(ax, reach, 2.0) == pytest.approx(lin)
    ticks = [float(t) for t in ax.get_yticks()]
    inside = sorted(abs(t) for t in ticks if abs(t) <= lin)
    assert inside[0] == 0 and inside[1:] == pytest.approx([lin, lin])  # 0 and ±lin
    outside = [abs(t) for t in ticks if abs(t) > lin]
    assert outside and all(t >= 3 * lin and np.log10(t) == pytest.approx(round(np.log10(t)))
                           for t in outside)  # fmt: skip
    labels = [ax.yaxis.get_major_formatter()(t) for t in ticks]
    assert "0" in labels and not any("-" in s for s in labels)  # minus signs, not hyphens


@pytest.mark.parametrize(
    ("afsmc_scale", "verdict"),
    [(1.0, "not smoother: the paper's finding"), (0.5, "smoother, as the paper finds")],
)
def test_the_report_says_who_chatters_and_whether_afsmc_is_smoother(
    monkeypatch, afsmc_scale, verdict
):
    """The prototype's report ranked SMC first after 1 s without a word of its forces
    ringing at 20 x FSMC's chattering index, and the paper's finding that AFSMC's forces
    are smoother (its Figs. 24, 26) went unmentioned where ours were not (a tester)."""
    from pkmctl.report import document

    base = np.array([500.0, 3.6e3, 510.0, 3.7e3])
    index = {"smc": np.array([500.0, 7.1e4, 500.0, 7.2e4]), "fsmc": base,
             "afsmc": afsmc_scale * base, "pd": 1.1 * base, "ctc": 0.9 * base}  # fmt: skip
    pairs = [(c, c) for c in index]  # the "result" is its name: the index is looked up
    monkeypatch.setattr(document, "chattering_index", lambda r: index[r])
    lines = document._chatter_sentences(pairs)
    assert lines[0].startswith("- **SMC chatters**: its chattering index on τ2 7.1e+04 N/s "
                               "and τ4 7.2e+04 N/s is 19.5 × the median")  # fmt: skip
    assert len(lines) == 2 and verdict in lines[1]


def test_machine_captions_say_no_negative_zero(tmp_path) -> None:
    """A caption read "alpha = -0.0 deg" at the largest tilt of a tester's run."""
    from pkmctl.experiment import _machine_section

    X = np.array([0.7, np.radians(-0.04), np.radians(12.25)])
    text = _machine_section([(tmp_path / "m.png", "largest tilt", 1.0, X)], "", tmp_path)
    assert "alpha = 0.0 deg, beta = 12.2 deg" in text, text


def test_a_panel_the_run_is_too_short_for_shows_no_axes_ticks(results) -> None:
    """Under 1 s, the after-1-s panels were empty axes with 0-1 ticks and data labels
    ("z error (mm)", "t (s)") around "run shorter than 1 s": they read as data."""
    pairs = list(results.items())  # 0.3 s runs
    for number, ax_index in ((17, 1), (20, 1)):
        fig, _ = _drawn(number, pairs)
        ax = fig.axes[ax_index]
        assert len(ax.get_xticks()) == len(ax.get_yticks()) == 0, number
        assert ax.get_xlabel() == ax.get_ylabel() == "", number
        assert any("1 s" in t.get_text() or "no samples" in t.get_text() for t in ax.texts)


def test_curves_a_decade_apart_on_a_log_panel_keep_their_own_line() -> None:
    """On the |error| panels (log axis) SMC's 5e-5 deg beta error was dashed as sharing
    FSMC's 6e-4, within 1 % of the panel's linear range (a review)."""
    from pkmctl.report.figures import _shared_styles

    t = np.linspace(0.0, 1.0, 200)
    rng = np.random.default_rng(0)
    big, mid = 1e-1 * (1 + rng.random(200)), 6e-4 * (1 + rng.random(200))
    small = 5e-5 * (1 + rng.random(200))
    drawn = [("pd", t, big), ("fsmc", t, mid), ("smc", t, small)]
    assert _shared_styles(drawn)["smc"] != "-"  # on a linear axis they do lie together
    assert set(_shared_styles(drawn, log=True).values()) == {"-"}
    same = [("fsmc", t, mid), ("afsmc", t, mid * (1 + 1e-4))]
    assert _shared_styles(same, log=True)["afsmc"] != "-"  # equal ones still share


def test_a_panel_a_thinned_log_has_no_rows_for_says_so() -> None:
    """With logging.every = 2000 (a row per 0.1 s), the force figures' "first 50 ms" and
    "detail" panels and, at every = 30000, the |error| panel after 1 s were blank axes
    with data-like ticks and no word (a code reader)."""
    for every, number, empty in ((2000, 24, (0, 2)), (30000, 17, (1,))):
        sc = pkmctl.Scenario.builtin("paper", 2.5).replace(**{"logging.every": every})
        fig, _ = _drawn(number, [("smc", pkmctl.simulate(sc, controller="smc"))])
        for i, ax in enumerate(fig.axes):
            said = [t.get_text() for t in ax.texts]
            if i in empty:
                assert len(ax.get_xticks()) == len(ax.get_yticks()) == 0, (number, i)
                assert ax.get_xlabel() == ax.get_ylabel() == "", (number, i)
                assert said == [
                    f"the log keeps a row every {every * 5e-5:.3g} s:\nfewer than 2 in this window"
                ], (number, i)
            else:
                assert said == [] and len(ax.get_lines()) >= 1, (number, i)
        # the legend on the first panel with curves (it was an empty box on a blank one)
        first = next(i for i in range(len(fig.axes)) if i not in empty)
        legend = [t.get_text() for t in fig.axes[first].get_legend().get_texts()]
        assert legend == (["SMC", "desired"] if number == 24 else ["SMC"]), number


def test_draw_figure_is_the_figure_reproduce_writes(results, figure_dir):
    """Library users had figures 10-26 only as files: ``draw_figure`` returns each as a
    matplotlib Figure whose plain ``savefig`` writes make_figures' PNG at the same dpi,
    byte for byte (one figure of each kind), by number or by name."""
    from pkmctl.report import draw_figure, figure_names

    outdir, _ = figure_dir  # (made at dpi 60)
    for number in (10, 17, 20, 23):  # tracking, error, box, force
        buf = io.BytesIO()
        draw_figure(results, number, dpi=60).savefig(buf, format="png")
        assert buf.getvalue() == (outdir / f"fig{number}.png").read_bytes(), number
    names = figure_names()
    assert sorted(names.values()) == list(range(10, 27))
    for name in ("z", "alpha error", "beta box", "tau4", "q3"):
        assert draw_figure(results, name)._suptitle.get_text().startswith(f"Fig. {names[name]} ")
    assert draw_figure(results, "  Alpha   ERROR ")._suptitle.get_text().startswith("Fig. 18 ")
    assert draw_figure(results, np.int64(12))._suptitle.get_text().startswith("Fig. 12 ")
    assert draw_figure(results, 10).get_dpi() == 110  # reproduce's


def test_result_plot_shows_the_runs_own_series():
    """``Result.plot`` draws one run: its z and the desired z, in mm, over its own time
    (a short run: nothing thinned), and in the force figure's first panel its forces up
    to 50 ms only."""
    run = pkmctl.simulate("paper", controller="fsmc", duration=0.1)
    top = run.plot("z").axes[0]
    lines = {line.get_label(): line for line in top.get_lines()}
    np.testing.assert_array_equal(lines["FSMC"].get_xdata(), run.t)
    np.testing.assert_allclose(lines["FSMC"].get_ydata(), 1e3 * run.X[:, 0], rtol=1e-15)
    np.testing.assert_allclose(lines["desired"].get_ydata(), 1e3 * run.X_desired[:, 0], rtol=1e-15)
    force = {line.get_label(): line for line in run.plot(24).axes[0].get_lines()}
    window = run.t <= 0.05 + 1e-12
    assert 0 < window.sum() < run.t.size
    np.testing.assert_array_equal(force["FSMC"].get_xdata(), run.t[window])
    np.testing.assert_array_equal(force["FSMC"].get_ydata(), run.tau[window, 1])


def test_draw_figure_gives_each_controller_of_ones_own_a_colour(results):
    """Every name outside the paper's five was drawn in the sixth colour: two controllers
    of a user's were one colour. Each has its own, in lines and boxes; the paper's keep
    theirs."""
    from pkmctl.report import draw_figure

    runs = {"mine": results["smc"], "yours": results["fsmc"], "afsmc": results["afsmc"]}
    top = draw_figure(runs, "z").axes[0]
    color = {line.get_label(): line.get_color() for line in top.get_lines()}
    assert color["AFSMC"] == "C2"
    assert len({color["mine"], color["yours"], color["AFSMC"]}) == 3
    boxes = draw_figure(runs, "z box").axes[0].patches
    assert len({tuple(b.get_facecolor()) for b in boxes}) == 3


@pytest.mark.parametrize(
    ("figure", "runs", "error", "says"),
    [
        ("zz", None, ValueError, "figure = 'zz': a number from 10 to 26 or one of z, alpha"),
        (9, None, ValueError, "figure = 9: a number from 10 to 26"),
        (27, None, ValueError, "figure = 27: a number from 10 to 26"),
        (True, None, TypeError, "figure = True: a number from 10 to 26"),
        (10.0, None, TypeError, "figure = 10.0: a number from 10 to 26"),
        (None, None, TypeError, "figure = None: a number from 10 to 26"),
        ("z", [], TypeError, "results = list: a Result, or a mapping"),
        ("z", {}, ValueError, "results: no known controller"),
        ("z", {"smc": "a run"}, TypeError, "results = dict: a Result, or a mapping"),
    ],
)
def test_draw_figure_refuses_in_one_line(results, figure, runs, error, says):
    from pkmctl.report import draw_figure

    with pytest.raises(error) as info:
        draw_figure(results if runs is None else runs, figure)
    assert str(info.value).startswith(says) and "\n" not in str(info.value)


def test_draw_figure_refuses_a_bad_dpi(results):
    from pkmctl.report import draw_figure

    with pytest.raises(ValueError, match=r"^dpi = 0: must be > 0$"):
        draw_figure(results, "z", dpi=0)
