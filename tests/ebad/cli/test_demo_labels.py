"""``ebad demo``'s comparison.png carries column labels above the test-view and training-frame rows."""

from __future__ import annotations

import numpy as np

from ebad.cli.demo import comparison_image


def test_the_comparison_grid_has_a_label_strip_above_each_group():
    img = np.full((12, 16, 1), 0.5, np.float32)
    rows = [[img] * 3, [img] * 3, [img] * 4, [img] * 4]
    rows = [r + [np.ones_like(img)] * (4 - len(r)) for r in rows]
    plain = comparison_image(rows, k=4)
    grid = comparison_image(rows, k=4, headers={0: ["truth", "3dgs", "ebad"], 2: ["blurry", "3dgs", "ebad", "truth"]})
    strip = grid.shape[0] - plain.shape[0]
    assert grid.shape[1] == plain.shape[1] and strip > 0 and strip % 2 == 0  # two strips of one height
    h = strip // 2
    top = grid[:h]
    assert (top < 100).any() and (top > 250).mean() > 0.7  # black text on white
    tile = 16 * 4
    for col in range(3):  # every labelled column has text over it
        assert (top[:, col * (tile + 2) : col * (tile + 2) + tile] < 100).any()
    assert not (top[:, 3 * (tile + 2) :] < 100).any()  # the unlabelled fourth column of the test rows
    second = grid[h + 2 * (12 * 4 + 2) : 2 * h + 2 * (12 * 4 + 2)]
    assert (second[:, 3 * (tile + 2) :] < 100).any()  # "truth" over the training rows' fourth column
    np.testing.assert_array_equal(grid[h : h + 12 * 4], plain[: 12 * 4])  # the images themselves unchanged
