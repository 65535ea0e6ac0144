"""The in-memory Capture: pose trust and test views without a pose."""

import numpy as np
import pytest

from edi import EventStream
from scenes import Capture, CaptureError, TestView


def _capture(**kw):
    f = np.full((2, 4, 5, 1), 0.5, np.float32)
    ev = EventStream(
        np.array([0, 10], np.int64),
        np.array([1, 2], np.int32),
        np.array([1, 3], np.int32),
        np.array([1, -1], np.int8),
        5,
        4,
    )
    args = dict(
        frames=f,
        exposures=np.array([[0.0, 0.01], [0.02, 0.03]]),
        events=ev,
        K=np.array([[5.0, 0, 2.5], [0, 5.0, 2.0], [0, 0, 1]]),
    )
    args.update(kw)
    return Capture(**args)


def test_effective_pose_trust_defaults():
    assert _capture().effective_pose_trust == "none"
    posed = _capture(c2w=np.tile(np.eye(4), (2, 1, 1)))
    assert posed.pose_trust is None and posed.effective_pose_trust == "approximate"  # never assumed exact
    assert _capture(c2w=np.tile(np.eye(4), (2, 1, 1)), pose_trust="exact").validate().effective_pose_trust == "exact"
    # "none" with poses present: the method must not use them
    assert _capture(c2w=np.tile(np.eye(4), (2, 1, 1)), pose_trust="none").validate().effective_pose_trust == "none"


@pytest.mark.parametrize(
    "kw, word",
    [
        (dict(pose_trust="trusted"), "pose_trust"),
        (dict(pose_trust="exact"), "pose_trust"),  # exact poses that are not there
        (dict(test_views=[TestView("a", 0.015, None, None)]), r"test_views\[0\]"),
    ],
)
def test_bad_pose_fields_name_the_field(kw, word):
    with pytest.raises(CaptureError, match=word):
        _capture(**kw).validate("x.json")


def test_test_view_with_an_image_and_no_pose_is_valid():
    img = np.zeros((4, 5, 1), np.float32)
    cap = _capture(test_views=[TestView("a", 0.015, None, img), TestView("b", 0.02, np.eye(4))]).validate()
    assert cap.test_views[0].c2w is None and cap.test_views[1].image is None
