"""ebad.run.warm_up: every parallel kernel a training step runs is compiled before timing starts."""

from __future__ import annotations

import json
import subprocess
import sys

_CODE = """
import json, numba
from ebad import run as trainer
import splat_cpu._numba_kernels, splat_cpu._numba_project, ebad.kernels._numba_ssim, ebad.kernels._numba_event
MODULES = (splat_cpu._numba_kernels, splat_cpu._numba_project, ebad.kernels._numba_ssim, ebad.kernels._numba_event)
def compiled():  # the parallel kernels of the rasteriser, SSIM and L_ev -> how many signatures each has
    return {f"{m.__name__}.{k}": len(v.signatures) for m in MODULES for k, v in vars(m).items()
            if isinstance(v, numba.core.registry.CPUDispatcher) and v.targetoptions.get("parallel")}
before = compiled()
trainer.warm_up()
print(json.dumps([before, compiled()]))
"""


def test_warm_up_compiles_every_parallel_kernel_of_the_rasteriser_ssim_and_event_loss():
    # a fresh interpreter: nothing compiled before, every kernel after (a kernel the ebad preset's
    # steps did not reach would be compiled inside the first timed run that needs it)
    r = subprocess.run([sys.executable, "-c", _CODE], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    before, after = json.loads(r.stdout.strip().splitlines()[-1])
    assert len(after) >= 8, after
    assert all(n == 0 for n in before.values()), before
    missing = [k for k, n in after.items() if n == 0]
    assert not missing, f"not compiled by warm_up: {missing}"
    twice = {k: n for k, n in after.items() if n > 1}  # a grey run: one dtype, one layout per argument
    assert not twice, f"compiled in more than one specialisation: {twice}"
