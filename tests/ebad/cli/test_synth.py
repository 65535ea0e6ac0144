"""``ebad synth``: a synthetic capture and its ground truth written from the command line."""

import json
import typing

from ebad.cli import main
from ebad.cli.synth import Args
from scenes import load
from scenes.synth import SCENES, SENSORS, SIZES

REALISTIC = SENSORS["realistic"]


def test_the_choices_are_the_registries_of_scenes_synth():
    # written out in ebad.cli.synth so that ``ebad --help`` does not import the scene builder
    hints = typing.get_type_hints(Args, include_extras=True)
    literal = {
        name: set(typing.get_args(typing.get_args(hints[name])[0]) if name == "name" else typing.get_args(hints[name]))
        for name in ("name", "size", "sensor")
    }
    assert literal == {"name": set(SCENES), "size": set(SIZES), "sensor": set(SENSORS)}


def test_cli_synth(tmp_path, capsys):
    rc = main(["synth", "spheres", "--out", str(tmp_path / "o"), "--frames", "3", "--test-views", "1", "--seed", "2"])
    assert rc == 0
    cap = load(tmp_path / "o" / "capture")
    assert cap.num_frames == 3 and len(cap.test_views) == 1 and cap.meta["sensor"] == "realistic"
    truth = json.loads((tmp_path / "o" / "gt" / "gt.json").read_text())["truth"]
    assert truth["seed"] == 2 and truth["sensor"]["c_pos"] == REALISTIC.c_pos
    assert "3 frames" in capsys.readouterr().out
    rc = main(["synth", "spheres", "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "out_dir" in capsys.readouterr().err
    rc = main(
        [
            "synth",
            "boxes",
            "--out",
            str(tmp_path / "i"),
            "--frames",
            "2",
            "--test-views",
            "1",
            "--sensor",
            "ideal",
            "--poses",
            "none",
            "--c",
            "0.3",
            "0.25",
        ]
    )
    assert rc == 0
    cap = load(tmp_path / "i" / "capture")
    assert cap.c2w is None and cap.test_views[0].c2w is None and cap.test_views[0].image is not None
    assert cap.pose_trust == "none" and cap.effective_pose_trust == "none"
    assert json.loads((tmp_path / "i" / "gt" / "gt.json").read_text())["truth"]["c"] == [0.3, 0.25]
    assert main(["synth", "boxes", "--out", str(tmp_path / "j"), "--c", "0.1", "0.2", "0.3"]) == 2
    assert "--c" in capsys.readouterr().err


def test_overwrite_replaces_only_a_synthetic_scene(tmp_path, capsys):
    args = ["synth", "boxes", "--size", "tiny", "--frames", "2", "--test-views", "1"]
    assert main(args + ["--out", str(tmp_path / "s")]) == 0
    assert main(args + ["--out", str(tmp_path / "s"), "--overwrite", "--seed", "3"]) == 0  # an ebad synth output
    assert json.loads((tmp_path / "s" / "gt" / "gt.json").read_text())["truth"]["seed"] == 3
    precious = tmp_path / "home"
    (precious / "photos").mkdir(parents=True)
    (precious / "photos" / "a.jpg").write_bytes(b"x")
    capsys.readouterr()
    assert main(args + ["--out", str(precious), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "refusing to overwrite" in err and "photos" in err
    assert (precious / "photos" / "a.jpg").read_bytes() == b"x"  # nothing deleted
    (tmp_path / "f").write_text("x")
    assert main(args + ["--out", str(tmp_path / "f"), "--overwrite"]) == 2
    assert (tmp_path / "f").read_text() == "x"


def test_cli_synth_colour_davis(tmp_path, capsys):
    args = ["synth", "glossy", "--frames", "2", "--test-views", "1", "--cfa", "RGGB"]
    assert main(args + ["--out", str(tmp_path / "d")]) == 0
    assert "RGGB colour filter, demosaiced frames" in capsys.readouterr().out
    cap = load(tmp_path / "d" / "capture")
    assert cap.cfa == "RGGB" and cap.channels == 3 and not cap.raw_mosaic and cap.meta["scene"] == "glossy"
    assert main(args + ["--out", str(tmp_path / "r"), "--raw-frames"]) == 0
    raw = load(tmp_path / "r" / "capture")
    assert raw.cfa == "RGGB" and raw.raw_mosaic and raw.test_views[0].image.shape == (48, 64, 1)
    assert json.loads((tmp_path / "r" / "gt" / "gt.json").read_text())["truth"]["cfa"] == "RGGB"
    capsys.readouterr()
    assert main(["synth", "boxes", "--out", str(tmp_path / "x"), "--raw-frames"]) == 2
    assert "--raw-frames needs --cfa" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert main(["synth", "boxes", "--out", str(tmp_path / "y"), "--cfa", "RGBW"]) == 2  # tyro rejects it
