"""ebad.config: presets, JSON round trip, validation."""

from __future__ import annotations

import pytest

from ebad import config as C
from ebad.errors import ConfigError


def test_presets_registry_and_json_roundtrip(tmp_path):
    assert set(C.PRESETS) == {"3dgs", "bad", "edi-3dgs", "ebad", "3dgs-sharp"}
    e = C.preset("ebad")
    assert (e.loss.w_blur, e.loss.w_event, e.loss.w_edi) == (1.0, 0.1, 1.0)
    assert C.preset("bad").loss.w_event == 0 and C.preset("bad").trajectory.kind == "linear"
    assert C.preset("3dgs").trajectory.kind == "fixed"
    assert (e.trajectory.kind, e.loss.edi_instants) == ("cubic", "views")
    assert C.preset("edi-3dgs").loss.target == "edi"
    e.model.init_depth = (1.0, 3.0)
    C.save_config(e, tmp_path / "c.json")
    back = C.load_config(tmp_path / "c.json")
    assert back == e


def test_config_errors_name_the_key():
    with pytest.raises(ValueError, match="nope"):
        C.preset("nope")
    with pytest.raises(ValueError, match="bogus"):
        C.config_from_dict({"train": {"bogus": 1}})


@pytest.mark.parametrize(
    "section,field,value,needle",
    [
        ("train", "lr_means", float("nan"), "--train.lr_means: must be a finite number"),
        ("train", "checkpoint_every", -1, "--train.checkpoint_every: must be >= 0"),
        ("loss", "ssim_window", 6, "--loss.ssim_window: must be an odd number"),
        ("loss", "event_windows", "sliding", "--loss.event_windows: must be one of consecutive, random"),
        ("loss", "event_norm", "l3", "--loss.event_norm: must be one of l1, l2"),
        ("loss", "edi_prior", "mapEDI", "--loss.edi_prior: must be one of edi, medi"),
        ("model", "background", 5.0, "--model.background: must be in [0, 1]"),
        ("model", "max_gaussians", -3, "--model.max_gaussians: must be >= 0"),
        ("model", "init_depth", (2.0, 1.0), "--model.init_depth: must be two depths"),
        ("train", "iters", -1, "--train.iters: must be >= 0"),
        ("trajectory", "num_views", 0, "--trajectory.num_views: must be >= 1"),
        ("strategy", "split_shrink", 1.0, "--strategy.split_shrink: must be > 1"),
    ],
)
def test_check_refuses_values_that_cannot_work_naming_the_option(section, field, value, needle):
    cfg = C.preset("ebad")
    cfg.check()  # the preset itself is valid
    setattr(getattr(cfg, section), field, value)
    with pytest.raises(ConfigError) as info:
        cfg.check()
    assert needle in str(info.value)


def test_json_values_of_the_wrong_type_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match=r"train.iters: must be an integer, got '30'"):
        C.config_from_dict({"train": {"iters": "30"}})
    with pytest.raises(ConfigError, match=r"trajectory.kind: must be one of"):
        C.config_from_dict({"trajectory": {"kind": "spline"}})
    with pytest.raises(ConfigError, match=r"train.progress: must be true or false"):
        C.config_from_dict({"train": {"progress": 1}})
    (tmp_path / "c.json").write_text('{"train": {"iters": "30"}}')
    with pytest.raises(ConfigError, match=r"c.json: train.iters"):
        C.load_config(tmp_path / "c.json")
    assert C.config_from_dict({"model": {"init_depth": [0.5, 2]}}).model.init_depth == (0.5, 2.0)


def test_config_diff_lists_changed_fields():
    a, b = C.preset("ebad"), C.preset("ebad")
    assert C.config_diff(a, b) == {}
    b.train.iters = 7
    b.loss.w_event = 0.5
    assert C.config_diff(a, b) == {"train.iters": (0, 7), "loss.w_event": (0.1, 0.5)}
    assert "train.iters" in C.RESUMABLE_FIELDS and "loss.w_event" not in C.RESUMABLE_FIELDS
