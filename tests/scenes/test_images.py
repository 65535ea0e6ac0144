"""scenes.images: the one image reader/writer; 16-bit PNGs of every filter type, from other tools."""

import struct
import zlib

import numpy as np
import png
import pytest
from PIL import Image

from scenes import CaptureError
from scenes.images import quantize, read_image, write_image

SHAPES = [(5, 7, 1), (6, 4, 3)]


def _rand(shape, seed):
    return np.random.default_rng(seed).uniform(0, 1, shape).astype(np.float32)


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def _filtered_png16(ints: np.ndarray, filter_type: int) -> bytes:  # ints [H, W, D] uint16
    """A reference PNG encoder that filters every row with ``filter_type`` (PNG spec 9.2):
    the kind of file libpng-based tools write and a filter-0-only decoder cannot read."""
    h, w, d = ints.shape
    rows = ints.astype(">u2").reshape(h, -1).view(np.uint8).astype(np.int64)  # [H, W*D*2] bytes
    bpp = 2 * d
    out = []
    prev = np.zeros(rows.shape[1], np.int64)
    for r in rows:
        left = np.concatenate([np.zeros(bpp, np.int64), r[:-bpp]])
        upleft = np.concatenate([np.zeros(bpp, np.int64), prev[:-bpp]])
        pred = {0: 0, 1: left, 2: prev, 3: (left + prev) // 2, 4: _paeth(left, prev, upleft)}[filter_type]
        out.append(bytes([filter_type]) + ((r - pred) % 256).astype(np.uint8).tobytes())
        prev = r
    colour = 0 if d == 1 else 2
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, colour, 0, 0, 0))
        + _chunk(b"IDAT", zlib.compress(b"".join(out)))
        + _chunk(b"IEND", b"")
    )


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("bits", [8, 16])
def test_write_read_round_trip_at_each_depth(tmp_path, shape, bits):
    for seed in range(3):
        img = quantize(_rand(shape, seed), bits)
        out = write_image(tmp_path / f"a{seed}", img, bits=bits)
        assert out.suffix == ".png"
        back = read_image(out)
        assert back.dtype == np.float32 and back.shape == shape
        np.testing.assert_array_equal(back, img)


@pytest.mark.parametrize("shape", SHAPES)
def test_lossless_mode_picks_png8_png16_or_npy(tmp_path, shape):
    for bits, suffix in ((8, ".png"), (16, ".png"), (None, ".npy")):
        img = _rand(shape, 1) if bits is None else quantize(_rand(shape, 1), bits)
        out = write_image(tmp_path / f"x{bits}", img)
        assert out.suffix == suffix
        np.testing.assert_array_equal(read_image(out), img)
    with open(tmp_path / "x16.png", "rb") as fh:
        assert fh.read(25)[24] == 16


def test_explicit_bits_quantise_and_clip(tmp_path):
    img = np.array([[[-0.5], [0.5], [2.0]]], np.float32)
    np.testing.assert_array_equal(
        read_image(write_image(tmp_path / "q", img, bits=8))[0, :, 0],
        np.array([0, 128, 255], np.float32) / np.float32(255),
    )


@pytest.mark.parametrize("filter_type", [0, 1, 2, 3, 4])
@pytest.mark.parametrize("d", [1, 3])
def test_sixteen_bit_png_of_every_filter_type_reads_back(tmp_path, filter_type, d):
    ints = np.random.default_rng(filter_type).integers(0, 65536, (4, 5, d)).astype(np.uint16)
    path = tmp_path / "f.png"
    path.write_bytes(_filtered_png16(ints, filter_type))
    np.testing.assert_array_equal(read_image(path), ints.astype(np.float32) / np.float32(65535))


@pytest.mark.parametrize("interlace", [False, True])
def test_sixteen_bit_colour_png_written_by_pypng_reads_back(tmp_path, interlace):
    ints = np.random.default_rng(3).integers(0, 65536, (9, 11, 3)).astype(np.uint16)
    with open(tmp_path / "c.png", "wb") as fh:
        png.Writer(11, 9, greyscale=False, bitdepth=16, interlace=interlace).write(fh, ints.reshape(9, -1))
    np.testing.assert_array_equal(read_image(tmp_path / "c.png"), ints.astype(np.float32) / np.float32(65535))


