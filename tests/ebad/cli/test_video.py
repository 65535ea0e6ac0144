"""``ebad video``: files read back (frame count, size), camera paths, the exposure video."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from PIL import Image

import scenes
from ebad.cli import main
from ebad.cli.video import (
    PANEL_GAP,
    PANEL_LABELS,
    camera_path_fps,
    exposure_frames,
    exposure_instants,
    read_camera_path,
    render_views,
    write_camera_path,
)
from ebad.errors import EbadError
from ebad.runfolder import load_run

N_INSTANTS = 21  # odd: the middle instant is u = 0.5


def _gif(path):
    with Image.open(path) as im:
        return im.n_frames, im.size


def test_video_gif_and_png_folder_along_the_smooth_path(tiny_run, tmp_path, capsys):
    gif = tmp_path / "fly.gif"
    assert main(["video", str(tiny_run.run), "--out", str(gif), "--frames", "7", "--no-progress"]) == 0
    assert _gif(gif) == (7, (64, 48))
    assert "7 frames 64x48" in capsys.readouterr().out
    folder = tmp_path / "fly_png"
    assert main(["video", str(tiny_run.run), "--out", str(folder), "--frames", "5", "--no-progress"]) == 0
    pngs = sorted(folder.glob("frame_*.png"))
    assert len(pngs) == 5
    with Image.open(pngs[0]) as im:
        assert im.size == (64, 48)


def test_video_mp4_reads_back(tiny_run, tmp_path):
    ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="the 'video' extra (imageio-ffmpeg) is not installed")
    mp4 = tmp_path / "fly.mp4"
    assert main(["video", str(tiny_run.run), "--out", str(mp4), "--frames", "9", "--fps", "12", "--no-progress"]) == 0
    gen = ffmpeg.read_frames(str(mp4))
    meta = next(gen)
    frames = [np.frombuffer(f, np.uint8) for f in gen]
    assert tuple(meta["size"]) == (64, 48) and meta["fps"] == pytest.approx(12)
    assert len(frames) == 9 and frames[0].size == 64 * 48 * 3


def test_mp4_without_imageio_ffmpeg_names_the_install(tiny_run, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails as if not installed
    assert main(["video", str(tiny_run.run), "--out", str(tmp_path / "v.mp4"), "--frames", "2", "--no-progress"]) == 2
    assert "pip install imageio-ffmpeg" in capsys.readouterr().err


def test_camera_path_roundtrip_and_render(tiny_run, tmp_path):
    run = load_run(tiny_run.run)
    mid = run.trajectories.mid_poses().numpy().astype(np.float64)
    path = write_camera_path(tmp_path / "camera_path.json", mid, run.K, run.width, run.height)
    c2w, K, W, H = read_camera_path(path)
    np.testing.assert_allclose(c2w, mid, atol=1e-12)
    assert (W, H) == (run.width, run.height)
    np.testing.assert_allclose(K[0], run.K, rtol=1e-6)  # tiny scene: square pixels, centred
    # the path's views are the training cameras: renders equal the mid-exposure renders
    np.testing.assert_allclose(render_views(run, c2w, K, W, H, progress=False), run.deblurred_frames(), atol=1e-5)
    gif = tmp_path / "cp.gif"
    assert main(["video", str(tiny_run.run), "--out", str(gif), "--camera-path", str(path), "--no-progress"]) == 0
    assert _gif(gif) == (len(mid), (64, 48))


def test_camera_path_errors_name_file_and_field(tmp_path):
    p = tmp_path / "cp.json"
    p.write_text('{"render_width": 8, "render_height": 6, "camera_path": [{"camera_to_world": [1, 0]}]}')
    with pytest.raises(EbadError, match=r"cp\.json.*camera_path\[0\]"):
        read_camera_path(p)
    p.write_text('{"render_width": 8, "camera_path": []}')
    with pytest.raises(EbadError, match="render_height"):
        read_camera_path(p)
    cam = {"camera_to_world": np.eye(4).ravel().tolist(), "fov": 190.12345678901234}
    p.write_text(json.dumps({"render_width": 8, "render_height": 6, "camera_path": [cam]}))
    with pytest.raises(EbadError, match=r"fov 190\.123 outside") as err:
        read_camera_path(p)
    assert "190.12345678" not in str(err.value)  # no 16-digit floats in messages


def test_exposure_video_panels(tiny_run, tmp_path):
    run = load_run(tiny_run.run)
    cap = scenes.load(tiny_run.capture)
    W = run.width
    for f, name in enumerate(run.names):
        panels, what = exposure_frames(run, name, N_INSTANTS, cap, progress=False)
        assert panels.shape == (N_INSTANTS, run.height, 3 * W + 2 * PANEL_GAP, 1) and "EDI" in what
        blurry = panels[:, :, :W]
        edi_lat = panels[:, :, W + PANEL_GAP : 2 * W + PANEL_GAP]
        renders = panels[:, :, 2 * W + 2 * PANEL_GAP :]
        np.testing.assert_allclose(blurry[0], cap.frames[cap.names.index(name)], atol=1e-6)
        # the middle instant is mid-exposure: the render is the frame's sharp mid-exposure render
        np.testing.assert_allclose(renders[N_INSTANTS // 2], run.deblurred_frames()[f], atol=1e-5)
        # EDI's latents average back to the blurry frame over the exposure (its defining
        # relation, up to the midpoint rule over N instants); they differ from it instant by instant
        assert np.abs(edi_lat.mean(0) - blurry[0]).mean() < 0.1 * np.abs(edi_lat - blurry).mean()
    u, t = exposure_instants(run.exposures[0], 5)
    assert np.all((t > run.exposures[0, 0]) & (t < run.exposures[0, 1])) and u[2] == 0.5


def test_exposure_video_cli_and_errors(tiny_run, tmp_path, capsys):
    gif = tmp_path / "exp.gif"
    name = load_run(tiny_run.run).names[1]
    argv = [
        "video",
        str(tiny_run.run),
        "--out",
        str(gif),
        "--exposure",
        name,
        "--instants",
        "6",
        "--capture",
        str(tiny_run.capture),
        "--no-progress",
    ]
    assert main(argv) == 0
    n, (w, h) = _gif(gif)
    assert (n, w) == (6, 3 * 64 + 2 * PANEL_GAP) and h - 48 == 14  # a label strip above the panels
    assert "10 fps" in capsys.readouterr().out
    assert main(["video", str(tiny_run.run), "--out", str(gif), "--exposure", "nope", "--no-progress"]) == 2
    assert "--exposure 'nope'" in capsys.readouterr().err
    assert main(["video", str(tiny_run.run), "--out", str(tmp_path / "v.avi"), "--frames", "2", "--no-progress"]) == 2
    assert "v.avi" in capsys.readouterr().err


def _files(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def test_a_failed_mp4_write_is_exit_2_naming_the_file_and_leaves_nothing(tiny_run, tmp_path, monkeypatch, capsys):
    """ffmpeg's failures (the output is a folder, an unwritable place, a full disk) were "4 frames -> out" with
    exit 0 and a truncated mp4; now one line naming the file, exit 2, and no file claimed complete."""
    ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="the 'video' extra (imageio-ffmpeg) is not installed")
    video = ["video", str(tiny_run.run), "--frames", "4", "--no-progress", "--out"]
    (tmp_path / "dir.mp4").mkdir()  # a folder where the file goes
    capsys.readouterr()
    assert main([*video, str(tmp_path / "dir.mp4")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "dir.mp4" in err and "folder" in err
    assert _files(tmp_path) == ["dir.mp4"]
    (tmp_path / "file").write_text("x")  # a place nothing can be written under (root ignores permissions)
    assert main([*video, str(tmp_path / "file" / "v.mp4")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "v.mp4" in err
    real = ffmpeg.write_frames

    def failing(path, size, **kw):  # ffmpeg exits at once, as on a full disk: imageio-ffmpeg does not notice
        return real(path, size, **{**kw, "codec": "no_such_codec"})

    monkeypatch.setattr(ffmpeg, "write_frames", failing)
    assert main([*video, str(tmp_path / "v.mp4")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(tmp_path / "v.mp4") in err and "ffmpeg" in err
    assert _files(tmp_path) == ["dir.mp4", "file"]  # no v.mp4, no temporary
    (tmp_path / "dir.mp4").rmdir()
    from ebad.cli.video import write_video

    with pytest.raises(EbadError, match="v.gif"):  # a gif into a folder that is a file: the same one line
        write_video(tmp_path / "file" / "v.gif", np.zeros((2, 4, 4, 1), np.uint8), 10.0)


def test_exposure_video_panels_are_labelled(tiny_run, tmp_path):
    """The three panels carry their labels (dark text pixels in a white strip above each panel); the
    frames below the strip are the panels as they were."""
    run = load_run(tiny_run.run)
    name = run.names[1]
    out = tmp_path / "exp"
    argv = ["video", str(tiny_run.run), "--out", str(out), "--exposure", name, "--instants", "2"]
    assert main([*argv, "--capture", str(tiny_run.capture), "--no-progress"]) == 0
    with Image.open(out / "frame_00000.png") as im:
        got = np.asarray(im)
    W, H = run.width, run.height
    strip = got[: got.shape[0] - H]
    assert strip.shape[0] == 14 and strip.shape[1] == 3 * W + 2 * PANEL_GAP
    for i in range(len(PANEL_LABELS)):
        cols = strip[:, i * (W + PANEL_GAP) : i * (W + PANEL_GAP) + W]
        dark = int((cols < 100).sum())
        assert 10 < dark < 0.5 * cols.size  # text, not a blank or a black strip
        assert (cols == 255).mean() > 0.5  # on white
    from ebad.export import to_display8

    panels, _ = exposure_frames(run, name, 2, scenes.load(tiny_run.capture), progress=False)
    np.testing.assert_array_equal(got[strip.shape[0] :], to_display8(panels[0])[..., 0])


def test_camera_path_fps_sets_the_video_rate(tiny_run, tmp_path, capsys):
    run = load_run(tiny_run.run)
    mid = run.trajectories.mid_poses().numpy().astype(np.float64)
    path = write_camera_path(tmp_path / "cp.json", mid[:3], run.K, run.width, run.height, fps=5.0)
    assert camera_path_fps(path) == 5.0
    gif = tmp_path / "cp.gif"
    argv = ["video", str(tiny_run.run), "--out", str(gif), "--camera-path", str(path), "--no-progress"]
    assert main(argv) == 0
    assert "at 5 fps" in capsys.readouterr().out
    with Image.open(gif) as im:
        assert im.info["duration"] == 200  # ms per frame
    assert main([*argv, "--fps", "20"]) == 0  # --fps wins
    assert "at 20 fps" in capsys.readouterr().out
    doc = json.loads(path.read_text())
    doc.pop("fps")
    path.write_text(json.dumps(doc))
    assert camera_path_fps(path) is None
    doc["fps"] = -1
    path.write_text(json.dumps(doc))
    with pytest.raises(EbadError, match=r"cp\.json.*'fps'.*-1"):
        camera_path_fps(path)
