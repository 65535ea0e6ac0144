"""Benchmark the capture I/O of scenes: PNG codecs, binned events, ROS bag event decoding.

    python -m benchmarks.formats_io [--quick]

Rows (median of repeats, milliseconds; compare ratios within one run, the machine is shared):

- 16-bit RGB PNG at 346x260: ``scenes.images`` write and read (pypng) next to Pillow's read,
  which is faster but wrong (it returns 8 bits: the check column says whether the values
  came back exactly);
- 8-bit RGB PNG at 346x260 through ``read_image`` (Pillow);
- ``events_from_bins`` at E2NeRF real-world size (views x 4 bins x 346x260, signed counts);
- ROS ``dvs_msgs/EventArray`` decoding: numpy from the raw bytes (``decode_event_array``)
  against rosbags' deserialiser (one Python object per event), same messages.

Writes benchmarks/results/formats_io.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "formats_io.json"
W, H = 346, 260


def _median_ms(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def bench_png(tmp: Path, repeats: int) -> list[dict]:
    from PIL import Image

    from scenes.images import quantize, read_image, write_image

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:H, 0:W]
    smooth = (np.sin(x / 23.0)[..., None] * np.cos(y / 17.0)[..., None] * [0.4, 0.3, 0.2] + 0.5).astype(np.float32)
    img16 = quantize(np.clip(smooth + rng.normal(0, 0.01, smooth.shape), 0, 1).astype(np.float32), 16)
    img8 = quantize(smooth, 8)
    p16 = write_image(tmp / "a16", img16, bits=16)
    p8 = write_image(tmp / "a8", img8, bits=8)
    pil16 = np.asarray(Image.open(p16))
    rows = [
        {
            "case": "16-bit RGB PNG write (pypng)",
            "ms": _median_ms(lambda: write_image(tmp / "w16", img16, bits=16), repeats),
            "exact": bool(np.array_equal(read_image(tmp / "w16.png"), img16)),
        },
        {
            "case": "16-bit RGB PNG read (read_image, pypng)",
            "ms": _median_ms(lambda: read_image(p16), repeats),
            "exact": bool(np.array_equal(read_image(p16), img16)),
        },
        {
            "case": "16-bit RGB PNG read (Pillow)",
            "ms": _median_ms(lambda: np.asarray(Image.open(p16)), repeats),
            "exact": bool(pil16.dtype == np.uint16 and np.array_equal(pil16 / 65535.0, img16)),
            "note": f"Pillow returns {pil16.dtype} mode {Image.open(p16).mode}",
        },
        {
            "case": "8-bit RGB PNG read (read_image, Pillow)",
            "ms": _median_ms(lambda: read_image(p8), repeats),
            "exact": bool(np.array_equal(read_image(p8), img8)),
        },
    ]
    return rows


def bench_bins(views: int, repeats: int) -> list[dict]:
    from scenes.e2nerf import events_from_bins, nominal_exposures

    rng = np.random.default_rng(1)
    mag = rng.poisson(0.6, (views, 4, H * W))
    counts = (mag * rng.choice([-1, 1], mag.shape)).astype(np.int32)
    exps = nominal_exposures(views, 4)
    n = int(np.abs(counts).sum())
    ms = _median_ms(lambda: events_from_bins(counts, exps, W, H), repeats)
    return [
        {
            "case": f"events_from_bins {views} views x 4 bins x {W}x{H}",
            "ms": ms,
            "events": n,
            "M_events_per_s": n / ms / 1e3,
        }
    ]


def bench_rosbag(tmp: Path, messages: int, per_message: int, repeats: int) -> list[dict]:
    from rosbags.rosbag1 import Reader, Writer

    from scenes.rosbag import decode_event_array, dvs_typestore

    store = dvs_typestore()
    Event, EventArray = store.types["dvs_msgs/msg/Event"], store.types["dvs_msgs/msg/EventArray"]
    Time, Header = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    rng = np.random.default_rng(2)
    path = tmp / "ev.bag"
    with Writer(path) as writer:
        conn = writer.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=store)
        for k in range(messages):
            t = 1_600_000_000 + k
            evs = [
                Event(
                    x=int(rng.integers(W)),
                    y=int(rng.integers(H)),
                    ts=Time(sec=t, nanosec=1000 * j),
                    polarity=bool(j % 2),
                )
                for j in range(per_message)
            ]
            msg = EventArray(
                header=Header(seq=k, stamp=Time(sec=t, nanosec=0), frame_id=""), height=H, width=W, events=evs
            )
            writer.write(conn, t * 1_000_000_000, store.serialize_ros1(msg, conn.msgtype))
    with Reader(path) as reader:
        raws = [bytes(raw) for _, _, raw in reader.messages()]

    def numpy_decode():
        return np.concatenate([decode_event_array(r)[0] for r in raws])

    def rosbags_decode():
        return [store.deserialize_ros1(r, "dvs_msgs/msg/EventArray") for r in raws]

    a = numpy_decode()
    b = rosbags_decode()
    same = bool(
        np.array_equal(a["x"], [e.x for m in b for e in m.events])
        and np.array_equal(a["nsec"], [e.ts.nanosec for m in b for e in m.events])
    )
    n = messages * per_message
    ms_np = _median_ms(numpy_decode, repeats)
    ms_rb = _median_ms(rosbags_decode, max(1, repeats // 3))
    return [
        {
            "case": f"EventArray decode, numpy ({n} events)",
            "ms": ms_np,
            "M_events_per_s": n / ms_np / 1e3,
            "exact": same,
        },
        {
            "case": f"EventArray decode, rosbags objects ({n} events)",
            "ms": ms_rb,
            "M_events_per_s": n / ms_rb / 1e3,
            "ratio_vs_numpy": ms_rb / ms_np,
        },
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.formats_io", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats and smaller inputs")
    args = ap.parse_args(argv)
    repeats = 3 if args.quick else 9
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        rows = bench_png(tmp, repeats)
        rows += bench_bins(5 if args.quick else 30, repeats)
        rows += bench_rosbag(tmp, 20 if args.quick else 50, 1000 if args.quick else 4000, repeats)
    print(f"{'case':58s} {'ms':>10s}  extra")
    for r in rows:
        extra = ", ".join(
            f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items() if k not in ("case", "ms")
        )
        print(f"{r['case']:58s} {r['ms']:10.2f}  {extra}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    out = RESULTS.with_name("formats_io_quick.json") if args.quick else RESULTS
    out.write_text(json.dumps({"machine": platform.platform(), "quick": args.quick, "rows": rows}, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
