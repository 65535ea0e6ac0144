"""What ``ebad reconstruct --view`` costs the training: steps/s with and without the live viewer.

    python -m benchmarks.live_view [--size tiny] [--iters 200] [--every 5] [--repeats 2]

The same run (``scenes.make_scene("boxes", SIZE)``, preset ``ebad``, seed 0, ``--iters`` steps) is
trained without and with an ``ebad.live_view.LiveView`` (redrawn every ``--every`` seconds, a
websocket client connected and reading every message, as a browser would), ``--repeats`` times
each in the order without, with, with, without, ... (a machine's load drifting cancels out).
Steps/s counts the steps after the first ``WARMUP_STEPS`` (numba's first calls, torch's warm-up,
the viewer's first scene build) by the loop's own clock, which includes the callbacks' time.
Reported: steps/s of each, their ratio (with / without), the viewer's updates and the fraction of
the training time they took in the training thread. Results in
``benchmarks/results/live_view.json``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time

from ._common import seed_all, write_json

WARMUP_STEPS = 20


def _drain(port: int, stop: threading.Event, counts: list[int]) -> None:
    """A websocket client of the viser server reading (and counting the bytes of) every message."""
    import viser
    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    while not stop.is_set():
        try:
            ws = connect(
                f"ws://127.0.0.1:{port}", subprotocols=[Subprotocol(f"viser-v{viser.__version__}")], open_timeout=5
            )
        except OSError:
            time.sleep(0.1)
            continue
        with ws:
            while not stop.is_set():
                try:
                    counts.append(len(ws.recv(timeout=0.5)))
                except TimeoutError:
                    continue
                except Exception:  # the server stopped
                    return
        return


def train_once(scene, iters: int, every: float | None) -> dict:
    """One run; with a LiveView (and a client reading it) when ``every`` is given."""
    from ebad.config import preset
    from ebad.live_view import LiveView
    from ebad.run import reconstruct

    cfg = preset("ebad")
    cfg.train.iters, cfg.train.max_seconds = iters, None
    cfg.train.progress, cfg.train.eval_every, cfg.train.seed = False, 0, 0
    seed_all(0)
    cap = scene.capture
    callbacks: list[LiveView] = []
    received: list[int] = []
    stop = threading.Event()
    client = None
    if every is not None:
        view = LiveView(cap.K, cap.width, cap.height, cap.names, port=0, every=every)
        client = threading.Thread(target=_drain, args=(view.port, stop, received), daemon=True)
        client.start()
        callbacks.append(view)
    try:
        run = reconstruct(cap, cfg, callbacks=callbacks)
    finally:
        stop.set()
        for cb in callbacks:
            cb.close()
        if client is not None:
            client.join(10)
    h = run.history
    seconds = h[-1].time - h[WARMUP_STEPS].time
    out = {"steps": len(h), "seconds": seconds, "steps_per_s": (len(h) - 1 - WARMUP_STEPS) / seconds}
    if callbacks:
        v = callbacks[0]
        out.update(updates=v.updates, view_seconds=v.seconds, view_fraction=v.seconds / h[-1].time)
        out.update(messages=len(received), bytes=sum(received), gaussians=run.num_gaussians)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.live_view", description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="tiny")
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--every", type=float, default=5.0, help="seconds between the viewer's redraws")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--name", default="live_view", help="results file benchmarks/results/NAME.json")
    args = ap.parse_args(argv)
    import scenes

    scene = scenes.make_scene("boxes", size=args.size, seed=0, n_frames=6, n_test=0)
    runs: dict[str, list[dict]] = {"without": [], "with": []}
    for r in range(args.repeats):
        for mode in ("without", "with") if r % 2 == 0 else ("with", "without"):  # ABBA: drifts in load cancel
            res = train_once(scene, args.iters, args.every if mode == "with" else None)
            runs[mode].append(res)
            print(f"repeat {r} {mode:7s} view: {res}", file=sys.stderr)
    off = statistics.mean(x["steps_per_s"] for x in runs["without"])
    on = statistics.mean(x["steps_per_s"] for x in runs["with"])
    summary = {
        "steps_per_s_without": off,
        "steps_per_s_with": on,
        "ratio": on / off,
        "pair_ratios": [a["steps_per_s"] / b["steps_per_s"] for a, b in zip(runs["with"], runs["without"])],
        "view_fraction": statistics.mean(x["view_fraction"] for x in runs["with"]),
    }
    print(
        f"live view, {args.size}, {args.iters} steps, redraw every {args.every} s: {off:.2f} steps/s without, "
        f"{on:.2f} with (ratio {on / off:.3f}); the redraws took {100 * summary['view_fraction']:.2f}% of the "
        "training thread's time"
    )
    print(f"per repeat, with / without: {', '.join(f'{x:.3f}' for x in summary['pair_ratios'])}")
    path = write_json(args.name, {"args": vars(args), "runs": runs, "summary": summary})
    print(f"results: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
