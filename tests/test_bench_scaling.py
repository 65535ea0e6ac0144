"""benchmarks.scaling's memory figures: a child's peak RSS is its own, not its parent's."""

import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks import scaling

ROOT = Path(__file__).resolve().parents[1]

_CHILD = """
import json, resource
from benchmarks.scaling import peak_rss_mb
print(json.dumps([peak_rss_mb(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024]))
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="VmHWM needs Linux's /proc")
def test_child_peak_rss_is_not_the_parents():
    # The scaling benchmark's parent simulated the capture (6 GB at 40 views) before it started the
    # child that reconstructs it; Linux carries ``ru_maxrss`` over fork + exec, so the child reported
    # the parent's 6368 MB as its own. Here the parent holds 400 MB (touched) while it starts a child
    # that allocates nothing: the child's ``ru_maxrss`` shows the 400 MB, its ``peak_rss_mb`` must not
    # (it imports numpy and the benchmarks' preamble: well under 300 MB).
    held = np.ones(50_000_000)  # 400 MB, every page touched
    out = subprocess.run(
        [sys.executable, "-c", _CHILD], capture_output=True, text=True, cwd=ROOT, env={"PYTHONPATH": str(ROOT)}
    )
    assert out.returncode == 0, out.stderr
    peak, inherited = json.loads(out.stdout.strip().splitlines()[-1])
    assert held.nbytes / 2**20 <= inherited  # what the benchmark reported before
    assert peak < 300, peak


def test_memory_mb_sees_an_allocation():
    rss0, hwm0 = scaling.memory_mb()
    if rss0 is None:
        pytest.skip("no /proc")
    held = np.ones(25_000_000)  # 200 MB, touched
    rss1, hwm1 = scaling.memory_mb()
    assert rss1 - rss0 >= 0.9 * held.nbytes / 2**20
    assert hwm1 >= rss1
    del held
    assert scaling.reset_peak()
    rss2, hwm2 = scaling.memory_mb()
    assert hwm2 < hwm1 - 150  # the peak starts again from the resident set


def test_first_step_takes_the_loop_start_from_the_loops_own_clock():
    """The training loop started ``stats.time`` before its first step ended: work after the loop (the
    final scoring) must not move it, as ``wall - train_seconds`` did (a negative first step)."""
    import time
    from types import SimpleNamespace

    t0 = time.perf_counter() - 10.0
    fs = scaling.FirstStep(t0)
    fs.on_step(None, SimpleNamespace(time=2.5))
    assert fs.at is not None and fs.train_start is not None
    assert 10.0 <= fs.at < 11.0
    assert abs((fs.at - fs.train_start) - 2.5) < 1e-9
    fs.on_step(None, SimpleNamespace(time=99.0))  # later steps change nothing
    assert abs((fs.at - fs.train_start) - 2.5) < 1e-9


def test_budgets_that_are_not_seconds_are_refused_before_anything_is_simulated(capsys):
    """``--seconds 850,3600`` is a run per budget; a budget that is not a positive number is one line."""
    import pytest

    for bad in ("abc", "850,x", "0", "900,-1", ","):
        with pytest.raises(SystemExit) as e:
            scaling.main(["--seconds", bad, "--views", "4", "--events", "0"])
        assert e.value.code == 2
        assert "--seconds" in capsys.readouterr().err


def test_the_kernels_are_ready_before_any_capture_is_simulated(monkeypatch):
    """The parent fills numba's cache first, so no child compiles inside its budget (a stale cache once cost
    a child 8.3 s of its 300)."""
    import pytest

    import ebad.run
    import scenes

    order = []

    class Stop(Exception):
        pass

    def make_scene(*a, **kw):
        order.append("simulate")
        raise Stop

    monkeypatch.setattr(ebad.run, "warm_up", lambda kinds: order.append(("warm_up", list(kinds))) or 0.0)
    monkeypatch.setattr(scenes, "make_scene", make_scene)
    with pytest.raises(Stop):
        scaling.main(["--views", "4", "--events", "0", "--size", "tiny"])
    assert order == [("warm_up", ["grey"]), "simulate"]


def test_budget_curves_give_each_budgets_gain_over_the_one_before():
    """Runs of one (views, preset, poses) at several budgets, listed out of order, with a failed run and a run of
    another preset alone: one line, budgets in order, each gain against the budget before it."""

    def row(seconds, psnr, wall, preset="ebad"):
        return {
            "views": 30,
            "preset": preset,
            "poses": "noisy",
            "seconds": seconds,
            "final_psnr_refined": psnr,
            "wall_seconds": wall,
        }

    rows = [
        row(3600, 25.10, 3650),
        row(840, 24.76, 871),
        row(1800, 25.00, 1830),
        row(840, 24.2, 854, "bad"),
        {"views": 30, "preset": "ebad", "poses": "noisy", "seconds": 7200, "error": ["killed"]},
    ]
    assert scaling.budget_curves(rows) == [
        " 30 views   ebad noisy by budget: 840 s 24.76 dB, 1800 s 25.00 dB (+0.24 for 2.1x the wall time), "
        "3600 s 25.10 dB (+0.10 for 2.0x the wall time)"
    ]
    assert scaling.budget_curves(rows[1:2] + rows[3:]) == []  # one budget a method: no curve


@pytest.mark.parametrize("keep", [False, True])
def test_the_captures_folder_goes_with_the_run_unless_given(monkeypatch, tmp_path, keep):
    """Without ``--workdir`` the captures (340 MB for 40 views at 346x260) are written to a temporary folder that
    the run removes, whether it ends or fails (nineteen earlier runs had left 1.7 GB in /tmp); ``--workdir`` keeps
    them."""
    import tempfile

    import ebad.run
    import scenes

    work = tmp_path / "work"

    class Stop(Exception):
        pass

    def make_scene(*a, **kw):
        (work / "davis_4").mkdir(parents=True)
        (work / "davis_4" / "frames.npz").write_bytes(b"0" * 1000)
        raise Stop

    def mkdtemp(prefix="", **kw):
        work.mkdir()
        return str(work)

    monkeypatch.setattr(ebad.run, "warm_up", lambda kinds: 0.0)
    monkeypatch.setattr(scenes, "make_scene", make_scene)
    monkeypatch.setattr(tempfile, "mkdtemp", mkdtemp)
    argv = ["--views", "4", "--events", "0"] + (["--workdir", str(work)] if keep else [])
    with pytest.raises(Stop):
        scaling.main(argv)
    assert (work / "davis_4" / "frames.npz").exists() == keep
    assert work.exists() == keep


def test_a_benchmark_stopped_midway_keeps_the_runs_it_finished(monkeypatch, tmp_path, capsys):
    """Each finished run goes to NAME.json at once, marked partial (as benchmarks.ablation does): Ctrl-C in the
    second hour-long run of a benchmark kept nothing before. A benchmark that ends writes it without the mark."""
    import benchmarks._common
    import ebad.run
    import scenes

    monkeypatch.setattr(benchmarks._common, "RESULTS", tmp_path)
    monkeypatch.setattr(scaling, "RESULTS", tmp_path)
    monkeypatch.setattr(ebad.run, "warm_up", lambda kinds: 0.0)
    monkeypatch.setattr(scenes, "make_scene", lambda *a, **kw: None)
    monkeypatch.setattr(scenes, "write_scene", lambda sc, d: None)
    calls = []

    def child(args):
        calls.append(json.loads(args[1])["seconds"])
        if len(calls) == 2:
            raise KeyboardInterrupt
        return {"error": ["a finished run"]}

    monkeypatch.setattr(scaling, "_subprocess", child)
    argv = ["--views", "4", "--events", "0", "--presets", "ebad", "--poses", "noisy", "--seconds", "10,20,30"]
    with pytest.raises(KeyboardInterrupt):
        scaling.main([*argv, "--name", "stopped"])
    partial = json.loads((tmp_path / "stopped.json").read_text())
    assert partial["partial"] is True
    assert [r["seconds"] for r in partial["runs"]["4"]] == [10.0]
    assert f"the runs it finished are in {tmp_path / 'stopped.json'} (marked partial)" in capsys.readouterr().err

    monkeypatch.setattr(scaling, "_subprocess", lambda args: {"error": ["a finished run"]})
    assert scaling.main([*argv, "--name", "stopped"]) == 0
    done = json.loads((tmp_path / "stopped.json").read_text())
    assert [r["seconds"] for r in done["runs"]["4"]] == [10.0, 20.0, 30.0] and "partial" not in done


def test_each_mark_keeps_every_test_views_scores_and_refinement_steps():
    """A 40-view mark's refined mean fell 1.85 dB while the unrefined one moved 0.25 (cap 120k, 1824 s): whether
    one view's refinement stopped short could not be told from the means. Each view's PSNR before and after, and its
    steps, are kept by name; a view scored only before refinement keeps None after."""
    from ebad.scoring import ViewScores

    res = {
        "test": ViewScores(
            19.0,
            0.5,
            3,
            {"t0": {"psnr": 20.0, "ssim": 0.6}, "t1": {"psnr": 18.0, "ssim": 0.4}, "t2": {"psnr": 17.5, "ssim": 0.3}},
        ),
        "test_refined": ViewScores(
            23.0, 0.8, 2, {"t1": {"psnr": 21.0, "ssim": 0.7}, "t0": {"psnr": 25.0, "ssim": 0.9}}
        ),
        "refine_steps": {"t0": 100, "t1": 37},
    }
    assert scaling.view_scores(res) == {
        "t0": {"psnr": 20.0, "psnr_refined": 25.0, "refine_steps": 100},
        "t1": {"psnr": 18.0, "psnr_refined": 21.0, "refine_steps": 37},
        "t2": {"psnr": 17.5, "psnr_refined": None, "refine_steps": None},
    }
    assert scaling.view_scores({}) == {}  # no test view with an image


def test_a_budget_run_several_times_gives_each_run_and_their_mean_and_spread():
    """``--seconds 300,300,300`` runs one setting three times: the spread of a time-budgeted run (its schedule follows
    the clock, so two runs differ) was only ever seen across commits. Each run's figure, their mean ± std (population),
    and the next budget's gain over that mean, not over one of the runs."""

    def row(seconds, psnr, wall):
        return {
            "views": 10,
            "preset": "ebad",
            "poses": "noisy",
            "seconds": seconds,
            "final_psnr_refined": psnr,
            "wall_seconds": wall,
        }

    rows = [row(300, 26.20, 322), row(1200, 26.90, 1222), row(300, 26.41, 318), row(300, 26.23, 323)]
    assert scaling.budget_curves(rows) == [
        " 10 views   ebad noisy by budget: 300 s x3 26.20, 26.41, 26.23: 26.28 ± 0.09 dB, "
        "1200 s 26.90 dB (+0.62 for 3.8x the wall time)"
    ]
    assert scaling.budget_curves([rows[0], rows[2]]) == [  # repeats alone: a line too
        " 10 views   ebad noisy by budget: 300 s x2 26.20, 26.41: 26.30 ± 0.11 dB"
    ]


