"""ebad.runfolder: the lock between processes, atomic files, unfinished runs, interrupts."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import scenes
from ebad.cli import main
from ebad.errors import UserError
from ebad.runfolder import RunLock, load_run, write_text_atomic

REPO = Path(__file__).resolve().parents[2]


def _holder(folder: Path) -> subprocess.Popen:
    """Another process that holds the run folder's lock until killed."""
    code = (
        "import sys, time; from ebad.runfolder import RunLock; "
        f"l = RunLock({str(folder)!r}).acquire(); print('locked', flush=True); time.sleep(60)"
    )
    p = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "locked"
    return p


def test_a_second_process_is_refused_naming_the_holder(tmp_path, capsys):
    holder = _holder(tmp_path / "run")
    try:
        with pytest.raises(UserError, match=f"in use by process {holder.pid}"):
            RunLock(tmp_path / "run").acquire()
        rc = main(["reconstruct", str(tmp_path / "nocapture"), "--out", str(tmp_path / "run")])
        assert rc == 2
    finally:
        holder.kill()
        holder.wait()


def test_a_stale_lock_is_taken_over_with_a_message(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / ".lock").write_text(f"{dead.pid} {os.uname().nodename}\n")
    said = []
    with RunLock(tmp_path, say=said.append):
        assert (tmp_path / ".lock").read_text().split()[0] == str(os.getpid())
    assert said and str(dead.pid) in said[0]
    assert not (tmp_path / ".lock").exists()


def test_atomic_text_write_leaves_no_temporary(tmp_path):
    write_text_atomic(tmp_path / "a" / "x.json", "{}\n")
    assert (tmp_path / "a" / "x.json").read_text() == "{}\n"
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["x.json"]


def test_out_that_is_a_file_or_not_writable_is_refused(tmp_path, capsys, monkeypatch):
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["reconstruct", str(tmp_path / "cap"), "--out", str(f)]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    if os.geteuid() == 0:  # root writes anywhere: make the permission check see what a user would
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == ro else real(p, mode))
    assert main(["reconstruct", str(tmp_path / "cap"), "--out", str(ro / "run")]) == 2
    err = capsys.readouterr().err
    assert "not writable" in err and str(ro) in err
    assert not (ro / "run").exists()


def test_an_unfinished_run_is_refused_with_the_resume_command(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.pt").write_bytes(b"x")
    with pytest.raises(UserError, match="unfinished run: resume it with 'ebad reconstruct CAPTURE --out .* --resume'"):
        load_run(run)
    (run / "metrics.json").write_text(json.dumps({"complete": False, "steps": 3}))
    with pytest.raises(UserError, match="unfinished run"):
        load_run(run)


@pytest.mark.slow
def test_sigint_checkpoints_writes_the_run_and_resume_finishes(tmp_path):
    scene = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)
    scenes.write_scene(scene, tmp_path / "scene")
    cap = str(tmp_path / "scene" / "capture")
    run = tmp_path / "run"
    args = [
        sys.executable,
        "-m",
        "ebad",
        "reconstruct",
        cap,
        "--out",
        str(run),
        "--preset",
        "3dgs",
        "--train.iters",
        "100000",
        "--train.checkpoint_every",
        "5",
        "--train.eval_every",
        "0",
    ]
    p = subprocess.Popen(args, cwd=REPO, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not (run / "checkpoints" / "last.pt").exists() and time.time() < deadline:  # training has started
        time.sleep(0.2)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "--resume" in err
    m = json.loads((run / "metrics.json").read_text())
    assert m["complete"] is False and m["stop_reason"] == "interrupted (SIGINT)" and m["steps"] > 0
    assert (run / "checkpoints" / "last.pt").exists() and not (run / ".lock").exists()
    with pytest.raises(UserError, match="unfinished run"):
        load_run(run)
    steps = m["steps"]
    assert (
        main(["reconstruct", cap, "--out", str(run), "--resume", "--train.iters", str(steps + 5), "--no-progress"]) == 0
    )
    m = json.loads((run / "metrics.json").read_text())
    assert m["complete"] is True and m["steps"] == steps + 5 and m["resumed_from"] == steps
    assert load_run(run).step == steps + 5


# what torch's zip writer raises on a full disk: a failed write, or (torch 2.13 on a full tmpfs, measured) the
# end-of-file record found at the wrong position
FULL_DISK_ERRORS = [
    "[enforce fail at inline_container.cc:859] . PytorchStreamWriter failed writing file data/0: file write failed",
    "[enforce fail at inline_container.cc:672] . unexpected pos 64 vs 0",
]


@pytest.mark.parametrize("message", FULL_DISK_ERRORS, ids=["write failed", "unexpected pos"])
def test_a_full_disk_is_one_line_and_leaves_no_complete_looking_run(tmp_path, capsys, monkeypatch, message):
    """A write that fails (torch's zip writer on a full disk) mid-checkpoint: one line naming the
    file, no temporary left behind, no metrics.json (the run is not presented as complete), and
    the previous checkpoint untouched."""
    import torch

    scene = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=3, n_test=1, sensor="ideal")
    scenes.write_scene(scene, tmp_path / "scene")
    cap = str(tmp_path / "scene" / "capture")
    run = tmp_path / "run"
    args = [
        "reconstruct",
        cap,
        "--out",
        str(run),
        "--preset",
        "3dgs",
        "--train.iters",
        "6",
        "--train.checkpoint_every",
        "3",
        "--no-progress",
    ]
    real_save = torch.save
    calls = []

    def failing_save(obj, f, *a, **k):
        calls.append(f)
        if len(calls) == 2:  # the second checkpoint finds the disk full half-way
            Path(f).write_bytes(b"PK\x03\x04partial")
            raise RuntimeError(message)
        return real_save(obj, f, *a, **k)

    monkeypatch.setattr(torch, "save", failing_save)
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "last.pt" in err and "could not write the checkpoint" in err
    assert not (run / "metrics.json").exists()
    assert not [p for p in run.rglob("*") if ".tmp" in p.name]
    assert (run / "checkpoints" / "last.pt").stat().st_size > 1000  # the first checkpoint, whole
    with pytest.raises(UserError, match="unfinished run"):
        load_run(run)


