"""AEDAT4 headers read in Python: DV's colour filter, and damage that would panic the decoder."""

import struct

import numpy as np
import pytest

from edi import CorruptFileError, read_aedat4
from edi.cfa import channel_map
from edi.io import DV_COLOR_FILTER, read_aedat4_info

pytest.importorskip("aedat")
W, H = 6, 4


def dv_xml(color_filter: str | None = None) -> bytes:
    """The info node DV writes: an events and a frames stream, ``colorFilter`` on the events'."""
    cf = "" if color_filter is None else f'<attr key="colorFilter" type="int">{color_filter}</attr>'
    streams = []
    for sid, name, ident in ((0, "events", "EVTS"), (1, "frames", "FRME")):
        extra = cf if ident == "EVTS" else ""
        streams.append(
            f'<node name="{sid}" path="/mainloop/Recorder/outInfo/{sid}/">'
            '<attr key="compression" type="string">NONE</attr>'
            f'<attr key="originalOutputName" type="string">{name}</attr>'
            f'<attr key="typeIdentifier" type="string">{ident}</attr>'
            f'<node name="info" path="/mainloop/Recorder/outInfo/{sid}/info/">'
            f'<attr key="sizeX" type="int">{W}</attr><attr key="sizeY" type="int">{H}</attr>{extra}</node></node>'
        )
    out = f'<node name="outInfo" path="/mainloop/Recorder/outInfo/">{"".join(streams)}</node>'
    return f'<dv version="2.0">{out}</dv>'.encode()


def aedat4_header(xml: bytes) -> bytes:
    """Magic line, size, and the IOHeader flatbuffer (identifier IOHE): table {compression: NONE,
    dataTablePosition: -1, infoNode: xml} at 20, its vtable at 8, the string at 40."""
    vtable = struct.pack("<HHHHH", 10, 20, 4, 8, 16) + b"\0\0"
    table = struct.pack("<iiqI", 20 - 8, 0, -1, 4)
    string = struct.pack("<I", len(xml)) + xml + b"\0"
    fb = struct.pack("<I", 20) + b"IOHE" + vtable + table + string + b"\0" * (-(len(string) + 1) % 4)
    return b"#!AER-DAT4.0\r\n" + struct.pack("<I", len(fb)) + fb


def test_libcaer_names_map_to_our_patterns():
    # libcaer frame_utils.c: colorKeys[filter][(x & 1) << 1 | (y & 1)] for RGBG, GRGB, GBGR, BGRG
    # (DV's colorFilter 0..3), channels R, G, B as 0, 1, 2
    R, G, B = 0, 1, 2
    color_keys = {0: (R, G, G, B), 1: (G, B, R, G), 2: (G, R, B, G), 3: (B, G, G, R)}
    for value, keys in color_keys.items():
        m = channel_map(DV_COLOR_FILTER[value], 4, 4)
        for y in range(4):
            for x in range(4):
                assert m[y, x] == keys[((x & 1) << 1) | (y & 1)], (value, x, y)
    assert DV_COLOR_FILTER == {0: "RGGB", 1: "GRBG", 2: "GBRG", 3: "BGGR"}


@pytest.mark.parametrize("value", [0, 1, 2, 3])
def test_dv_color_filter_is_read_from_the_header(tmp_path, value):
    f = tmp_path / "rec.aedat4"
    f.write_bytes(aedat4_header(dv_xml(str(value))))
    assert read_aedat4_info(f)["0"]["colorFilter"] == str(value)
    rec = read_aedat4(f)
    assert rec.cfa == DV_COLOR_FILTER[value]
    assert (rec.events.width, rec.events.height) == (W, H)


def test_no_color_filter_is_a_grey_sensor(tmp_path):
    f = tmp_path / "rec.aedat4"
    f.write_bytes(aedat4_header(dv_xml(None)))
    assert read_aedat4(f).cfa is None


def test_an_impossible_color_filter_names_the_file(tmp_path):
    f = tmp_path / "rec.aedat4"
    f.write_bytes(aedat4_header(dv_xml("7")))
    with pytest.raises(CorruptFileError, match=r"rec\.aedat4: events stream info colorFilter is '7'"):
        read_aedat4(f)


# offsets into the file: the flatbuffer starts at 18; vtable field 2 (infoNode) at 18 + 8 + 8,
# root offset at 18, the info string's length at 18 + 40
@pytest.mark.parametrize(
    "offset,value",
    [(18 + 16, b"\xf0\x00"), (18, b"\xff\x00\x00\x00"), (18 + 40, b"\xff\xff\x00\x00"), (18 + 4, b"XXXX")],
    ids=["info-field", "root", "string-length", "identifier"],
)
def test_damaged_header_is_one_corrupt_file_error_not_a_decoder_panic(tmp_path, capfd, offset, value):
    data = bytearray(aedat4_header(dv_xml("0")))
    data[offset : offset + len(value)] = value
    f = tmp_path / "bad.aedat4"
    f.write_bytes(bytes(data))
    with pytest.raises(CorruptFileError, match=r"bad\.aedat4: damaged AEDAT4 header") as e:
        read_aedat4(f)
    assert "\n" not in str(e.value)
    assert "panicked" not in capfd.readouterr().err


def test_a_packet_that_panics_the_decoder_is_one_corrupt_file_error(tmp_path, capfd):
    f = tmp_path / "bad.aedat4"
    f.write_bytes(aedat4_header(dv_xml("0")) + struct.pack("<ii", 0, 8) + b"\xff" * 8)  # a packet too short
    with pytest.raises(CorruptFileError, match=r"bad\.aedat4: truncated or corrupt AEDAT4 file .*PanicException") as e:
        read_aedat4(f)
    assert "\n" not in str(e.value)
    err = capfd.readouterr().err
    assert "panicked" not in err and "assertion failed" not in err


def test_decoder_output_that_is_not_a_panic_is_kept(tmp_path, capfd, monkeypatch):
    import os

    import aedat

    class Talkative:  # a decoder that writes to fd 2 and succeeds
        def __init__(self, path):
            os.write(2, b"decoder note\n")

        def id_to_stream(self):
            return {0: {"type": "events", "width": W, "height": H}}

        def __iter__(self):
            ev = np.zeros(2, [("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("on", "?")])
            ev["t"], ev["x"], ev["y"], ev["on"] = [5, 9], [1, 2], [3, 0], [True, False]
            yield {"stream_id": 0, "events": ev}

    monkeypatch.setattr(aedat, "Decoder", Talkative)
    f = tmp_path / "rec.aedat4"
    f.write_bytes(aedat4_header(dv_xml("2")))
    rec = read_aedat4(f)
    assert "decoder note" in capfd.readouterr().err
    assert rec.cfa == "GBRG" and len(rec.events) == 2
