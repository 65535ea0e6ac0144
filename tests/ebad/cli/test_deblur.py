"""``ebad deblur``: inputs, faults (issue 13, rows 2, 6, 7, 9) and what it says when c cannot be trusted."""

import json
from pathlib import Path

import numpy as np
import pytest

from ebad.cli import main

SHARED = Path(__file__).parents[3].parent / "shared" / "data"
STREET = SHARED / "davis346_street" / "davis346_street.aedat4"
NI = SHARED / "ni_joint_blur"
needs_street = pytest.mark.skipif(not STREET.exists(), reason=f"real data not found: {STREET}")
needs_ni = pytest.mark.skipif(not NI.exists(), reason=f"real data not found: {NI}")


@pytest.fixture()
def frame_and_events(tmp_path):
    """A 40x56 moving-texture frame as an 8-bit PNG and its events as .npz (sensor declared)."""
    from PIL import Image

    import edi

    s = edi.moving_texture(num_frames=1, seed=0, c=0.2)
    png = tmp_path / "frame.png"
    Image.fromarray(np.round(s.frames[0, ..., 0] * 255).astype(np.uint8)).save(png)
    ev = s.events
    npz = tmp_path / "ev.npz"
    np.savez(npz, t=ev.t, x=ev.x, y=ev.y, p=ev.p, width=ev.width, height=ev.height)
    return png, npz, s


