"""Campaign speed (issue 11, point 7), measured side by side in one process.

- the wall time of one campaign on 1 local worker (in this process), on 2 local
  workers, and on a local Dask cluster of 2 worker processes (one thread each), end to
  end and without the workers' start-up;
- the per-run cost outside the compiled loop (the cell's scenario, prepare, building the
  parts, the metrics, the record and the store), as a share of a 1 s run.

``python -m benchmarks.campaign_bench [--quick]`` prints the rows alone; ``pkmctl bench``
runs :func:`bench_campaign` with the rest. Nothing here is a pass/fail test.
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from pathlib import Path

#: The campaign timed: 1 s runs of the paper scenario, two controllers, two payloads.
SPEC = """
name = "bench"
scenario = "paper"
controllers = ["smc", "afsmc"]
seeds = {seeds}
duration = 1.0
metrics = ["rmse", "max_error"]

[factors."payload.mass"]
values = [0.0, 5.0]
"""


def _timed_campaign(spec, out: Path, **kw) -> dict[str, float]:
    from pkmctl.campaign.execute import run_campaign

    stamps: list[tuple[float, int]] = []

    def progress(done, failures, total, rate):
        stamps.append((time.perf_counter(), done))

    t0 = time.perf_counter()
    run = run_campaign(spec, out, progress=progress, **kw)
    wall = time.perf_counter() - t0
    assert run.complete and run.done_now == spec.n_runs
    import numpy as np

    from pkmctl.campaign.store import read_records

    loops = read_records(out).column("kernel_s").to_numpy()
    # a run's loop time: if it grows with the workers, they did not have a core each
    return {"wall_s": wall, "first_result_s": stamps[1][0] - t0,
            "loop_s_per_run": float(np.mean(loops))}  # fmt: skip


def _loops(seconds: float) -> float:
    """1 s SMC runs per second, run back to back for ``seconds`` in this process."""
    import pkmctl

    sc = pkmctl.Scenario.builtin("paper").replace(**{"timing.duration": 1.0})
    pkmctl.simulate(sc, "smc", duration=0.01)  # load the compiled loop
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        pkmctl.simulate(sc, "smc")
        n += 1
    return n / (time.perf_counter() - t0)


def parallel_ceiling(seconds: float = 5.0) -> dict[str, float]:
    """What two processes get on this machine now: plain simulate() loops, one process
    alone, then two at once (their rates summed). On a machine others share, this bounds
    what 2 campaign workers can do; on 2 free cores it is ~2."""
    from pkmctl.sim.workers import spawn_pool

    # the pool campaigns use: its workers die with this process (Ctrl-C ends the bench at
    # once) and its resource tracker stays quiet
    with spawn_pool(2) as pool:
        pool.submit(_loops, 0.1).result()  # start and warm the processes
        one = pool.submit(_loops, seconds).result()
        both = sum(f.result() for f in [pool.submit(_loops, seconds) for _ in range(2)])
    return {"one_runs_per_s": one, "two_runs_per_s": both, "ratio": both / one}


def overhead(seeds: int = 10) -> dict[str, float]:
    """Seconds per run outside the compiled loop, for 1 s runs of the paper scenario
    (SMC) in tasks of the size a campaign makes: the whole task timed (its records give
    its loops' time) plus writing its file, and each step alone. Best of 3."""
    import numpy as np

    from pkmctl.campaign.execute import run_task
    from pkmctl.campaign.spec import CampaignSpec
    from pkmctl.campaign.store import write_task
    from pkmctl.sim.metrics import summary
    from pkmctl.sim.simulate import metrics_only, prepare, resolve_parts, run_prepared

    spec = CampaignSpec.from_toml(SPEC.format(seeds=seeds))
    task = spec.tasks()[0]
    per_task = len(task.runs)
    run_task(spec, task)  # warm: compiled loops loaded
    best: dict[str, float] = {}

    def keep(name: str, dt: float) -> None:
        best[name] = min(best.get(name, np.inf), dt)

    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(3):
            t = time.perf_counter()
            table = run_task(spec, task)
            whole = time.perf_counter() - t
            t = time.perf_counter()
            write_task(Path(tmp), task.index, table)
            store = time.perf_counter() - t
            loops = float(np.sum(table.column("kernel_s").to_numpy()))
            keep("overhead", (whole - loops + store) / per_task)
            keep("kernel", loops / per_task)
            keep("store", store / per_task)
            # each step alone
            t = time.perf_counter()
            sc = spec.scenario(0)
            keep("scenario", (time.perf_counter() - t) / per_task)
            t = time.perf_counter()
            prep = prepare(metrics_only(sc), None)  # as run_task
            keep("prepare", (time.perf_counter() - t) / per_task)
            t = time.perf_counter()
            result = run_prepared(prep, resolve_parts(prep.scenario, "smc"), 0)
            keep("run_outside_kernel", time.perf_counter() - t - result.info["kernel_seconds"])
            t = time.perf_counter()
            summary(result, spec.metrics, source="loop")  # as run_task
            keep("metrics", time.perf_counter() - t)
    out = {f"{k}_s": v for k, v in best.items()}
    out["runs_per_task"] = per_task
    out["overhead_fraction"] = best["overhead"] / (best["overhead"] + best["kernel"])
    return out


def bench_campaign(quick: bool = False) -> dict:
    """The campaign rows of ``pkmctl bench``: 1 vs 2 local workers, local vs Dask, and
    the per-run overhead outside the compiled loop.

    A start-up (spawning the worker processes, importing pkmctl, loading the compiled
    loops) is counted as the extra time to the first result over the one-worker run,
    which runs in this process; ``*_work_s`` is the wall time without it."""
    from pkmctl.campaign.spec import CampaignSpec

    # 160 seeds (640 runs, 8 s on one worker here) is as much work as the 160 runs of 1 s
    # were when issue 11 set the 1.8x target. In lane loops a run takes a third of the
    # time it took then, and in 160 runs (2 s) each worker's first task of each
    # controller, which loads that controller's lane loop, weighed three times as much:
    # 2 workers gave 1.68-1.77x one there (docs/campaigns.md).
    seeds = 4 if quick else 160
    spec = CampaignSpec.from_toml(SPEC.format(seeds=seeds))
    res: dict = {"runs": spec.n_runs, "tasks": len(spec.tasks()), "duration_s": 1.0}
    if hasattr(os, "getloadavg"):
        res["load_before"] = os.getloadavg()
    res["ceiling"] = parallel_ceiling(1.0 if quick else 5.0)
    res["overhead"] = overhead(4 if quick else 10)
    with tempfile.TemporaryDirectory() as tmp:
        res["one_worker"] = _timed_campaign(spec, Path(tmp) / "w1", workers=1)
        res["two_workers"] = _timed_campaign(spec, Path(tmp) / "w2", workers=2)
        try:
            from distributed import LocalCluster
        except ImportError as exc:
            res["dask"] = {"error": f"not run: {exc}"}
        else:
            import dask

            # the workers as docs/campaigns.md says to start them: without the profiler,
            # which samples every thread every 10 ms (a run's loop 4-5 % slower with it)
            with (
                dask.config.set({"distributed.worker.profile.enabled": False}),
                LocalCluster(
                    n_workers=2,
                    threads_per_worker=1,
                    processes=True,
                    host="127.0.0.1",
                    # loopback only: with None the scheduler still serves HTTP on
                    # 0.0.0.0:8787, and each worker on 0.0.0.0 at a random port
                    dashboard_address="127.0.0.1:0",
                    worker_dashboard_address="127.0.0.1:0",
                    # a worker's heartbeat racing the cluster's close logged a 30-line
                    # CommClosedError traceback at ERROR (1 bench in 2, a tester); what
                    # the campaign meets is in its records
                    silence_logs=logging.CRITICAL,
                ) as cluster,
            ):
                res["dask"] = _timed_campaign(
                    spec, Path(tmp) / "dask", scheduler=cluster.scheduler_address
                )
    if hasattr(os, "getloadavg"):
        res["load_after"] = os.getloadavg()
    one = res["one_worker"]
    for key in ("two_workers", "dask"):
        r = res[key]
        if "wall_s" in r:
            r["start_s"] = max(0.0, r["first_result_s"] - one["first_result_s"])
            r["work_s"] = r["wall_s"] - r["start_s"]
    two = res["two_workers"]
    res["speedup"] = one["wall_s"] / two["work_s"]
    res["speedup_end_to_end"] = one["wall_s"] / two["wall_s"]
    if "wall_s" in res["dask"]:
        d = res["dask"]
        res["dask_over_local"] = two["work_s"] / d["work_s"]
        res["dask_over_local_end_to_end"] = two["wall_s"] / d["wall_s"]
    return res


def campaign_rows(c: dict) -> list[tuple[str, str, str, bool | None]]:
    """(measurement, result, target, held or None) rows of :func:`bench_campaign`; short,
    so that a table of ``pkmctl bench`` fits 80 columns."""
    one, two, d = c["one_worker"], c["two_workers"], c["dask"]
    rows = [
        (f"campaign {c['runs']} x 1 s, 1 worker",
         f"{one['wall_s']:.1f} s ({c['tasks']} tasks)", "", None),
        ("  2 local workers", f"{two['wall_s']:.1f} s (start {two['start_s']:.1f} s)", "", None),
        ("  2 workers / 1, start excluded", f"{c['speedup']:.3f} x", "≥ 1.8 x",
         c["speedup"] >= 1.8),
        ("  2 workers / 1, end to end", f"{c['speedup_end_to_end']:.2f} x", "", None),
        ("  2 plain processes / 1 (ceiling)", f"{c['ceiling']['ratio']:.2f} x", "", None),
        ("  a run's loop, 1 / 2 workers",
         f"{1e3 * one['loop_s_per_run']:.0f} / {1e3 * two['loop_s_per_run']:.0f} ms", "", None),
    ]  # fmt: skip
    if "wall_s" in d:
        rows += [
            ("  Dask cluster, 2 workers", f"{d['wall_s']:.1f} s (start {d['start_s']:.1f} s)",
             "", None),
            ("  Dask / local, start excluded", f"{c['dask_over_local']:.3f} x", "≥ 0.9 x",
             c["dask_over_local"] >= 0.9),
            ("  Dask / local, end to end", f"{c['dask_over_local_end_to_end']:.2f} x", "",
             None),
        ]  # fmt: skip
    else:
        rows.append(("  Dask cluster", d.get("error", "not run")[:40], "", None))
    o = c["overhead"]
    ms = {k: 1e3 * v for k, v in o.items() if k.endswith("_s")}
    rows += [
        ("campaign: cost outside the loop",
         f"{ms['overhead_s']:.1f} ms = {100 * o['overhead_fraction']:.1f} %", "< 10 %",
         o["overhead_fraction"] < 0.10),
        (f"  of a 1 s run (loop), {o['runs_per_task']} a task", f"{ms['kernel_s']:.0f} ms",
         "", None),
        ("  scenario + prepare, a run's", f"{ms['scenario_s']:.1f} + {ms['prepare_s']:.1f} ms",
         "", None),
        ("  parts + metrics + store",
         f"{ms['run_outside_kernel_s']:.1f} + {ms['metrics_s']:.1f} + {ms['store_s']:.1f} ms",
         "", None),
    ]  # fmt: skip
    if "load_before" in c:
        fmt = "/".join(["{:.1f}"] * 3)
        rows += [
            ("  load 1/5/15 min, before", fmt.format(*c["load_before"]), "", None),
            ("  load 1/5/15 min, after", fmt.format(*c["load_after"]), "", None),
        ]
    return rows


def main() -> None:
    import argparse
    import platform

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smoke test (4 seeds)")
    args = parser.parse_args()
    res = bench_campaign(quick=args.quick)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}{' (quick)' if args.quick else ''}")  # fmt: skip
    rows = campaign_rows(res)
    head = ("measurement", "result", "target", "held")
    table = [(a, b, t, "" if h is None else ("yes" if h else "NO")) for a, b, t, h in rows]
    widths = [max(len(r[i]) for r in [head, *table]) for i in range(4)]
    for r in [head, *table]:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())


if __name__ == "__main__":
    main()
