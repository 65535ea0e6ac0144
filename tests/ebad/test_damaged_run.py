"""A run folder marked complete whose model.json, metrics.json or point_cloud.ply is damaged: one
line naming the file and the field, through ``load_run`` and through the CLI (no traceback)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from ebad.errors import UserError
from ebad.runfolder import load_run


def _edit(doc: dict, **changes) -> str:
    d = dict(doc)
    for k, v in changes.items():
        if v is _DROP:
            d.pop(k)
        else:
            d[k] = v
    return json.dumps(d)


_DROP = object()

MODEL_CASES = {
    "garbage": (lambda m: "garbage{", "not valid JSON"),
    "a list": (lambda m: "[1, 2]", "must be a JSON object"),
    "no K": (lambda m: _edit(m, K=_DROP), r"missing field\(s\) \['K'\]"),
    "no response": (lambda m: _edit(m, response=_DROP), "response"),
    "negative width": (lambda m: _edit(m, width=-5), "'width' must be an integer"),
    "huge height": (lambda m: _edit(m, height=10**9), "'height' must be an integer"),
    "NaN in K": (lambda m: json.dumps(m).replace('"K": [[', '"K": [[NaN, '), "'K'"),
    "names shorter": (lambda m: _edit(m, names=m["names"][:2]), "'exposures' must have shape"),
    "knots cut": (lambda m: _edit(m, knots=[1.0]), "'knots' holds 1 numbers"),
    "unknown kind": (lambda m: _edit(m, kind="wobbly"), "'kind' must be one of"),
    "response raw": (lambda m: _edit(m, response={"kind": "gamma", "raw": [1]}), "'response.raw'"),
    "7 channels": (lambda m: _edit(m, channels=7), "'channels' must be 1 or 3"),
    "c2w a string": (lambda m: _edit(m, c2w_mid="x"), "'c2w_mid'"),
    "views zero": (lambda m: _edit(m, views=[0] * len(m["names"])), "'views'"),
    "deep nesting": (lambda m: "[" * 100000 + "]" * 100000, "(not valid JSON|must be a JSON object)"),
}


@pytest.fixture
def damaged(tiny_run, tmp_path):
    def make(file: str, content: str | bytes):
        run = tmp_path / "run"
        shutil.copytree(tiny_run.run, run)
        path = run / file
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        return run

    return make


@pytest.mark.parametrize("case", list(MODEL_CASES))
def test_a_damaged_model_json_names_the_file_and_field(tiny_run, damaged, case):
    change, match = MODEL_CASES[case]
    run = damaged("model.json", change(json.loads((tiny_run.run / "model.json").read_text())))
    with pytest.raises(UserError, match=match) as info:
        load_run(run)
    assert "model.json" in str(info.value)


@pytest.mark.parametrize(
    "content,match",
    [("{{{", "not valid JSON"), ('{"complete": true}', "not the metrics of a run"), (None, "'steps' must be")],
)
def test_a_damaged_metrics_json_names_the_file(tiny_run, damaged, content, match):
    if content is None:
        doc = json.loads((tiny_run.run / "metrics.json").read_text())
        doc["steps"] = "many"
        content = json.dumps(doc)
    with pytest.raises(UserError, match=match) as info:
        load_run(damaged("metrics.json", content))
    assert "metrics.json" in str(info.value)


def _ply_cases(ply: bytes) -> dict[str, bytes]:
    end = ply.index(b"end_header\n") + len(b"end_header\n")
    count = ply[:end].split(b"element vertex ")[1].split(b"\n")[0]
    nan = bytearray(ply)
    nan[end : end + 4] = np.float32(np.nan).tobytes()  # the first Gaussian's x
    return {
        "truncated": ply[: len(ply) // 2],
        "garbage": b"garbage" * 10,
        "huge count": ply[:end].replace(b"element vertex " + count, b"element vertex 999999999999") + ply[end:],
        "NaN mean": bytes(nan),
    }


@pytest.mark.parametrize("case", ["truncated", "garbage", "huge count", "NaN mean"])
def test_a_damaged_point_cloud_names_the_file(tiny_run, damaged, case):
    content = _ply_cases((tiny_run.run / "point_cloud.ply").read_bytes())[case]
    with pytest.raises(UserError, match="point_cloud.ply") as info:
        load_run(damaged("point_cloud.ply", content))
    assert ("non-finite" in str(info.value)) == (case == "NaN mean")


def test_the_cli_prints_one_line_for_a_damaged_run(tiny_run, damaged, tmp_path, capsys):
    from ebad.cli import main

    run = damaged("model.json", "garbage{")
    assert main(["render", str(run), "--out", str(tmp_path / "out"), "--split", "train"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "model.json: not valid JSON" in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
