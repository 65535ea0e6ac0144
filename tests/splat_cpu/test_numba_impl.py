"""The fast path does not depend on the caller's OpenMP environment (issue 8).

Two properties make `import torch; import splat_cpu` fast without OMP_WAIT_POLICY=PASSIVE
(measured by `python -m benchmarks.rasterize --omp-check`): numba runs on its own
"workqueue" pool unless the user chose a layer or OpenMP's threads sleep (then on "omp"),
and no torch kernel (hence no torch OpenMP region) runs inside `rasterize` or its backward.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torch.profiler import ProfilerActivity, profile

from splat_cpu._numba_impl import rasterize_numba

from .conftest import make_scene

REPO = Path(__file__).resolve().parents[2]

# torch ops that only wrap, view or allocate memory: no arithmetic, no parallel region
_NO_KERNEL_OPS = {
    "aten::as_strided",
    "aten::detach",
    "aten::empty",
    "aten::empty_like",
    "aten::empty_strided",
    "aten::lift_fresh",
    "aten::resolve_conj",
    "aten::resolve_neg",
    "aten::select",
    "aten::to",
    "aten::alias",
    "aten::view",
    "aten::_to_copy_no_op",
    "detach",
}

_LAYER_PROBE = """
import numba, torch, splat_cpu
from tests.splat_cpu.conftest import make_scene
splat_cpu.rasterize(*make_scene(20, d=1, n_cams=1, dtype=torch.float32), 37, 29)
print(numba.threading_layer())
"""


def _layer_in_subprocess(env_update: dict[str, str]) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_THREADING_LAYER", "OMP_WAIT_POLICY")}
    env.update(env_update)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    out = subprocess.run(
        [sys.executable, "-c", _LAYER_PROBE], capture_output=True, text=True, env=env, cwd=REPO, timeout=300
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()[-1]


def test_workqueue_layer_without_the_caller_setting_anything():
    assert _layer_in_subprocess({}) == "workqueue"


def test_a_layer_the_user_chose_is_kept():
    assert _layer_in_subprocess({"NUMBA_THREADING_LAYER": "omp"}) == "omp"
    assert _layer_in_subprocess({"NUMBA_THREADING_LAYER": "workqueue", "OMP_WAIT_POLICY": "PASSIVE"}) == "workqueue"


def test_omp_layer_when_openmp_threads_sleep():
    # OMP_WAIT_POLICY=PASSIVE before torch loads (as `import ebad` first and the ebad command set
    # it): OpenMP's idle threads sleep, so its layer is safe, and it wakes its threads sooner
    assert _layer_in_subprocess({"OMP_WAIT_POLICY": "PASSIVE"}) == "omp"
    assert _layer_in_subprocess({"OMP_WAIT_POLICY": "active"}) == "workqueue"


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_no_torch_kernel_runs_inside_forward_and_backward(dtype):
    inputs = [t.requires_grad_() for t in make_scene(200, d=3, n_cams=2, dtype=dtype)[:6]]
    ks = make_scene(200, d=3, n_cams=2, dtype=dtype)[6]
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=dtype, requires_grad=True)
    cot = (torch.ones(2, 29, 37, 3, dtype=dtype), torch.ones(2, 29, 37, 1, dtype=dtype))
    rasterize_numba(*inputs, ks, 37, 29, background=bg)  # compile / load first
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        img, alpha, _ = rasterize_numba(*inputs, ks, 37, 29, background=bg)
        torch.autograd.backward((img, alpha), cot)
    ops = {e.key for e in prof.key_averages() if e.key.startswith("aten::") or e.key == "detach"}
    assert ops, "the profiler saw no torch op at all: the check would be vacuous"
    assert ops <= _NO_KERNEL_OPS, f"torch kernels inside the fast path: {sorted(ops - _NO_KERNEL_OPS)}"
    assert all(x.grad is not None for x in inputs)