def test_refine_also_takes_step_caps_or_says_which_argument_is_wrong(capsys):
    for bad in ("abc", "300,x", "0", "300,-5"):
        with pytest.raises(SystemExit) as e:
            scaling.main(["--refine-also", bad, "--views", "4", "--events", "0"])
        assert e.value.code == 2
        assert "--refine-also" in capsys.readouterr().err


def test_each_mark_is_refined_again_under_every_other_step_cap(monkeypatch):
    """Three of eight views spent all 100 refinement steps at the 20-view run's end: whether the cap moves the figure
    needs the same snapshot refined with more. ``refine_also`` evaluates each mark again per cap; the mark's own
    figure stays the ``refine_iters`` one, and a spec without ``refine_also`` (older JSON) adds nothing."""
    from types import SimpleNamespace

    import ebad.evaluate
    import ebad.run
    import scenes
    from ebad.scoring import ViewScores

    calls = []

    def evaluate(run, capture, refine=False, refine_iters=300):
        calls.append((run.params["mark"], refine_iters))
        gain = {100: 3.0, 300: 3.5}[refine_iters] + run.params["mark"]
        return {
            "test": ViewScores(20.0, 0.5, 1, {"t0": {"psnr": 20.0, "ssim": 0.5}}),
            "test_refined": ViewScores(20.0 + gain, 0.8, 1, {"t0": {"psnr": 20.0 + gain, "ssim": 0.8}}),
            "refine_steps": {"t0": min(refine_iters, 140)},
        }

    def reconstruct(capture, cfg, callbacks=()):
        snaps = callbacks[1]
        for mark in (0, 1):
            snaps.taken.append(
                {
                    "seconds": 5.0 * (mark + 1),
                    "step": 10 * (mark + 1),
                    "gaussians": 3,
                    "params": {"mark": mark},
                    "trajectories": None,
                    "response": None,
                }
            )
        prepare = SimpleNamespace(sharp_frames=0, sharp_reason="none")
        metrics = SimpleNamespace(steps=20, train_seconds=10.0, prepare_seconds=1.0, gaussians=3, prepare=prepare)
        return SimpleNamespace(params=None, trajectories=None, response=None, metrics=metrics)

    capture = SimpleNamespace(events=type("Ev", (list,), {"nbytes": lambda self: 90})([0] * 10))
    monkeypatch.setattr(scenes, "load", lambda path: capture)
    monkeypatch.setattr(ebad.run, "reconstruct", reconstruct)
    monkeypatch.setattr(ebad.evaluate, "evaluate", evaluate)
    spec = {"capture": "c", "views": 4, "preset": "ebad", "poses": "noisy", "seconds": 10.0, "marks": 2}
    out = scaling.run_child({**spec, "refine_iters": 100, "refine_also": [300]})
    assert calls == [(0, 100), (0, 300), (1, 100), (1, 300)]
    assert [p["test_psnr_refined"] for p in out["points"]] == [23.0, 24.0]
    assert [p["refined_at"]["300"]["test_psnr_refined"] for p in out["points"]] == [23.5, 24.5]
    assert out["points"][1]["refined_at"]["300"]["views"] == {
        "t0": {"psnr": 20.0, "psnr_refined": 24.5, "refine_steps": 140}
    }
    assert out["points"][1]["views"]["t0"]["refine_steps"] == 100
    calls.clear()
    old = scaling.run_child({**spec, "refine_iters": 100})
    assert calls == [(0, 100), (1, 100)] and all("refined_at" not in p for p in old["points"])


def test_a_child_run_in_process_leaves_the_progress_loggers_as_it_found_them(monkeypatch):
    """``run_child`` sets ``ebad.progress`` and ``scenes.colmap`` to INFO with its timeline as a handler. Left there,
    every later ``say`` in the process went to the timeline rather than stderr (``ebad eval``'s refinement lines went
    missing in the test run after this module's, in CI), and a failed run must not leave it either."""
    import scenes

    loggers = [logging.getLogger(name) for name in scaling.PHASE_LOGGERS]
    before = [(lg.level, lg.handlers[:]) for lg in loggers]

    def load(path):
        assert all(lg.level == logging.INFO and len(lg.handlers) == len(b[1]) + 1 for lg, b in zip(loggers, before))
        raise FileNotFoundError(path)

    monkeypatch.setattr(scenes, "load", load)
    with pytest.raises(FileNotFoundError):
        scaling.run_child({"capture": "c", "preset": "ebad", "poses": "noisy", "seconds": 1.0, "marks": 1})
    assert [(lg.level, lg.handlers) for lg in loggers] == before
