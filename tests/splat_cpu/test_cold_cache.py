"""A kernel compiled in its own process against the same kernel loaded by a later process from numba's cache.

Issue 32: the 11-step determinism run differs in the last float32 bits between a first run on a cold numba cache and
later runs (which agree with one another). The cause is in the tile compositing kernels, `parallel=True` with
fast-math reassociation: numba compiles a prange loop's body (the parfor gufunc) as a library of its own, optimises
it and loads it into the process, then links a copy of it into the kernel's library, which is optimised a second
time. The cache keeps that second copy, while the process that compiled it calls the first one (both define one
symbol, and the process resolves it to the copy loaded first). Optimised twice, the reassociated arithmetic rounds
differently: without `reassoc` `forward_tiles` agrees cold and warm (at 1.6 times its CPU time), without
`contract` it still differs. `backward_tiles` differs as well; the other kernels of a training step give the same
bits cold and warm. Until a fix that costs no speed, this is a strict xfail: the day
cold and warm agree it fails, and README's and `TrainConfig.max_seconds`' caveat goes.

The child builds tile lists by hand (no binning, no projection), so that only `forward_tiles` compiles.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CASE = (0, 400, 2, 2, 0.3)  # seed, Gaussians, tiles across and down, highest opacity: the bits differ today

_CHILD = """
import hashlib
import numpy as np
from splat_cpu import _numba_kernels as K

seed, n, tiles_x, tiles_y, op_hi = {case}
r = np.random.default_rng(seed)
w, h, f32 = 16 * tiles_x, 16 * tiles_y, np.float32
means2d = np.stack([r.uniform(0, w, n), r.uniform(0, h, n)], 1)[None].astype(f32)
sa, sc, rho = r.uniform(1.0, 8.0, n), r.uniform(1.0, 8.0, n), r.uniform(-0.8, 0.8, n)
cov = np.stack([sa**2, rho * sa * sc, sc**2], 1)
det = cov[:, 0] * cov[:, 2] - cov[:, 1] ** 2
conics = np.stack([cov[:, 2] / det, -cov[:, 1] / det, cov[:, 0] / det], 1)[None].astype(f32)
opac = r.uniform(0.01, op_hi, n).astype(f32)
colors = r.uniform(0.0, 1.0, (1, n, 1)).astype(f32)
bg = r.uniform(0.0, 1.0, 1).astype(f32)
n_t = tiles_x * tiles_y
per = [np.sort(r.choice(n, size=n // 2, replace=False)) for _ in range(n_t)]  # each tile lists half the Gaussians
gid = np.concatenate(per).astype(np.int32)
tile_start = np.arange(n_t + 1, dtype=np.int64) * (n // 2)
a, b = r.integers(0, 16, (gid.size, 2)), r.integers(0, 16, (gid.size, 2))
lo, hi = np.minimum(a, b), np.maximum(a, b)
rows = np.stack([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]], 1).astype(np.int8)  # random rows of each half tile
img, t, last = np.zeros((1, h, w, 1), f32), np.zeros((1, h, w), f32), np.zeros((1, h, w), np.int32)
K.forward_tiles(means2d, conics, opac, colors, bg, rows, tile_start, gid, w, h, tiles_x, tiles_y, img, t, last)
assert (last >= 0).any()
print(hashlib.sha256(img.tobytes() + t.tobytes() + last.tobytes()).hexdigest())
"""


def _child(cache: Path, hash_seed: str) -> subprocess.Popen:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONHASHSEED=hash_seed)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return subprocess.Popen(
        [sys.executable, "-c", _CHILD.format(case=CASE)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )


def _outputs(proc: subprocess.Popen) -> str:
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err.decode()[-2000:]
    return out.decode()


class _ColdDiffersFromWarm(AssertionError):
    """The known difference (the module's docstring); any other failure fails the test."""


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=_ColdDiffersFromWarm, reason="numba runs the gufunc compiled alone, cold")
def test_forward_tiles_compiled_cold_gives_the_bits_of_the_kernel_loaded_from_the_cache(tmp_path):
    # two cold compiles side by side (empty caches, different set and dict orders), then a warm load of the first
    cold = [_child(tmp_path / f"cache{i}", seed) for i, seed in enumerate(("1", "2"))]
    cold_out = [_outputs(p) for p in cold]
    warm_out = _outputs(_child(tmp_path / "cache0", "3"))
    assert cold_out[0] == cold_out[1]  # cold compiles agree with one another
    if cold_out[0] != warm_out:
        raise _ColdDiffersFromWarm(f"cold:\n{cold_out[0]}warm:\n{warm_out}")