@pytest.mark.slow
def test_a_run_that_learns_nothing_is_flagged(tmp_path, capsys):
    """Every learning rate at 0: the test PSNR ends where it began, and the command says so."""
    scene = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=3, n_test=1, sensor="ideal")
    scenes.write_scene(scene, tmp_path / "scene")
    zero = [f"--train.{k}" for k in ("lr_means", "lr_scales", "lr_quats", "lr_opacities", "lr_colors")]
    args = [
        "reconstruct",
        str(tmp_path / "scene" / "capture"),
        "--out",
        str(tmp_path / "run"),
        "--preset",
        "3dgs",
        "--train.iters",
        "3",
        "--no-progress",
        "--trajectory.anchor_mid",
        "yes",
    ]
    for z in zero:
        args += [z, "0"]
    assert main(args) == 0
    assert "test PSNR did not change" in capsys.readouterr().err


@pytest.mark.slow
def test_resume_with_another_capture_is_refused_and_the_run_kept(tmp_path, capsys):
    a = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1, sensor="ideal")
    b = scenes.make_scene("boxes", size="tiny", seed=1, n_frames=3, n_test=1, sensor="ideal")
    scenes.write_scene(a, tmp_path / "a")
    scenes.write_scene(b, tmp_path / "b")
    run = tmp_path / "run"
    common = ["--out", str(run), "--preset", "3dgs", "--no-progress", "--train.checkpoint_every", "2"]
    assert main(["reconstruct", str(tmp_path / "a" / "capture"), *common, "--train.iters", "4"]) == 0
    before = {p.name: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert main(["reconstruct", str(tmp_path / "b" / "capture"), *common, "--train.iters", "8", "--resume"]) == 2
    err = capsys.readouterr().err
    assert "made from another capture" in err and "4 frames then, 3 now" in err
    # the finished run of capture a is as it was, and still loads as complete
    after = {p.name: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert set(after) - set(before) <= {"config.json"} and after["last.pt"] == before["last.pt"]
    assert load_run(run).step == 4


def test_an_atomic_write_that_fails_leaves_the_old_file_and_no_temporary(tmp_path):
    from scenes._atomic import atomic_path

    target = tmp_path / "x.ply"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="disk full"):
        with atomic_path(target) as tmp:
            assert tmp.parent == tmp_path and tmp.suffix == ".ply" and tmp != target  # the writer sees the suffix
            tmp.write_text("half")
            raise RuntimeError("disk full")
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["x.ply"]
    with atomic_path(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["x.ply"]


def _copy_run(tiny_run, tmp_path: Path) -> Path:
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run.run, run)
    assert load_run(run).metrics.complete is True  # the copy loads
    return run


@pytest.mark.parametrize("value", ['"no"', '"false"', "1", "null", '"true"'])
def test_complete_must_be_the_json_boolean_true(tiny_run, tmp_path, value):
    run = _copy_run(tiny_run, tmp_path)
    doc = json.loads((run / "metrics.json").read_text())
    doc["complete"] = json.loads(value)
    (run / "metrics.json").write_text(json.dumps(doc))
    with pytest.raises(UserError, match=r"metrics\.json"):
        load_run(run)


def test_a_ply_without_gaussians_is_an_error_naming_it(tiny_run, tmp_path):
    from ebad.io import read_ply, write_ply

    run = _copy_run(tiny_run, tmp_path)
    empty = {k: v[:0] for k, v in read_ply(run / "point_cloud.ply").items()}
    write_ply(run / "point_cloud.ply", empty)
    with pytest.raises(UserError, match=r"point_cloud\.ply: holds no Gaussians"):
        load_run(run)
    (run / "point_cloud.ply").write_bytes(b"not a ply")
    with pytest.raises(UserError, match=r"point_cloud\.ply"):
        load_run(run)


def _snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    return {
        p.relative_to(folder).as_posix(): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.mark.parametrize("damage", ["missing", "invalid JSON"])
def test_resume_without_a_readable_config_touches_nothing(tiny_run, tmp_path, capsys, damage):
    """A finished run whose config.json is gone or unreadable: --resume is one line naming config.json, before
    anything is deleted or rewritten (it used to delete metrics.json, write the ebad preset's config and crash)."""
    run = tmp_path / "run"
    common = [str(tiny_run.capture), "--out", str(run), "--no-progress", "--train.eval_every", "0"]
    assert main(["reconstruct", *common, "--train.iters", "2"]) == 0  # a finished run with its checkpoint
    assert (run / "checkpoints" / "last.pt").is_file() and load_run(run).metrics.complete
    cfg = run / "config.json"
    if damage == "missing":
        cfg.unlink()
    else:
        cfg.write_text("{")
    before = _snapshot(run)
    capsys.readouterr()
    assert main(["reconstruct", *common, "--resume", "--train.iters", "40"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "config.json" in err
    assert _snapshot(run) == before  # every file unchanged, none added or removed