def test_frame_image_with_events(tmp_path, frame_and_events, capsys):
    png, npz, s = frame_and_events
    ex = [str(v) for v in s.exposures[0]]
    assert main(["deblur", str(png), "--events", str(npz), "--exposure", *ex, "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "time unit us (relative integer timestamps" in out and "c 0." in out
    assert out.strip().splitlines()[-1].endswith("1 frame(s) written to " + str(tmp_path / "o"))  # nothing flagged
    meta = json.loads((tmp_path / "o" / "c.json").read_text())
    frame = meta["frames"][0]
    assert frame["c_at_bracket_end"] is False and frame["c_reliable"] is True
    assert frame["num_events"] == len(s.events[: s.events.window(*s.exposures[0])[1]])


def test_sensor_size_mismatch_is_an_error(tmp_path, frame_and_events, capsys):
    png, npz, s = frame_and_events
    z = dict(np.load(npz))
    z["width"], z["height"] = 346, 260
    np.savez(tmp_path / "big.npz", **z)
    assert main(["deblur", str(png), "--events", str(tmp_path / "big.npz"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "declares a 346x260 (WxH) sensor but 56x40 was given" in err and len(err.strip().splitlines()) == 1


def test_no_exposure_with_events_stops_with_the_times_and_unit(tmp_path, frame_and_events, capsys):
    png, npz, s = frame_and_events
    rc = main(["deblur", str(png), "--events", str(npz), "--exposure", "10", "10.04", "--out", str(tmp_path / "o")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "no exposure has events: exposures from 10.000000 to 10.040000 s" in err
    assert "events from 0.000350 to 0.040000 s" in err and "time unit assumed us" in err and "--t-unit" in err
    assert not (tmp_path / "o" / "sharp").exists()


def test_epoch_nanoseconds_are_read_as_nanoseconds(tmp_path, frame_and_events, capsys):
    """Issue 13, row 2: epoch-ns timestamps spanning 40 ms were read as microseconds."""
    png, npz, s = frame_and_events
    z = dict(np.load(npz))
    z["t"] = z["t"].astype(np.int64) * 1000 + 1_700_000_000_000_000_000  # stored int32 (edi.EventStream)
    np.savez(tmp_path / "ns.npz", **z)
    rc = main(["deblur", str(png), "--events", str(tmp_path / "ns.npz"), "--out", str(tmp_path / "o")])
    out = capsys.readouterr().out
    assert rc == 0 and "time unit ns (integer timestamps from 1.7e+18: ns since 1970" in out
    assert "exposure from the events' span: 0.000000 .. 0.0396" in out  # 39.65 ms, not 39.65 s
    rc = main(
        ["deblur", str(png), "--events", str(tmp_path / "ns.npz"), "--t-unit", "us", "--out", str(tmp_path / "o2")]
    )
    assert rc == 0 and "time unit us (given)" in capsys.readouterr().out
    # relative times spanning 1e9 to 1e10 are refused unless the unit is given
    z["t"] = (z["t"] - z["t"][0]) * 100
    np.savez(tmp_path / "amb.npz", **z)
    rc = main(["deblur", str(png), "--events", str(tmp_path / "amb.npz"), "--out", str(tmp_path / "o3")])
    assert rc == 2 and "cannot tell the time unit" in capsys.readouterr().err


def test_medi_needs_two_frames(tmp_path, frame_and_events, capsys):
    png, npz, s = frame_and_events
    assert main(["deblur", str(png), "--events", str(npz), "--medi", "--out", str(tmp_path / "o")]) == 2
    assert "--medi needs two or more frames" in capsys.readouterr().err


def test_bad_c(tmp_path, frame_and_events, capsys):
    png, npz, s = frame_and_events
    for bad in ("-1", "0.2,0.3,0.4", "x", "nan"):
        assert main(["deblur", str(png), "--events", str(npz), "--c", bad, "--out", str(tmp_path / "o")]) == 2
        assert "--c must be" in capsys.readouterr().err


@pytest.mark.parametrize("flag,value", [("--max-frames", "-3"), ("--times", "-1")])
def test_negative_counts_are_refused_naming_the_option(tmp_path, frame_and_events, capsys, flag, value):
    png, npz, s = frame_and_events
    assert main(["deblur", str(png), "--events", str(npz), flag, value, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{flag} must be >= 0" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


@needs_street
def test_truncated_aedat4_is_one_line(tmp_path, capsys):
    pytest.importorskip("aedat")
    cut = tmp_path / "cut.aedat4"
    cut.write_bytes(STREET.read_bytes()[:200_000])
    assert main(["deblur", str(cut), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "cut.aedat4: truncated or corrupt AEDAT4 file" in err and len(err.strip().splitlines()) == 1


@needs_street
def test_medi_on_the_street(tmp_path, capsys):
    out = tmp_path / "m"
    assert main(["deblur", str(STREET), "--out", str(out), "--max-frames", "6", "--medi"]) == 0
    text = capsys.readouterr().out
    assert "1 of 6 blurry exposure(s) have no events" in text and "mEDI" in text
    meta = json.loads((out / "c.json").read_text())
    assert meta["medi"] is True and len(list((out / "sharp").iterdir())) == 6


@needs_ni
def test_estimate_without_interior_minimum_says_what_to_do(tmp_path, capsys):
    rc = main(["deblur", str(NI / "keyboard.png"), "--events", str(NI / "keyboard.mat"), "--out", str(tmp_path / "k")])
    assert rc == 0
    out = capsys.readouterr().out
    assert "warning: keyboard" in out and "no interior minimum" in out and "--c C" in out
    last = out.strip().splitlines()[-1]  # the summary does not present the frame as deblurred
    assert "1 frame(s) written" in last and "1 of them with an unreliable c" in last and "(keyboard)" in last
    meta = json.loads((tmp_path / "k" / "c.json").read_text())
    assert meta["frames"][0]["c_at_bracket_end"] is True and meta["frames"][0]["c_reliable"] is False


@needs_ni
def test_cli_deblur_frame_and_mat_events(tmp_path):
    import json

    from skimage import io

    from ebad.cli import main

    out = tmp_path / "out"
    rc = main(
        [
            "deblur",
            str(NI / "toy.png"),
            "--events",
            str(NI / "toy.mat"),
            "--out",
            str(out),
            "--c",
            "0.25",
            "--times",
            "3",
        ]
    )
    assert rc == 0
    sharp = io.imread(out / "sharp" / "toy.png")
    assert sharp.shape == (260, 346) and sharp.dtype == np.uint16  # 16-bit by default
    rc = main(
        [
            "deblur",
            str(NI / "toy.png"),
            "--events",
            str(NI / "toy.mat"),
            "--out",
            str(tmp_path / "o8"),
            "--c",
            "0.25",
            "--bits",
            "8",
        ]
    )
    sharp8 = io.imread(tmp_path / "o8" / "sharp" / "toy.png")
    assert rc == 0 and sharp8.dtype == np.uint8
    assert np.abs(sharp8 / 255.0 - sharp / 65535.0).max() <= 0.5 / 255 + 1e-6  # the same image
    assert io.imread(out / "side_by_side" / "toy.png").shape == (260, 692)
    assert sorted(p.name for p in (out / "instants").iterdir()) == ["toy_00.png", "toy_01.png", "toy_02.png"]
    meta = json.loads((out / "c.json").read_text())
    assert meta["frames"][0]["c_pos"] == 0.25 and meta["frames"][0]["num_events"] == 27594


@needs_street
def test_cli_deblur_aedat4_and_bad_arguments(tmp_path, capsys):
    import json

    from ebad.cli import main

    out = tmp_path / "street"
    assert main(["deblur", str(STREET), "--out", str(out), "--max-frames", "4"]) == 0
    meta = json.loads((out / "c.json").read_text())
    assert len(meta["frames"]) == 4 and meta["frames"][0]["c_pos"] is None  # no events: returned B
    assert len(list((out / "sharp").iterdir())) == 4
    assert main(["deblur", str(STREET), "--out", str(out), "--c", "-1"]) == 2
    assert "--c must be" in capsys.readouterr().err
    assert main(["deblur", str(NI / "toy.png"), "--out", str(out)]) == 2
    assert "needs --events" in capsys.readouterr().err


def test_gamma_linearises_the_frame_and_writes_what_it_used(tmp_path, capsys):
    """A frame recorded through irradiance ** 0.8: --gamma 0.8 deblurs the linearised frame and
    maps the latent back (what edi.deblur(gamma=0.8) gives), and c.json says so."""
    from PIL import Image

    import edi
    from scenes.images import read_image

    s = edi.moving_texture(num_frames=1, seed=0, c=0.2)
    png = tmp_path / "frame.png"
    Image.fromarray(np.round(s.frames[0, ..., 0] ** 0.8 * 255).astype(np.uint8)).save(png)
    npz = tmp_path / "ev.npz"
    ev = s.events
    np.savez(npz, t=ev.t, x=ev.x, y=ev.y, p=ev.p, width=ev.width, height=ev.height)
    ex = [str(v) for v in s.exposures[0]]
    out = tmp_path / "o"
    assert (
        main(
            [
                "deblur",
                str(png),
                "--events",
                str(npz),
                "--exposure",
                *ex,
                "--c",
                "0.2",
                "--gamma",
                "0.8",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    meta = json.loads((out / "c.json").read_text())
    assert meta["gamma"] == 0.8 and meta["gamma_source"] == "given (--gamma)"
    want = edi.deblur(read_image(png, "frame"), s.exposures[0], s.events, c=0.2, gamma=0.8)
    got = read_image(out / "sharp" / "frame.png", "sharp")
    np.testing.assert_allclose(got, want, atol=0.5 / 65535 + 1e-9)
    assert "given (--c); log-irradiance units, frames linearised with gamma 0.8" in capsys.readouterr().out


@pytest.mark.parametrize("bad", ["0", "-1", "x", "nan", "estimate"])
def test_bad_gamma_is_one_line_naming_the_option(tmp_path, frame_and_events, capsys, bad):
    png, npz, s = frame_and_events
    assert main(["deblur", str(png), "--events", str(npz), "--gamma", bad, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "--gamma must be a number" in err and len(err.strip().splitlines()) == 1
