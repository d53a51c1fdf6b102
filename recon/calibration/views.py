r"""Where the kaleidoscope's 3×3 views lie on the sensor, found from a uniform-white capture.

The kaleidoscope copies the diffuser into a 3×3 grid; the relay lens images the grid onto the
mask and the prism disperses every copy horizontally.  Under a spectrally flat white target the
sensor shows nine lit rectangles (each modulated by its part of the random mask, so only about
half of its pixels are bright).  This module finds them.

View ids follow the project order: 0 centre, 1 left, 2 right, 3 top, 4 bottom, then the corners
5 top-left, 6 top-right, 7 bottom-left, 8 bottom-right.  Left/right views are horizontal mirror
images of the centre, top/bottom vertical ones, corners both (:data:`VIEW_FLIPS`).

Method (projections, no per-pixel loops).  With :math:`I` the dark-subtracted white capture
(for a stack of monochromatic captures: each scaled to its bright level, then the maximum over
the stack), the column profile :math:`p(x) = \operatorname{mean}_y I(y, x)` is about half the
white level inside a view (random 50 % mask) and about zero outside, wherever the mask holes
fall; an edge is where the profile crosses a fraction (``level``) of its plateau.  Globally this
gives the grid's cells (lit runs, cut at the middle of the gaps); locally (the profile inside
one cell) each view's lit extent.  Views that touch (no dark gap between them on the sensor)
are split into equal parts of the lit extent.  All boxes finally get the common size (the
largest), grown symmetrically about their lit extent.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError

#: Grid cell (row, column) of every view id in the 3×3 layout.
VIEW_GRID = {0: (1, 1), 1: (1, 0), 2: (1, 2), 3: (0, 1), 4: (2, 1),
             5: (0, 0), 6: (0, 2), 7: (2, 0), 8: (2, 2)}

#: Image axes (0 rows, 1 columns) that the mirrors reverse in every view, relative to the centre.
VIEW_FLIPS = {0: (), 1: (1,), 2: (1,), 3: (0,), 4: (0,), 5: (0, 1), 6: (0, 1), 7: (0, 1),
              8: (0, 1)}

ALL_VIEWS = tuple(range(9))


def check_view_ids(view_ids) -> tuple[int, ...]:
    """Validate a sequence of distinct view ids in 0..8.

    Raises
    ------
    InputError
        Empty, repeated or unknown ids.
    """
    try:
        ids = tuple(int(v) for v in view_ids)
    except (TypeError, ValueError):
        raise InputError(f"view ids must be integers 0..8, got {view_ids!r}") from None
    if not ids:
        raise InputError("view ids must not be empty")
    bad = [v for v in ids if v not in VIEW_GRID]
    if bad:
        raise InputError(f"unknown view ids {bad}: ids are 0..8 (centre, left, right, top, "
                         "bottom, then the corners)")
    if len(set(ids)) != len(ids):
        raise InputError(f"view ids repeat: {list(ids)}")
    return ids


def as_frame_stack(captures, name: str = "capture") -> np.ndarray:
    """A capture or stack of captures as a float32 (N, H, W) array (finite, non-empty).

    float32 holds raw DN exactly and keeps a stack of full-sensor frames at half the memory;
    the calibration steps convert only their crops to float64.
    """
    try:
        a = np.asarray(captures, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric array: {exc}") from None
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] < 2 or a.shape[2] < 2:
        raise InputError(f"{name} must be a 2-D frame or a stack (N, H, W), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} contains non-finite values")
    return a


def crop(frame: np.ndarray, box) -> np.ndarray:
    """The (..., h, w) sub-image of ``frame`` (..., H, W) at ``box`` = (y0, x0, h, w)."""
    y0, x0, h, w = (int(v) for v in box)
    return frame[..., y0:y0 + h, x0:x0 + w]


def find_view_boxes(white, view_ids=(0, 1, 2, 3, 4), dark=None, grid: int = 3,
                    level: float = 0.25, margin: int = 0, margin_x: int | None = None
                    ) -> np.ndarray:
    r"""Find each view's rectangle on the sensor from a uniform-white capture.

    Parameters
    ----------
    white : (H, W) or (N, H, W) array_like
        A broadband white capture, or the stack of monochromatic white captures of every band
        (each scaled to its 99.5th percentile, then the maximum over the stack): the box must
        hold the view under every band, so a single monochromatic capture alone gives boxes
        that are too narrow by the dispersion span.
    view_ids : sequence of int
        Views to return, in this order.
    dark : (H, W) array_like, optional
        Dark frame subtracted first.
    grid : int
        Views per side (3 for the kaleidoscope).
    level : float
        Edge threshold as a fraction of the profile's plateau.  Lower than half maximum because
        an edge row or column of the random mask may have far fewer than half its cells open
        (a 2×2-cell mask row of 45 cells is below 25 % open with probability ~5e-4); a blurred
        edge then moves out by a fraction of the blur radius, which ``margin`` covers.
    margin : int
        Pixels added on every side of every box (e.g. to keep a blurred rim).
    margin_x : int, optional
        Pixels added on the left and right of every box instead of ``margin``, *at most*: it is
        reduced as far as needed for the boxes to stay apart and on the sensor (the rows of
        views may touch, the dispersed columns have a gap).  A view's outermost columns are
        lit by one band only and fall under ``level``; this keeps them in the box.

    Returns
    -------
    boxes : (K, 4) int64
        ``y0, x0, h, w`` per view; all share one size ``(Hv, Wm) = (h, w)``.

    Raises
    ------
    InputError
        Bad shapes, a frame without lit views, a grid that cannot be resolved, or boxes that
        would overlap or leave the sensor.
    """
    ids = check_view_ids(view_ids)
    if grid < 1:
        raise InputError(f"grid must be >= 1, got {grid}")
    if not 0.0 < level < 1.0:
        raise InputError(f"level must be in (0, 1), got {level}")
    stack = as_frame_stack(white, "white capture")
    if dark is not None:
        d = as_frame_stack(dark, "dark frame").mean(axis=0)
        if d.shape != stack.shape[1:]:
            raise InputError(f"dark frame shape {d.shape} != capture shape {stack.shape[1:]}")
        stack = stack - d
    # A pixel belongs to a view if any band lights it; bands differ in brightness (source, QE),
    # so each frame is scaled to its own bright level before the maximum.
    img = np.zeros(stack.shape[1:], dtype=np.float32)
    for frame in stack:
        top = float(np.percentile(frame, 99.5))
        if not top > 0:
            raise InputError("the white capture is dark (a frame has no lit pixels)")
        np.maximum(img, frame / np.float32(top), out=img)
    hs, ws = img.shape
    rows = _grid_runs(img.mean(axis=1, dtype=np.float64), grid, level, "rows")
    cols = _grid_runs(img.mean(axis=0, dtype=np.float64), grid, level, "columns")

    lit = np.empty((len(ids), 4), dtype=np.int64)
    for i, v in enumerate(ids):
        r, c = VIEW_GRID[v] if grid == 3 else divmod(v, grid)
        if r >= grid or c >= grid:
            raise InputError(f"view {v} is outside a {grid}x{grid} grid")
        (ry0, ry1), (cx0, cx1) = rows[r], cols[c]
        cell = img[ry0:ry1, cx0:cx1].astype(np.float64)
        y0, y1 = _lit_extent(cell.mean(axis=1), level)
        x0, x1 = _lit_extent(cell.mean(axis=0), level)
        if y1 <= y0 or x1 <= x0:
            raise InputError(f"view {v} is dark in the white capture")
        lit[i] = (ry0 + y0, cx0 + x0, y1 - y0, x1 - x0)

    hv = int(lit[:, 2].max()) + 2 * margin
    wm = int(lit[:, 3].max()) + 2 * margin
    if margin_x is not None:
        if int(margin_x) < 0:
            raise InputError(f"margin_x must be >= 0, got {margin_x}")
        wm = int(lit[:, 3].max())
        for mx in range(int(margin_x), -1, -1):
            boxes = _grow(lit, hv, wm + 2 * mx, (hs, ws), ids, strict=mx == 0)
            if boxes is not None and _disjoint(boxes):
                return boxes
    boxes = _grow(lit, hv, wm, (hs, ws), ids, strict=True)
    _check_disjoint(boxes, ids)
    return boxes


def _grow(lit, hv, wm, sensor, ids, strict):
    """Boxes of size (hv, wm) grown symmetrically about the lit extents; ``None`` (or, when
    ``strict``, an InputError) if one would leave the sensor."""
    hs, ws = sensor
    boxes = np.empty_like(lit)
    for i, (y0, x0, h, w) in enumerate(lit):
        # Grow symmetrically (the odd pixel goes after) so a view's lit area stays centred.
        by = y0 - (hv - h) // 2
        bx = x0 - (wm - w) // 2
        if by < 0 or bx < 0 or by + hv > hs or bx + wm > ws:
            if not strict:
                return None
            raise InputError(f"view {ids[i]}'s box ({by}, {bx}, {hv}, {wm}) leaves the sensor "
                             f"{hs}x{ws}; use a smaller margin")
        boxes[i] = (by, bx, hv, wm)
    return boxes


def _disjoint(boxes) -> bool:
    try:
        _check_disjoint(boxes, list(range(len(boxes))))
    except InputError:
        return False
    return True


def _lit_extent(profile: np.ndarray, level: float) -> tuple[int, int]:
    """First and one-past-last index where ``profile`` exceeds ``level`` × its plateau."""
    plateau = _plateau(profile)
    if plateau <= 0:
        return 0, 0
    on = np.nonzero(profile > level * plateau)[0]
    if on.size == 0:
        return 0, 0
    return int(on[0]), int(on[-1]) + 1


def _plateau(profile: np.ndarray) -> float:
    """Typical lit value of a profile: the median of its upper half (robust to vignetting)."""
    p = np.sort(profile)
    return float(np.median(p[p.size // 2:])) if p.size else 0.0


def _grid_runs(profile: np.ndarray, n: int, level: float, axis: str) -> list[tuple[int, int]]:
    """Split a row or column profile into ``n`` cells [start, stop), one lit run in each."""
    peak = float(np.percentile(profile, 95))
    if not peak > 0:
        raise InputError(f"the white capture is dark (no lit {axis})")
    on = profile > level * peak
    edges = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    starts = np.nonzero(edges == 1)[0]
    stops = np.nonzero(edges == -1)[0]
    runs = [(int(a), int(b)) for a, b in zip(starts, stops)]
    # Isolated bright pixels (hot columns, noise) are not views.
    longest = max(b - a for a, b in runs)
    runs = [(a, b) for a, b in runs if b - a >= longest / 4]
    if len(runs) == n:
        # Cells reach to the middle of the gaps (and to the sensor's edges): a run seen through
        # fewer views (corners dark) is dimmer in the global profile and its edges may fall
        # under the threshold there; the local profile inside the cell finds them.
        cuts = [0] + [(runs[i][1] + runs[i + 1][0]) // 2 for i in range(n - 1)] + [profile.size]
        return [(int(cuts[i]), int(cuts[i + 1])) for i in range(n)]
    if len(runs) == 1:
        # Views that touch on the sensor: equal parts of the lit extent.
        a, b = runs[0]
        cuts = np.round(np.linspace(a, b, n + 1)).astype(int)
        return [(int(cuts[i]), int(cuts[i + 1])) for i in range(n)]
    raise InputError(f"found {len(runs)} lit runs along the {axis} of the white capture, "
                     f"expected {n} (or one run of touching views)")


def _check_disjoint(boxes: np.ndarray, ids) -> None:
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            if (a[0] < b[0] + b[2] and b[0] < a[0] + a[2]
                    and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]):
                raise InputError(f"boxes of views {ids[i]} and {ids[j]} overlap: {a} and {b}")


def check_boxes(view_boxes, frame_shape=None, n_views=None) -> np.ndarray:
    """Validate (K, 4) integer boxes of one common size inside a frame of ``frame_shape``."""
    try:
        boxes = np.asarray(view_boxes, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"view_boxes must be numbers, got {view_boxes!r}") from None
    if boxes.ndim != 2 or boxes.shape[1] != 4 or boxes.shape[0] == 0:
        raise InputError(f"view_boxes must be (K, 4) = y0, x0, h, w, got shape {boxes.shape}")
    if not np.all(np.equal(np.mod(boxes, 1), 0)):
        raise InputError("view_boxes must hold integers")
    boxes = boxes.astype(np.int64)
    if np.any(boxes[:, 2:] != boxes[0, 2:]):
        raise InputError(f"all view boxes must share one size, got {boxes[:, 2:].tolist()}")
    if n_views is not None and boxes.shape[0] != n_views:
        raise InputError(f"view_boxes has {boxes.shape[0]} rows, expected {n_views} (one per view)")
    if np.any(boxes[:, :2] < 0) or np.any(boxes[:, 2:] < 1):
        raise InputError(f"view_boxes {boxes.tolist()} have negative origins or empty sizes")
    if frame_shape is None:
        return boxes
    hs, ws = frame_shape
    if np.any(boxes[:, 0] + boxes[:, 2] > hs) or np.any(boxes[:, 1] + boxes[:, 3] > ws):
        raise InputError(f"view_boxes {boxes.tolist()} do not fit in the {hs}x{ws} frame")
    return boxes
