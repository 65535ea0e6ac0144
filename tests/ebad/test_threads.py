"""The thread set-up (``ebad.threads.configure``): nothing on import, the policy only before torch,
numba's layer from the policy actually in force, and training with torch on one thread."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

RASTERIZE = """
import torch, splat_cpu
splat_cpu.rasterize(torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.full((1, 3), 0.1),
                    torch.tensor([0.5]), torch.ones(1, 1), torch.eye(4)[None],
                    torch.tensor([[[20.0, 0.0, 8.0], [0.0, 20.0, 8.0], [0.0, 0.0, 1.0]]]), 16, 16)
"""


def _run(code: str, env_update: dict[str, str] | None = None, timeout: float = 300) -> dict:
    """``code`` in a fresh interpreter started without OMP_WAIT_POLICY / NUMBA_THREADING_LAYER
    (plus ``env_update``); it prints one JSON line last."""
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "NUMBA_THREADING_LAYER")}
    env.update(env_update or {})
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout, cwd=REPO
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _setup_then_layer(before: str, env_update: dict[str, str] | None = None) -> dict:
    """Run ``before``, then ``configure()``, then one parallel kernel: what it reported and what ran."""
    code = (
        f"import json, os\n{before}\n"
        "import dataclasses, numba\nfrom ebad.threads import configure\n"
        "setup = dataclasses.asdict(configure())\n"
        f"{RASTERIZE}\n"
        "print(json.dumps({'setup': setup, 'layer': numba.threading_layer(),"
        " 'policy': os.environ.get('OMP_WAIT_POLICY')}))"
    )
    return _run(code, env_update)


def test_importing_ebad_its_cli_and_splat_cpu_changes_no_environment_variable_nor_numba_setting():
    code = (
        "import json, os\nenv = dict(os.environ)\n"
        "import ebad, ebad.cli, ebad.run, ebad.loop, splat_cpu, splat_cpu._numba_impl, ebad.threads, numba\n"
        "changed = sorted(k for k in set(env) | set(os.environ) if env.get(k) != os.environ.get(k))\n"
        "print(json.dumps({'changed': changed, 'layer': numba.config.THREADING_LAYER,"
        " 'priority': numba.config.THREADING_LAYER_PRIORITY}))"
    )
    out = _run(code)
    assert out == {"changed": [], "layer": "default", "priority": ["tbb", "omp", "workqueue"]}


def test_configure_before_torch_sets_the_policy_and_runs_numba_on_openmp():
    out = _setup_then_layer("import ebad")
    assert out["setup"] == {"policy_set": True, "threads_sleep": True, "numba_layer": "omp"}
    assert out["policy"] == "PASSIVE" and out["layer"] == "omp"


def test_torch_loaded_first_the_set_up_neither_sets_the_policy_nor_uses_openmp_spinning_threads():
    # the old bug: the CLI set OMP_WAIT_POLICY after torch had loaded (so it was not in force)
    # and the rasteriser then chose numba's OpenMP layer on threads that spin
    out = _setup_then_layer("import torch, ebad.cli")
    assert out["setup"] == {"policy_set": False, "threads_sleep": False, "numba_layer": "workqueue"}
    assert out["policy"] is None and out["layer"] == "workqueue"
    late = _setup_then_layer("import torch\nos.environ['OMP_WAIT_POLICY'] = 'PASSIVE'  # too late for torch")
    assert late["setup"] == {"policy_set": False, "threads_sleep": False, "numba_layer": "workqueue"}
    assert late["layer"] == "workqueue"


def test_a_policy_in_force_before_torch_loaded_is_recognised_and_a_users_choices_win():
    out = _setup_then_layer("import torch", {"OMP_WAIT_POLICY": "PASSIVE"})  # from the process's start
    assert out["setup"] == {"policy_set": False, "threads_sleep": True, "numba_layer": "omp"}
    assert out["layer"] == "omp"
    active = _setup_then_layer("import ebad", {"OMP_WAIT_POLICY": "active"})
    assert active["setup"] == {"policy_set": False, "threads_sleep": False, "numba_layer": "workqueue"}
    assert active["policy"] == "active" and active["layer"] == "workqueue"
    user = _setup_then_layer("import ebad", {"NUMBA_THREADING_LAYER": "workqueue"})
    assert user["setup"] == {"policy_set": True, "threads_sleep": True, "numba_layer": "user"}
    assert user["layer"] == "workqueue"


def test_the_cli_main_sets_the_threads_up_before_its_command_runs(monkeypatch):
    from ebad import cli

    calls = []
    monkeypatch.setattr(cli, "configure_threads", lambda: calls.append("configure"))
    assert cli.main(["--help"]) == 0
    assert calls == ["configure"]


TRAIN = """
import json, torch, scenes
from ebad.callbacks import StepHook
from ebad.config import preset
from ebad.run import reconstruct
seen = []
cfg = preset("3dgs"); cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 2, False, 0
torch.set_num_threads(2)
reconstruct(scenes.make_scene("boxes", "tiny", n_frames=3, n_test=1).capture, cfg,
            callbacks=[StepHook(lambda step, stats: seen.append(torch.get_num_threads()))])
print(json.dumps([seen, torch.get_num_threads()]))
"""


def test_training_runs_torch_on_one_thread_and_restores_its_count():
    assert _run(TRAIN) == [[1, 1], 2]
