"""INRIA's tools open a run folder (issue 30, item 6): ``point_cloud/iteration_N/point_cloud.ply``
and ``cfg_args`` beside ``cameras.json``. The checks below re-implement what INRIA's loaders do
with those files (graphdeco-inria/gaussian-splatting ``arguments/__init__.py`` get_combined_args,
``scene/__init__.py`` + ``utils/system_utils.py`` searchForMaxIteration,
``scene/gaussian_model.py`` load_ply, and the SIBR gaussian viewer's ``findArg`` on cfg_args)."""

from __future__ import annotations

import json
import os
from argparse import Namespace

import numpy as np
from plyfile import PlyData

from ebad.runfolder import write_inria_layout

# the vertex layout the SIBR viewer reads as raw structs (RichPoint<3>: sh_degree 3), in this order
SIBR_SH3_LAYOUT = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [
    *(f"f_rest_{i}" for i in range(45)),
    "opacity",
    *(f"scale_{i}" for i in range(3)),
    *(f"rot_{i}" for i in range(4)),
]


def _search_for_max_iteration(folder: str) -> int:  # INRIA utils/system_utils.py
    return max(int(fname.split("_")[-1]) for fname in os.listdir(folder))


def _get_combined_args(model_path: str) -> Namespace:  # INRIA arguments/__init__.py, reading cfg_args
    with open(os.path.join(model_path, "cfg_args")) as fh:
        return eval(fh.read(), {"Namespace": Namespace})  # what INRIA does (eval in its module's globals)


def _find_arg(line: str, name: str) -> str:  # SIBR gaussianViewer main.cpp findArg + substr
    start = line.find("=", line.find(name)) + 1
    end = min(i for i in (line.find(",", start), line.find(")", start)) if i >= 0)
    return line[start:end]


def _load_ply(path: str, max_sh_degree: int) -> dict[str, np.ndarray]:  # INRIA GaussianModel.load_ply
    el = PlyData.read(path).elements[0]
    xyz = np.stack([np.asarray(el[k]) for k in ("x", "y", "z")], axis=1)
    extra = sorted((p.name for p in el.properties if p.name.startswith("f_rest_")), key=lambda n: int(n.split("_")[-1]))
    assert len(extra) == 3 * (max_sh_degree + 1) ** 2 - 3
    scales = sorted((p.name for p in el.properties if p.name.startswith("scale_")), key=lambda n: int(n.split("_")[-1]))
    rots = sorted((p.name for p in el.properties if p.name.startswith("rot")), key=lambda n: int(n.split("_")[-1]))
    assert len(scales) == 3 and len(rots) == 4
    return {
        "xyz": xyz,
        "opacity": np.asarray(el["opacity"]),
        "f_dc": np.stack([np.asarray(el[f"f_dc_{i}"]) for i in range(3)], 1),
        "scale": np.stack([np.asarray(el[n]) for n in scales], 1),
        "rot": np.stack([np.asarray(el[n]) for n in rots], 1),
        "order": [p.name for p in el.properties],
    }


def test_inria_loaders_open_the_run_folder(tiny_run):
    run = str(tiny_run.run)
    assert os.path.isfile(os.path.join(run, "cameras.json"))
    args = _get_combined_args(run)
    for key in ("sh_degree", "source_path", "model_path", "images", "resolution", "white_background", "eval"):
        assert hasattr(args, key), key
    assert args.sh_degree == 3 and args.model_path == os.path.realpath(run) and args.white_background is False
    it = _search_for_max_iteration(os.path.join(run, "point_cloud"))
    steps = json.loads((tiny_run.run / "metrics.json").read_text())["steps"]
    assert it == max(steps, 1)
    ply = os.path.join(run, "point_cloud", f"iteration_{it}", "point_cloud.ply")
    got = _load_ply(ply, args.sh_degree)
    assert got["order"] == SIBR_SH3_LAYOUT
    assert os.path.samefile(ply, os.path.join(run, "point_cloud.ply"))  # linked, not a second copy
    # the SIBR viewer: first line, source_path between quotes, sh_degree an int, white_background
    line = (tiny_run.run / "cfg_args").read_text().splitlines()[0]
    assert _find_arg(line, "source_path")[1:-1] == os.path.realpath(run)
    assert int(_find_arg(line, "sh_degree")) == 3 and "True" not in _find_arg(line, "white_background")


def test_a_later_write_replaces_the_iteration_folder(tmp_path):
    (tmp_path / "point_cloud.ply").write_bytes(b"ply 1")
    write_inria_layout(tmp_path, 100)
    (tmp_path / "point_cloud.ply").unlink()
    (tmp_path / "point_cloud.ply").write_bytes(b"ply 2")
    write_inria_layout(tmp_path, 250, white_background=True, eval=True)
    assert os.listdir(tmp_path / "point_cloud") == ["iteration_250"]  # searchForMaxIteration parses every entry
    assert (tmp_path / "point_cloud" / "iteration_250" / "point_cloud.ply").read_bytes() == b"ply 2"
    args = _get_combined_args(str(tmp_path))
    assert args.white_background is True and args.eval is True
    write_inria_layout(tmp_path, 0)
    assert os.listdir(tmp_path / "point_cloud") == ["iteration_1"]  # INRIA's Scene reads iteration 0 as none