def test_sixteen_bit_rgba_drops_alpha(tmp_path):
    ints = np.random.default_rng(4).integers(0, 65536, (3, 4, 4)).astype(np.uint16)
    with open(tmp_path / "a.png", "wb") as fh:
        png.Writer(4, 3, greyscale=False, alpha=True, bitdepth=16).write(fh, ints.reshape(3, -1))
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), ints[..., :3].astype(np.float32) / np.float32(65535))


def test_files_we_write_open_in_pillow_with_the_same_values(tmp_path):
    grey16 = quantize(_rand((5, 6, 1), 0), 16)
    with Image.open(write_image(tmp_path / "g16", grey16, bits=16)) as im:
        assert im.mode.startswith("I;16")
        np.testing.assert_array_equal(np.asarray(im), np.round(grey16[..., 0] * 65535).astype(np.uint16))
    rgb8 = quantize(_rand((5, 6, 3), 1), 8)
    with Image.open(write_image(tmp_path / "c8", rgb8, bits=8)) as im:
        assert im.mode == "RGB"
        np.testing.assert_array_equal(np.asarray(im), np.round(rgb8 * 255).astype(np.uint8))


def test_pillow_written_images_read_back(tmp_path):
    a = np.random.default_rng(5).integers(0, 256, (6, 7, 3)).astype(np.uint8)
    Image.fromarray(a).save(tmp_path / "p.png")
    Image.fromarray(a[..., 0]).save(tmp_path / "g.png")
    Image.fromarray(a).convert("P").save(tmp_path / "pal.png")
    np.testing.assert_array_equal(read_image(tmp_path / "p.png"), a.astype(np.float32) / np.float32(255))
    np.testing.assert_array_equal(read_image(tmp_path / "g.png"), a[..., :1].astype(np.float32) / np.float32(255))
    pal = np.asarray(Image.open(tmp_path / "pal.png").convert("RGB")).astype(np.float32) / np.float32(255)
    np.testing.assert_array_equal(read_image(tmp_path / "pal.png"), pal)


@pytest.mark.parametrize("bits", [8, 16])
def test_truncated_png_names_file_and_field(tmp_path, bits):
    out = write_image(tmp_path / "t", quantize(_rand((40, 30, 3), 0), bits), bits=bits)
    data = out.read_bytes()
    out.write_bytes(data[: len(data) // 2])
    with pytest.raises(CaptureError, match=r"t\.png.*frames\[2\]\.file.*unreadable") as e:
        read_image(out, field="frames[2].file")
    assert e.value.file == str(out) and e.value.field == "frames[2].file"


def test_not_an_image_and_missing_file(tmp_path):
    (tmp_path / "x.png").write_bytes(b"not a png at all")
    with pytest.raises(CaptureError, match=r"x\.png.*unreadable"):
        read_image(tmp_path / "x.png")
    with pytest.raises(CaptureError, match=r"nope\.png.*not found"):
        read_image(tmp_path / "nope.png")
    np.save(tmp_path / "bad.npy", np.full((2, 2, 1), 2.0, np.float32))
    with pytest.raises(CaptureError, match=r"bad\.npy.*\[0, 1\]"):
        read_image(tmp_path / "bad.npy")


def test_write_image_refuses_bad_input(tmp_path):
    with pytest.raises(ValueError, match="bits"):
        write_image(tmp_path / "a", np.zeros((2, 2, 1)), bits=12)
    with pytest.raises(ValueError, match="non-finite"):
        write_image(tmp_path / "a", np.full((2, 2, 1), np.nan), bits=16)
    with pytest.raises(ValueError, match=r"\[H, W\]"):
        write_image(tmp_path / "a", np.zeros((2, 2, 2)))
    assert not list(tmp_path.iterdir())


def test_failed_write_leaves_neither_file_nor_temporary(tmp_path, monkeypatch):
    def boom(self, *a, **k):
        raise OSError("No space left on device")

    monkeypatch.setattr(png.Writer, "write_packed", boom)
    with pytest.raises(OSError, match="No space"):
        write_image(tmp_path / "full", quantize(_rand((3, 3, 3), 0), 16), bits=16)
    assert not list(tmp_path.iterdir())
