"""View boxes from synthetic uniform-white captures: exact recovery and bad-input errors."""

import numpy as np
import pytest

from recon.calibration.views import VIEW_GRID, check_boxes, find_view_boxes, overlapping_pair
from recon.errors import InputError


def _mask(rng, h, w):
    cells = rng.random((h // 2 + 1, w // 2 + 1)) < 0.5
    return np.kron(cells, np.ones((2, 2)))[:h, :w]


def _sensor(rng, hv, wm, gap_y, gap_x, y0=7, x0=11, noise=0.005, shape=None):
    """A white capture with 3×3 views of size (hv, wm); returns it and the boxes of ids 0..8."""
    hs = shape[0] if shape else y0 + 3 * hv + 2 * gap_y + 9
    ws = shape[1] if shape else x0 + 3 * wm + 2 * gap_x + 13
    img = np.zeros((hs, ws))
    boxes = np.empty((9, 4), dtype=int)
    for v, (r, c) in VIEW_GRID.items():
        by, bx = y0 + r * (hv + gap_y), x0 + c * (wm + gap_x)
        # Corner views a little dimmer (vignetting), side views lose to the mirrors.
        level = 1000.0 * (0.8 if v >= 5 else 0.9 if v else 1.0)
        img[by:by + hv, bx:bx + wm] = level * _mask(rng, hv, wm)
        boxes[v] = (by, bx, hv, wm)
    img += noise * 1000.0 * rng.standard_normal(img.shape)
    return img.astype(np.float32), boxes


def test_boxes_exact_with_gaps():
    rng = np.random.default_rng(0)
    img, truth = _sensor(rng, 64, 90, gap_y=6, gap_x=9)
    ids = (0, 1, 2, 3, 4, 5, 6, 7, 8)
    boxes = find_view_boxes(img, ids)
    np.testing.assert_array_equal(boxes, truth[list(ids)])


def test_boxes_exact_for_touching_views_and_subset_order():
    rng = np.random.default_rng(1)
    img, truth = _sensor(rng, 60, 84, gap_y=0, gap_x=0)
    ids = (4, 0, 2)
    # Nine views touching in both directions look like one view: the grid must be given.
    np.testing.assert_array_equal(find_view_boxes(img, ids, grid=3), truth[list(ids)])


def test_union_of_monochromatic_stack_gives_dispersed_width():
    # Each band shows the code region (width 70) shifted by its dispersion (0..14 px): the box
    # must hold all of them (width 84), which no single band shows.
    rng = np.random.default_rng(2)
    hv, wc, span = 60, 70, 14
    code = [_mask(rng, hv, wc) for _ in range(9)]
    stack = []
    y0, x0, gap = 5, 8, 10
    for s in (0, 5, 9, 14):
        img = np.zeros((y0 + 3 * hv + 2 * gap + 5, x0 + 3 * (wc + span) + 2 * gap + 5))
        for v, (r, c) in VIEW_GRID.items():
            by, bx = y0 + r * (hv + gap), x0 + c * (wc + span + gap) + s
            img[by:by + hv, bx:bx + wc] = 500.0 * code[v]
        stack.append(img)
    boxes = find_view_boxes(np.stack(stack), (0, 1, 2, 3, 4))
    assert np.all(boxes[:, 2:] == (hv, wc + span))
    assert tuple(boxes[0, :2]) == (y0 + hv + gap, x0 + wc + span + gap)
    single = find_view_boxes(stack[0], (0,))
    assert single[0, 3] == wc


def test_margin_and_common_size():
    rng = np.random.default_rng(3)
    img, truth = _sensor(rng, 50, 70, gap_y=12, gap_x=12)
    boxes = find_view_boxes(img, (0, 1), margin=2)
    np.testing.assert_array_equal(boxes, truth[[0, 1]] + np.array([-2, -2, 4, 4]))


def test_dark_frame_is_subtracted():
    rng = np.random.default_rng(4)
    img, truth = _sensor(rng, 50, 70, gap_y=8, gap_x=8)
    dark = np.full(img.shape, 300.0, dtype=np.float32)
    np.testing.assert_array_equal(find_view_boxes(img + dark, (0, 3), dark=dark), truth[[0, 3]])


def test_bad_inputs():
    rng = np.random.default_rng(5)
    img, _ = _sensor(rng, 40, 60, gap_y=8, gap_x=8)
    with pytest.raises(InputError, match="dark"):
        find_view_boxes(np.zeros((100, 100)))
    with pytest.raises(InputError, match="2-D frame"):
        find_view_boxes(np.zeros(10))
    with pytest.raises(InputError, match="repeat"):
        find_view_boxes(img, (0, 0))
    with pytest.raises(InputError, match="unknown view"):
        find_view_boxes(img, (0, 9))
    with pytest.raises(InputError, match="non-finite"):
        bad = img.copy()
        bad[0, 0] = np.nan
        find_view_boxes(bad)
    with pytest.raises(InputError, match="leaves the sensor|overlap"):
        find_view_boxes(img, (5, 6), margin=30)
    # Two lit columns only: not a 3x3 grid.
    two = np.zeros((80, 200))
    two[10:70, 10:80] = 1.0
    two[10:70, 120:190] = 1.0
    with pytest.raises(InputError, match="lit runs"):
        find_view_boxes(two, (0,))


def test_check_boxes():
    assert check_boxes([[0, 0, 4, 5], [4, 6, 4, 5]], (10, 12)).dtype == np.int64
    with pytest.raises(InputError, match="one size"):
        check_boxes([[0, 0, 4, 5], [4, 6, 4, 6]])
    with pytest.raises(InputError, match="do not fit"):
        check_boxes([[8, 0, 4, 5]], (10, 12))
    with pytest.raises(InputError, match="integers"):
        check_boxes([[0.5, 0, 4, 5]])
    with pytest.raises(InputError, match=r"\(K, 4\)"):
        check_boxes([0, 0, 4, 5])


def test_margin_x_grows_boxes_only_as_far_as_they_stay_apart():
    rng = np.random.default_rng(5)
    img, truth = _sensor(rng, 64, 90, gap_y=0, gap_x=9)      # rows touch, columns have a gap
    ids = tuple(range(9))
    base = find_view_boxes(img, ids)
    np.testing.assert_array_equal(base, truth)
    two = find_view_boxes(img, ids, margin_x=2)
    np.testing.assert_array_equal(two[:, 1], truth[:, 1] - 2)
    assert np.all(two[:, 3] == 94) and np.all(two[:, 2] == 64)
    # A 9-px gap leaves room for 4 px per side at most; asking for more never overlaps.
    wide = find_view_boxes(img, ids, margin_x=100)
    assert np.all(wide[:, 3] <= 90 + 2 * 4) and np.all(wide[:, 3] >= 94)


def _plus_stack(rng, hv=60, wc=50, span=36, gap_x=4, gap_y=2, x0=8, y0=3, shape=None,
                shifts=(0, 6, 12, 18, 24, 30, 36)):
    """Monochromatic whites of the five views 0..4 (a plus), wide dispersion: each band shows
    the code region (width ``wc``) shifted by up to ``span``. Returns the stack and the boxes
    (union of the bands) of ids 0..4."""
    wm = wc + span
    hs = shape[0] if shape else y0 + 3 * hv + 2 * gap_y + 3
    ws = shape[1] if shape else x0 + 3 * wm + 2 * gap_x + 8
    code = {v: _mask(rng, hv, wc) for v in range(5)}
    boxes = np.empty((5, 4), dtype=int)
    stack = []
    for s in shifts:
        img = np.zeros((hs, ws))
        for v in range(5):
            r, c = VIEW_GRID[v]
            by, bx = y0 + r * (hv + gap_y), x0 + c * (wm + gap_x)
            boxes[v] = (by, bx, hv, wm)
            # The shortest band is brightest: the dispersed edges are lit by one band each.
            img[by:by + hv, bx + s:bx + s + wc] = (800.0 - 10.0 * s) * code[v]
        stack.append(img)
    return np.stack(stack).astype(np.float32), boxes


def test_wide_dispersion_plus_layout_follows_each_view():
    # Only the middle row and column are lit, the dispersion span (36 px) is 9× the column
    # gap: the columns' global profiles are uneven, the boxes must still hold every view.
    rng = np.random.default_rng(6)
    stack, truth = _plus_stack(rng)
    boxes = find_view_boxes(stack, (0, 1, 2, 3, 4), margin_x=2)
    assert overlapping_pair(boxes) is None
    assert np.all(boxes[:, 2:] == boxes[0, 2:])
    for b, t in zip(boxes, truth):
        assert b[0] <= t[0] and b[0] + b[2] >= t[0] + t[2]
        assert b[1] <= t[1] and b[1] + b[3] >= t[1] + t[3]
        assert b[3] - t[3] <= 4 and b[2] == t[2]


def test_view_at_the_sensor_edge_is_clipped_and_a_cut_view_is_named():
    rng = np.random.default_rng(7)
    # View 1 starts at column 0: its box may not grow to the left, it is shifted instead.
    stack, truth = _plus_stack(rng, x0=0)
    boxes = find_view_boxes(stack, (0, 1, 2), margin_x=3)
    assert boxes[1, 1] == 0 and overlapping_pair(boxes) is None
    assert boxes[1, 1] + boxes[1, 3] >= truth[1, 1] + truth[1, 3]
    # A view cut by the sensor's left edge cannot be used: named in the error.
    cut = stack[:, :, 30:]
    with pytest.raises(InputError, match="view 1.*left edge"):
        find_view_boxes(cut, (0, 1, 2))
    # ... but the views that are whole still can.
    whole = find_view_boxes(cut, (0, 2, 3))
    assert overlapping_pair(whole) is None and np.all(whole[:, 3] >= truth[0, 3])


def test_single_full_frame_view_and_a_partial_row():
    rng = np.random.default_rng(8)
    # The traditional CASSI: one view fills most of the sensor.
    one = np.zeros((120, 150), dtype=np.float32)
    one[2:118, 10:140] = 900.0 * _mask(rng, 116, 130)
    np.testing.assert_array_equal(find_view_boxes(one, (0,)), [[2, 10, 116, 130]])
    with pytest.raises(InputError, match="view 1 is dark"):
        find_view_boxes(one, (0, 1))
    # Only the middle row of a kaleidoscope lit: three columns, one row (not three touching).
    stack, truth = _plus_stack(rng)
    row = stack.copy()
    row[:, :truth[0, 0] - 1] = 0.0
    row[:, truth[0, 0] + truth[0, 2] + 1:] = 0.0
    np.testing.assert_array_equal(find_view_boxes(row, (1, 0, 2)), truth[[1, 0, 2]])
