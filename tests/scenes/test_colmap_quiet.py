"""SfM prints nothing of COLMAP's own (issue 30: glog's "Failed to create any sparse model" leaked to
fd 2 when mapping failed) while our progress lines still come through logging."""

import logging

import pytest

from scenes.colmap import ColmapConfig, SfMError


@pytest.fixture(scope="module")
def capture():
    import scenes

    return scenes.make_scene("boxes", "tiny", seed=0, poses="none", n_frames=6, n_test=0).capture


@pytest.fixture()
def progress_to_stderr():
    """scenes.colmap's INFO lines on fd 2, as a command line shows them."""
    import os

    class ToFd2(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            os.write(2, (self.format(record) + "\n").encode())

    lg = logging.getLogger("scenes.colmap")
    handler = ToFd2()
    old = lg.level
    lg.addHandler(handler)
    lg.setLevel(logging.INFO)
    yield
    lg.removeHandler(handler)
    lg.setLevel(old)


def test_failed_sfm_leaks_no_colmap_log_line(capture, capfd, progress_to_stderr):
    import pycolmap

    from scenes.colmap import estimate_poses

    level = pycolmap.logging.minloglevel
    with pytest.raises(SfMError, match="registered no frames"):
        estimate_poses(capture, ColmapConfig(num_threads=1, init_min_num_inliers=100000))
    out, err = capfd.readouterr()
    lines = err.strip().splitlines()
    assert lines and all(line.startswith("SfM: ") for line in lines), err  # ours only, nothing from glog
    assert "SfM: matched in" in err and "Failed to create" not in err and "sfm.cc" not in err
    assert out == ""
    assert pycolmap.logging.minloglevel == level  # restored
