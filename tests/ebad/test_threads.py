"""torch's OpenMP threads and the rasteriser's: ``ebad.OMP_PASSIVE``, and training with torch on one thread."""
from __future__ import annotations

import os
import subprocess
import sys

PROBE = """
import sys, {first}, {second}
import ebad, torch
import scenes
from ebad.config import preset
from ebad.callbacks import StepHook
from ebad.run import reconstruct
seen = []
cfg = preset("3dgs"); cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 2, False, 0
torch.set_num_threads(2)
reconstruct(scenes.make_scene("boxes", "tiny", n_frames=3, n_test=1).capture, cfg,
            callbacks=[StepHook(lambda step, stats: seen.append(torch.get_num_threads()))])
print(ebad.OMP_PASSIVE, os.environ.get("OMP_WAIT_POLICY"), seen, torch.get_num_threads())
"""


def _probe(first: str, second: str) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", "import os\n" + PROBE.format(first=first, second=second)],
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


def test_importing_ebad_first_makes_torch_threads_sleep_and_trains_single_threaded_and_restores():
    assert _probe("ebad", "torch") == "True PASSIVE [1, 1] 2"


def test_torch_imported_first_without_the_policy_trains_single_threaded_and_restores():
    assert _probe("torch", "ebad") == "False None [1, 1] 2"


def _imports(policy: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if policy is not None:
        env["OMP_WAIT_POLICY"] = policy
    code = ("import sys, ebad, splat_cpu._omp as o\n"
            "print('torch' in sys.modules, ebad.OMP_PASSIVE, o.openmp_threads_sleep(), repr(o.os.environ['OMP_WAIT_POLICY']))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip()


def test_importing_ebad_loads_no_torch_and_reads_the_policy_as_the_rasteriser_does():
    # one reader (splat_cpu._omp) for ebad.OMP_PASSIVE and for the rasteriser's threading layer
    assert _imports(None) == "False True True 'PASSIVE'"
    assert _imports(" passive ") == "False True True ' passive '"
    assert _imports("ACTIVE") == "False False False 'ACTIVE'"
