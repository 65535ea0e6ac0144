"""ebad.run.warm_up compiles for the kinds of capture its caller will run, and no other."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any, cast

import pytest

import scenes
from ebad import run as trainer
from ebad.errors import ConfigError


@pytest.fixture
def calls(monkeypatch):
    """warm_up's scenes (make_scene's keywords) and the configs it reconstructs them with, nothing run."""
    made: list[dict] = []
    cfgs: list = []
    monkeypatch.setattr(scenes, "make_scene", lambda *a, **kw: made.append(kw) or type("S", (), {"capture": None}))
    monkeypatch.setattr(trainer, "reconstruct", lambda cap, cfg: cfgs.append(cfg))
    return made, cfgs


def test_grey_warm_up_builds_no_colour_capture(calls):
    made, cfgs = calls
    trainer.warm_up()
    assert len(made) == 1 and "cfa" not in made[0] and not made[0].get("rgb")
    assert cfgs[0].model.sh_degree == 0 and cfgs[0].train.iters == 3
    made.clear()
    trainer.warm_up(["grey"])
    assert len(made) == 1 and "cfa" not in made[0]


def test_each_kind_once_and_sh_degree(calls):
    made, cfgs = calls
    trainer.warm_up(["cfa", "grey", "cfa", "rgb"], sh_degree=2)
    assert [(kw.get("rgb", False), kw.get("cfa")) for kw in made] == [(True, "RGGB"), (False, None), (True, None)]
    assert all(c.model.sh_degree == 2 and c.model.sh_degree_interval == 1 for c in cfgs)


@pytest.mark.parametrize("kinds", [["gray"], []])
def test_unknown_kind_is_one_line(calls, kinds):
    with pytest.raises(ConfigError, match=r"warm_up: kinds must be some of grey, rgb, cfa"):
        trainer.warm_up(kinds)
    assert calls[0] == []


def test_capture_kind():  # what capture_kind reads of a Capture: its colour filter and its frames' channels
    caps = [SimpleNamespace(cfa=None, channels=1), SimpleNamespace(cfa=None, channels=3)]
    caps.append(SimpleNamespace(cfa="RGGB", channels=3))
    assert [trainer.capture_kind(cast(Any, c)) for c in caps] == ["grey", "rgb", "cfa"]
