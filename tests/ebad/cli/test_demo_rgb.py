"""``ebad demo --rgb`` simulates a colour DAVIS (an RGGB Bayer filter over frame and event pixels)."""

import pytest

import scenes
from ebad.cli import demo


class _Stop(Exception):
    pass


@pytest.fixture(autouse=True)
def _no_precompile(monkeypatch):  # these tests stop before training: no child compiles numba's kernels for them
    import ebad.precompile

    monkeypatch.setattr(ebad.precompile, "kernels_cached", lambda: True)


@pytest.mark.parametrize("rgb, cfa", [(True, "RGGB"), (False, None)])
def test_demo_rgb_builds_a_colour_davis_capture(tmp_path, monkeypatch, rgb, cfa):
    seen = {}

    def fake_make_scene(name, **kw):
        seen.update(kw, name=name)
        raise _Stop

    monkeypatch.setattr(scenes, "make_scene", fake_make_scene)
    with pytest.raises(_Stop):
        demo.run(demo.Args(out=str(tmp_path / "o"), rgb=rgb))
    assert seen["cfa"] == cfa and seen["rgb"] is rgb and seen["name"] == "boxes"


@pytest.mark.parametrize("rgb, kinds", [(True, ["cfa"]), (False, ["grey"])])
def test_demo_warms_up_only_its_capture_kind(tmp_path, monkeypatch, rgb, kinds):
    import ebad.run

    seen = []

    def fake_warm_up(k=("grey",), sh_degree=0):
        seen.append(list(k))
        raise _Stop

    monkeypatch.setattr(ebad.run, "warm_up", fake_warm_up)
    with pytest.raises(_Stop):
        demo.run(demo.Args(out=str(tmp_path / "o"), rgb=rgb, size="tiny"))
    assert seen == [kinds]
