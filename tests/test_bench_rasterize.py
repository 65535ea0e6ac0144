"""benchmarks.rasterize --rounds: the paths alternate; each path's median run and every round's ratio are reported."""

from __future__ import annotations

import argparse

import pytest

from benchmarks import rasterize as bench


def test_rounds_alternate_the_paths_and_report_the_median_run(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    fast_units, base_units = iter([3.0, 2.0, 2.5]), iter([4.0, 2.5, 3.0])

    def fake_run(cfg: dict, timeout: float, policy: str) -> dict:
        path = "base" if cfg.get("root") else "fast"
        calls.append(path)
        units = next(base_units if path == "base" else fast_units)
        return {"fwd_bwd_units": units, "fwd_bwd_ms": 10 * units, "tag": f"{path}{len(calls)}"}

    monkeypatch.setattr(bench, "_run_sub", fake_run)
    args = argparse.Namespace(rounds=3, baseline="/somewhere", timeout=1.0, omp_wait_policy="unset")
    fast, base, pairs = bench._alternate({"n": 1}, args)
    assert calls == ["fast", "base"] * 3
    assert (fast["fwd_bwd_units"], base["fwd_bwd_units"]) == (2.5, 3.0)  # the medians of 3, 2, 2.5 and 4, 2.5, 3
    assert [p["units_ratio"] for p in pairs] == [0.75, 0.8, 2.5 / 3.0]
    assert [p["ms_ratio"] for p in pairs] == pytest.approx([0.75, 0.8, 2.5 / 3.0])


def test_one_round_without_a_baseline_runs_the_fast_path_once(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bench, "_run_sub", lambda cfg, timeout, policy: {"skipped": "took more than 1 s"})
    args = argparse.Namespace(rounds=1, baseline=None, timeout=1.0, omp_wait_policy="unset")
    fast, base, pairs = bench._alternate({"n": 1}, args)
    assert fast == {"skipped": "took more than 1 s"} and "skipped" in base and pairs == []


def test_name_writes_the_json_under_that_name(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.setattr(bench, "RESULTS", tmp_path)
    monkeypatch.setattr(bench, "_run_sub", lambda cfg, timeout, policy: {"skipped": "took more than 1 s"})
    assert bench.main(["--target", "--no-reference", "--name", "rasterize_r7_run1"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["rasterize_r7_run1.json"]


def test_a_baseline_root_imports_that_checkouts_splat_cpu_under_the_same_threading(tmp_path) -> None:
    """benchmarks._common imports this checkout's splat_cpu (ebad.threads) and sets its threads up: --baseline
    must still time the root's splat_cpu, and hand it that set-up (the state of `_omp`)."""
    import subprocess
    import sys
    from pathlib import Path

    (tmp_path / "splat_cpu").mkdir()
    (tmp_path / "splat_cpu" / "__init__.py").write_text("")
    (tmp_path / "splat_cpu" / "_omp.py").write_text("_noted: list = []\n_chosen: list = []\n")
    repo = Path(bench.__file__).resolve().parents[1]
    code = (
        "import sys; from benchmarks import rasterize as b; setup = sys.modules['splat_cpu._omp']; "
        "state = (setup._noted[:], setup._chosen[:]); assert state[1], state; "
        f"print(b.import_splat_cpu({str(tmp_path)!r}).__file__); omp = sys.modules['splat_cpu._omp']; "
        "print(omp.__file__, (omp._noted, omp._chosen) == state)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    init, omp, same_state = out.stdout.split()
    assert Path(init) == tmp_path / "splat_cpu" / "__init__.py"
    assert Path(omp) == tmp_path / "splat_cpu" / "_omp.py" and same_state == "True"
