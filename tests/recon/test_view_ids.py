"""recon.view_ids: one convention for the nine views."""

from __future__ import annotations

from recon.view_ids import ALL_VIEWS, VIEW_FLIPS, VIEW_GRID, VIEW_ORDER


def test_the_grid_holds_each_cell_once_and_the_centre_first():
    assert sorted(VIEW_GRID.values()) == [(r, c) for r in range(3) for c in range(3)]
    assert VIEW_GRID[0] == (1, 1)
    assert sorted(VIEW_ORDER) == list(ALL_VIEWS) == sorted(VIEW_GRID)
    assert VIEW_ORDER[0] == 0


def test_a_view_is_mirrored_along_each_axis_it_is_moved_along():
    """One reflection off a wall per step away from the centre: rows reversed for the top and
    bottom rows of the grid, columns for the left and right columns."""
    for v, (r, c) in VIEW_GRID.items():
        want = tuple(ax for ax, off in ((0, r != 1), (1, c != 1)) if off)
        assert VIEW_FLIPS[v] == want, v
