"""The SSIM of the training losses: the fused numba kernels against torch implementations, in one run.

    python -m benchmarks.ssim [--quick] [--repeats 20] [--name NAME]

Forward + backward (gradient to the render; the target needs none, as in training) of the
mean SSIM, 7-tap window, at the shapes of a 346x260 training step: one image (L_blur's mean
render) and five (L_EDI at V = 5 views), grey and colour, at full and half resolution. Three
implementations, each timed in this process, alternately, median of ``--repeats`` calls after
a warm-up:

- ``fused loss``: ``ebad.losses.l1_ssim`` with the SSIM weight 1, what the training losses call
  (``ebad.kernels._numba_ssim``: one kernel pass over both separable directions that sums the map
  without storing it, one for its adjoint with a constant upstream gradient);
- ``fused``: ``ebad.losses.ssim_map`` (the same kernels, writing the map, and the adjoint of a
  map of upstream gradients), what the metrics call;
- ``grouped conv``: the previous implementation, kept here as the baseline: one grouped
  ``conv2d`` of the five moments with the 7x7 window in torch (autograd for the backward);
- ``kornia``: ``kornia.metrics.ssim``, the reference the fused passes are tested against.

Also the largest difference of the fused map from kornia's and of the fused loss from kornia's
1 - mean SSIM (float32). Prints a table, writes
``benchmarks/results/ssim[_quick].json`` (or ``NAME.json``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from ._common import write_json

SHAPES = [(1, 260, 346, 1), (5, 260, 346, 1), (5, 260, 346, 3), (1, 130, 173, 1), (5, 130, 173, 1)]
QUICK_SHAPES = [(1, 60, 80, 1), (5, 60, 80, 1)]


def grouped_conv_ssim(a, b, window: int = 7):
    """The previous ``ssim_map``: the five moments in one grouped conv2d (torch autograd)."""
    import torch

    from ebad.kernels._numba_ssim import C1, C2, DEN_EPS, gauss_taps

    a = a.permute(0, 3, 1, 2)
    b = b.permute(0, 3, 1, 2)
    D = a.shape[1]
    g = torch.as_tensor(gauss_taps(window), dtype=a.dtype)
    k = g[:, None] * g[None, :]
    x = torch.cat([a, b, a * a, b * b, a * b], 1)
    pad = window // 2
    x = torch.nn.functional.pad(x, (pad, pad, pad, pad), mode="reflect")
    m = torch.nn.functional.conv2d(x, k.expand(5 * D, 1, window, window), groups=5 * D)
    mu1, mu2, s11, s22, s12 = m.split(D, 1)
    mu11, mu22, mu12 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    num = (2 * mu12 + C1) * (2 * (s12 - mu12) + C2)
    den = (mu11 + mu22 + C1) * ((s11 - mu11) + (s22 - mu22) + C2)
    return (num / (den + DEN_EPS)).permute(0, 2, 3, 1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.ssim", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small shapes, 5 repeats")
    ap.add_argument("--repeats", type=int, default=None, help="timed calls per implementation and shape (default 20)")
    ap.add_argument("--name", default=None, help="results file benchmarks/results/NAME.json (default ssim[_quick])")
    args = ap.parse_args(argv)
    import torch

    from ebad.losses import l1_ssim, ssim_map, ssim_map_kornia

    def fused_loss(a, b, window):  # 1 - mean SSIM (the timing takes the mean of this scalar)
        return l1_ssim(a, b, 1.0, window)

    impls = {"fused loss": fused_loss, "fused": ssim_map, "grouped conv": grouped_conv_ssim, "kornia": ssim_map_kornia}
    shapes = QUICK_SHAPES if args.quick else SHAPES
    repeats = args.repeats or (5 if args.quick else 20)
    rows = []
    print(f"mean SSIM forward + backward, 7-tap window, float32, median of {repeats} calls (ms)")
    print(
        f"{'shape [B, H, W, D]':>20s} "
        + " ".join(f"{k:>13s}" for k in impls)
        + f" {'conv / fused loss':>17s} {'kornia / fused loss':>19s} {'max |fused - kornia|':>20s}"
    )
    for shape in shapes:
        g = torch.Generator().manual_seed(0)
        a = torch.rand(shape, generator=g).requires_grad_()
        b = (a.detach() + 0.2 * torch.rand(shape, generator=g)).clamp(0, 1)
        times = {k: [] for k in impls}

        def call(fn, a=a, b=b):
            a.grad = None
            t0 = time.perf_counter()
            fn(a, b, 7).mean().backward()
            return 1e3 * (time.perf_counter() - t0)

        for fn in impls.values():  # warm-up (numba's first call compiles or loads its cache)
            call(fn)
        for _ in range(repeats):  # alternately, so a change of load hits every implementation
            for k, fn in impls.items():
                times[k].append(call(fn))
        med = {k: statistics.median(v) for k, v in times.items()}
        with torch.no_grad():
            err = float((ssim_map(a, b) - ssim_map_kornia(a, b)).abs().max())
            loss_err = abs(float(l1_ssim(a, b, 1.0, 7)) - float(1 - ssim_map_kornia(a, b).mean()))
        rows.append(
            {
                "shape": list(shape),
                "median_ms": med,
                "conv_over_fused_loss": med["grouped conv"] / med["fused loss"],
                "kornia_over_fused_loss": med["kornia"] / med["fused loss"],
                "max_abs_diff_vs_kornia": err,
                "loss_abs_diff_vs_kornia": loss_err,
            }
        )
        print(
            f"{str(list(shape)):>20s} "
            + " ".join(f"{med[k]:13.2f}" for k in impls)
            + f" {rows[-1]['conv_over_fused_loss']:17.2f} {rows[-1]['kornia_over_fused_loss']:19.2f} {err:20.1e}",
            flush=True,
        )
    write_json(
        args.name or ("ssim_quick" if args.quick else "ssim"),
        {
            "repeats": repeats,
            "window": 7,
            "dtype": "float32",
            "rows": rows,
            "torch_threads": torch.get_num_threads(),
            "argv": sys.argv[1:] if argv is None else list(argv),
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
