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
from scipy.ndimage import uniform_filter1d

from recon.errors import InputError
from recon.view_ids import ALL_VIEWS, VIEW_FLIPS, VIEW_GRID, VIEW_ORDER  # noqa: F401


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


def find_view_boxes(white, view_ids=(0, 1, 2, 3, 4), dark=None, grid: int | None = None,
                    level: float = 0.25, margin: int = 0, margin_x: int | None = None
                    ) -> np.ndarray:
    r"""Find each view's rectangle on the sensor from a uniform-white capture.

    The boxes follow the layout found in the capture: every view's lit region (across all
    bands), with its own placement; they are clipped to the sensor and never overlap.

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
    grid : int, optional
        Views per side of the layout.  ``None`` (default) infers it from the capture: 3 (the
        kaleidoscope) when the lit region splits into several views, 1 (a single full-frame
        view, the traditional CASSI) when it is one lit rectangle.  Give it only for a layout
        whose views all touch in both directions, which cannot be told from a single view.
    level : float
        Edge threshold as a fraction of the profile's plateau.  Lower than half maximum because
        an edge row or column of the random mask may have far fewer than half its cells open
        (a 2×2-cell mask row of 45 cells is below 25 % open with probability ~5e-4); a blurred
        edge then moves out by a fraction of the blur radius, which ``margin`` covers.
    margin : int
        Pixels added on every side of every box (e.g. to keep a blurred rim), as far as the
        sensor allows.
    margin_x : int, optional
        Pixels added on the left and right of every box instead of ``margin``, *at most*: it is
        reduced as far as needed for the boxes to stay apart and on the sensor (the rows of
        views may touch, the dispersed columns have a gap).  A view's outermost columns are
        lit by one band only and fall under ``level``; this keeps them in the box.

    Returns
    -------
    boxes : (K, 4) int64
        ``y0, x0, h, w`` per view; all share one size ``(Hv, Wm) = (h, w)``.

    Notes
    -----
    *Layout.*  With :math:`I` the (stacked) white image, the column profile is
    :math:`p(x) = \max_y \bar I(y, x)` with :math:`\bar I` the mean of :math:`I` over a short
    window along y (it averages the random mask): every column that any view lights is at that
    view's plateau, however many views share the column, and a gap between views is dark.  Runs
    of :math:`p > \text{level}\cdot p_{95}` are the lit columns; the cells of neighbouring runs
    meet at the darkest column between them (the gap), the outer cells reach the sensor's
    edges.  A run holding several touching views (the rows of the kaleidoscope may touch) is
    split into equal parts: its length over the views' size (the other runs of the same axis,
    or of the other axis, views being about square) says how many.  Cells are numbered from
    the one whose lit run holds the sensor's centre (the optical axis: the centre view).
    Rows likewise.

    *Boxes.*  Inside its cell, each view's lit extent is where the cell's mean profiles exceed
    ``level`` × their plateau.  All boxes get the common size (the largest extent plus the
    margins), placed about the extent, shifted (never shrunk) to stay inside the view's cell,
    hence on the sensor and apart from the others; only when a cell is smaller than the common
    size (views that touch, their shared rim lit on both sides) are the boxes trimmed to the
    smallest cell; if only the margins do not fit, the box falls back to its symmetric place,
    clipped to the sensor, and overlaps are reported.

    Raises
    ------
    InputError
        Bad shapes, a frame without lit views, a layout that cannot be resolved, a view whose
        light runs off the sensor (its lit extent cut short by the sensor's edge), or boxes that
        would overlap.
    """
    ids = check_view_ids(view_ids)
    if grid is not None and int(grid) < 1:
        raise InputError(f"grid must be >= 1, got {grid}")
    if not 0.0 < level < 1.0:
        raise InputError(f"level must be in (0, 1), got {level}")
    if int(margin) < 0:
        raise InputError(f"margin must be >= 0, got {margin}")
    if margin_x is not None and int(margin_x) < 0:
        raise InputError(f"margin_x must be >= 0, got {margin_x}")
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
    gmax = 3 if grid is None else int(grid)
    rows, cols = _layout(img, gmax, level, explicit=grid is not None)

    lit = np.empty((len(ids), 4), dtype=np.int64)
    cells = np.empty((len(ids), 4), dtype=np.int64)
    for i, v in enumerate(ids):
        r, c = VIEW_GRID[v] if gmax == 3 else divmod(v, gmax)
        if r >= gmax or c >= gmax:
            raise InputError(f"view {v} is outside a {gmax}x{gmax} grid")
        if r not in rows or c not in cols:
            raise InputError(f"view {v} is dark in the white capture (no lit "
                             f"{'row' if r not in rows else 'column'} of views where it lies)")
        (ry0, ry1), (cx0, cx1) = rows[r], cols[c]
        cell = img[ry0:ry1, cx0:cx1].astype(np.float64)
        y0, y1 = _lit_extent(cell.mean(axis=1), level)
        x0, x1 = _lit_extent(cell.mean(axis=0), level)
        if y1 <= y0 or x1 <= x0:
            raise InputError(f"view {v} is dark in the white capture")
        lit[i] = (ry0 + y0, cx0 + x0, y1 - y0, x1 - x0)
        cells[i] = (ry0, cx0, ry1 - ry0, cx1 - cx0)
    _check_on_sensor(lit, ids, (hs, ws))

    hv = int(lit[:, 2].max()) + 2 * int(margin)
    wl = int(lit[:, 3].max())
    widths = ([wl + 2 * mx for mx in range(int(margin_x), -1, -1)] if margin_x is not None
              else [wl + 2 * int(margin)])
    # Touching views: the rim that two neighbours share (a partly lit line, the blur) may put a
    # view's lit extent a line beyond its equal share of the run; the boxes are then trimmed to
    # the smallest cell, so that no sensor pixel is in two boxes.
    ch, cw = int(cells[:, 2].min()), int(cells[:, 3].min())
    if lit[:, 2].max() > ch:
        hv = ch
    if lit[:, 3].max() > cw:
        widths = [cw]
    for wm in widths:
        boxes = _place(lit, cells, hv, wm, (hs, ws))
        if boxes is not None:
            return boxes
    boxes = _place(lit, None, hv, widths[-1], (hs, ws), ids)
    _check_disjoint(boxes, ids)
    return boxes


def _layout(img, gmax, level, explicit):
    """The lit rows and columns of views: ``{grid index: (start, stop)}`` per axis."""
    hs, ws = img.shape
    # Average the mask along the other axis over a few cells, then take the brightest line:
    # a row of the sensor crossed by one view is as bright as one crossed by three.
    k = max(5, min(hs, ws) // 40)
    py = uniform_filter1d(img, k, axis=1, mode="constant").max(axis=1).astype(np.float64)
    px = uniform_filter1d(img, k, axis=0, mode="constant").max(axis=0).astype(np.float64)
    runs_y, runs_x = _runs(py, level, "rows"), _runs(px, level, "columns")
    ny, nx = _run_counts(runs_y, runs_x, hs, ws, gmax, explicit)
    return (_cells(py, runs_y, ny, gmax, "rows"), _cells(px, runs_x, nx, gmax, "columns"))


def _runs(profile, level, axis):
    """Runs [start, stop) where ``profile`` exceeds ``level`` × its 95th percentile."""
    peak = float(np.percentile(profile, 95))
    if not peak > 0:
        raise InputError(f"the white capture is dark (no lit {axis})")
    on = profile > level * peak
    edges = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    runs = [(int(a), int(b)) for a, b in zip(np.nonzero(edges == 1)[0],
                                              np.nonzero(edges == -1)[0])]
    # Isolated bright lines (hot columns, noise) are not views.
    longest = max(b - a for a, b in runs)
    return [(a, b) for a, b in runs if b - a >= longest / 4]


def _view_len(runs, size):
    """One view's extent along an axis: the shortest run not cut by the sensor's edge."""
    inner = [b - a for a, b in runs if a > 0 and b < size]
    return float(min(inner or [b - a for a, b in runs]))


def _run_counts(runs_y, runs_x, hs, ws, gmax, explicit):
    """How many touching views every run holds (rows, columns)."""
    if len(runs_y) == 1 and len(runs_x) == 1:
        if explicit:
            # Views touching in both directions look like one view: trust the given grid.
            return [gmax], [gmax]
        ly, lx = runs_y[0][1] - runs_y[0][0], runs_x[0][1] - runs_x[0][0]
        # Views are about square: a run much longer than the other holds touching views.
        return ([int(np.clip(round(ly / lx), 1, gmax))],
                [int(np.clip(round(lx / ly), 1, gmax))])
    out = []
    for runs, size, other, osize in ((runs_y, hs, runs_x, ws), (runs_x, ws, runs_y, hs)):
        if len(runs) > 1:
            s = _view_len(runs, size)
            out.append([int(np.clip(round((b - a) / s), 1, gmax)) for a, b in runs])
        else:
            # One run across views seen apart on the other axis: one view, or a whole line of
            # touching ones (then about gmax times a view's size; views need not be square).
            ratio = (runs[0][1] - runs[0][0]) / _view_len(other, osize)
            out.append([gmax if ratio >= 2.0 else 1])
    return out[0], out[1]


def _cells(profile, runs, counts, gmax, axis):
    """``{grid index: (start, stop)}``: runs split into their views, cut at the gaps."""
    size = profile.size
    n = sum(counts)
    if n > gmax:
        raise InputError(f"found {n} lit runs of views along the {axis} of the white capture, "
                         f"expected at most {gmax}")
    cuts = [0]
    for (a0, b0), (a1, b1) in zip(runs[:-1], runs[1:]):
        # The darkest stretch between two runs is the gap between their views: cut at its middle.
        seg = profile[b0:a1]
        low = seg <= seg.min() + 0.02 * float(np.percentile(profile, 95))
        e = np.diff(np.concatenate([[0], low.astype(np.int8), [0]]))
        st, sp = np.nonzero(e == 1)[0], np.nonzero(e == -1)[0]
        j = int(np.argmax(sp - st))
        cuts.append(b0 + (int(st[j]) + int(sp[j])) // 2)
    cuts.append(size)
    spans, lit = [], []
    for i, ((a, b), c) in enumerate(zip(runs, counts)):
        if c == 1:
            spans.append((cuts[i], cuts[i + 1]))
            lit.append((a, b))
            continue
        # Touching views: equal parts of the lit run (the first and last reach the cuts).
        edges = np.round(np.linspace(a, b, c + 1)).astype(int)
        for j in range(c):
            lo = cuts[i] if j == 0 else int(edges[j])
            hi = cuts[i + 1] if j == c - 1 else int(edges[j + 1])
            spans.append((lo, hi))
            lit.append((int(edges[j]), int(edges[j + 1])))
    if n == gmax:
        first = 0
    else:
        # Fewer lines of views than the grid: the centre one is lit where the optical axis
        # meets the sensor (its middle).
        mid = 0.5 * size
        hit = [j for j, (a, b) in enumerate(lit) if a <= mid < b]
        if not hit:
            raise InputError(f"found {n} lit runs of views along the {axis} of the white "
                             f"capture and none at the sensor's centre: cannot tell the centre "
                             f"view (expected {gmax}, or the centre's line of views)")
        first = gmax // 2 - hit[0]
        if first < 0 or first + n > gmax:
            raise InputError(f"found {n} lit runs of views along the {axis} of the white "
                             f"capture, placed off a {gmax}-view grid about the sensor's centre")
    return {first + j: s for j, s in enumerate(spans)}


def _check_on_sensor(lit, ids, sensor):
    """A view whose lit extent touches the sensor's edge *and* falls short of the others' is cut
    off by the sensor: part of it is lost, so it cannot be calibrated."""
    hs, ws = sensor
    for ax, (lo_name, hi_name), size in ((0, ("top", "bottom"), hs), (1, ("left", "right"), ws)):
        ext = lit[:, 2 + ax]
        full = int(ext.max())
        tol = max(2, int(round(0.02 * full)))
        for i, v in enumerate(ids):
            a, n = int(lit[i, ax]), int(ext[i])
            side = lo_name if a == 0 else hi_name if a + n == size else None
            if side is not None and n < full - tol:
                raise InputError(
                    f"view {v}'s light runs off the sensor's {side} edge: {n} of {full} px "
                    f"{'rows' if ax == 0 else 'columns'} on the sensor; it cannot be "
                    f"calibrated (leave view {v} out or change the design)")


def _place(lit, cells, hv, wm, sensor, ids=None):
    """Boxes of size (hv, wm) about the lit extents.

    With ``cells``: each box centred on its extent, then shifted to lie inside its cell (so the
    boxes are disjoint and on the sensor); ``None`` if some cell is smaller than the box.
    Without: centred, then shifted onto the sensor (InputError, naming the view, if the box is
    larger than the sensor).
    """
    hs, ws = sensor
    boxes = np.empty_like(lit)
    for i, (y0, x0, h, w) in enumerate(lit):
        # Centred on the lit extent (the odd pixel goes after).
        by, bx = y0 - (hv - h) // 2, x0 - (wm - w) // 2
        if cells is not None:
            cy, cx, ch, cw = cells[i]
            lo_y, hi_y = max(cy, 0), min(cy + ch, hs) - hv
            lo_x, hi_x = max(cx, 0), min(cx + cw, ws) - wm
        else:
            lo_y, hi_y, lo_x, hi_x = 0, hs - hv, 0, ws - wm
        if lo_y > hi_y or lo_x > hi_x:
            if cells is not None:
                return None
            raise InputError(f"view {ids[i]}'s box ({hv}x{wm}) is larger than the sensor "
                             f"{hs}x{ws}; use a smaller margin")
        boxes[i] = (min(max(by, lo_y), hi_y), min(max(bx, lo_x), hi_x), hv, wm)
    return boxes


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


def overlapping_pair(boxes) -> tuple[int, int] | None:
    """The first pair ``(i, j)``, ``i < j``, of ``y0, x0, h, w`` boxes that overlap, or None."""
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            if (a[0] < b[0] + b[2] and b[0] < a[0] + a[2]
                    and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]):
                return i, j
    return None


def _check_disjoint(boxes: np.ndarray, ids) -> None:
    pair = overlapping_pair(boxes)
    if pair is not None:
        i, j = pair
        raise InputError(f"boxes of views {ids[i]} and {ids[j]} overlap: {boxes[i]} and "
                         f"{boxes[j]}")


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
