r"""Geometric calibration: a homography from the centre view to every other view.

A checkerboard is captured at one wavelength (550 nm); every view shows it through its part of
the random mask and, for the mirrored views, flipped.  For every view (box on the sensor):

1. *Unmask*: divide the checkerboard capture by the white capture of the same wavelength,
   :math:`r = I_\text{checker} / I_\text{white}`, where the mask is open, and fill the chrome
   holes by normalised convolution,
   :math:`\hat r = (G * (v\,r)) / (G * v)` with :math:`v` the open-pixel indicator and
   :math:`G` a Gaussian.
2. *Unflip*: reverse the view's known mirror axes so that the board looks like the centre's and
   OpenCV numbers its corners in the same order.
3. ``cv2.findChessboardCorners`` (or the sector-based detector, or either on the view
   upsampled; a detection whose corners no homography of the grid fits is passed over,
   :func:`grid_misfit`) then ``cv2.cornerSubPix``; corners are put in a canonical order
   (row-major from the top-left) and mapped back through the flip to box coordinates.
4. ``cv2.findHomography`` (least squares over all corners) from an ideal board to the view:
   :math:`B_k`.  The filled holes leave the corners jagged, and ``cornerSubPix`` is then biased
   by up to 1–2 px, so by default :math:`B_k` is refined by ECC image alignment
   (``cv2.findTransformECCWithMask``, homography motion) of an ideal, anti-aliased board to the
   view, evaluated on the open pixels only (:func:`board_homography`).  On synthetic masked
   boards this brings the error from ~2 px to ~0.1 px.
5. :math:`H_k = B_k B_0^{-1}`: a 3×3 matrix with
   :math:`(x_k, y_k, 1)^\top \sim H_k (x_0, y_0, 1)^\top`, the convention of
   ``cv2.warpPerspective`` and of :class:`recon.operators.HomographyWarp`.
6. Optionally (:func:`board_field`) what :math:`B_k` misses: the prism deviates a ray by an
   amount that depends on its field angle, so a view's image of a flat target bends along x
   (on the ``paper`` design up to ±0.4 px from the best homography, the same for every view).
   ECC aligns the board, seen through :math:`B_k`, tile by tile (2×2 squares, translation
   only) and a quadratic :class:`~recon.operators.warp.DisplacementField` is fitted to the
   tiles' shifts; between two views it does not cancel, because the mirrored views see it
   reversed.

Optionally :func:`refine_homography` corrects :math:`H_k` with dense optical flow (Farneback or
DIS) between the centre image and the view image pulled back to the centre.

The matrices here are in *box* coordinates (pixel (0, 0) = the box's top-left) at the capture
wavelength.  The prism shifts each band's image inside the box, so the operator's view
coordinates differ by that band's offset; :func:`to_view_coordinates` converts.
"""

from __future__ import annotations

import cv2
import numpy as np

from recon.calibration.views import (VIEW_FLIPS, as_frame_stack, check_boxes, check_view_ids,
                                     crop)
from recon.errors import InputError

_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)


def unmask(checker: np.ndarray, white: np.ndarray, open_level: float = 0.25,
           sigma: float = 1.5, return_valid: bool = False):
    r"""Remove the mask from a checkerboard view: ratio to the white, holes filled.

    Parameters
    ----------
    checker, white : (h, w) arrays
        The same view's crop of the checkerboard and the white capture (same wavelength).
    open_level : float
        A pixel counts as open where the white exceeds this fraction of the view's white level
        (the 99th percentile).
    sigma : float
        Gaussian width (px) of the normalised convolution that fills closed cells.

    return_valid : bool
        Also return the open-pixel indicator :math:`v` (bool).

    Returns
    -------
    (h, w) float32
        :math:`r` where open, :math:`(G * (v r))/(G * v)` elsewhere (0 where no open pixel is
        near).
    valid : (h, w) bool, only with ``return_valid``
    """
    c = np.asarray(checker, dtype=np.float64)
    wh = np.asarray(white, dtype=np.float64)
    top = float(np.percentile(wh, 99))
    if not top > 0:
        raise InputError("the white capture is dark in this view")
    valid = wh > open_level * top
    r = np.where(valid, c / np.where(valid, wh, 1.0), 0.0)
    v = valid.astype(np.float64)
    num = cv2.GaussianBlur(r, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    den = cv2.GaussianBlur(v, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    filled = np.where(den > 1e-3, num / np.maximum(den, 1e-3), 0.0)
    out = np.where(valid, r, filled).astype(np.float32)
    return (out, valid) if return_valid else out


def _flip(img: np.ndarray, axes) -> np.ndarray:
    for a in axes:
        img = np.flip(img, axis=a)
    return np.ascontiguousarray(img)


def _to_u8(img: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(img, [1, 99])
    if not hi > lo:
        raise InputError("the checkerboard view has no contrast")
    return np.clip((img - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def find_corners(img: np.ndarray, pattern_size, flips=(), win: int | None = None) -> np.ndarray:
    """Checkerboard inner corners of an (unmasked) view image, in its own pixel coordinates.

    Detection tries, in turn, ``cv2.findChessboardCorners`` (adaptive threshold) and
    ``cv2.findChessboardCornersSB`` on the view, then both on the view upsampled 2× (bicubic):
    small squares (≈ 10 px, 5 mask cells, whose hole-filled edges are ragged) are found by the
    sector-based detector or after upsampling where the classic one fails.  A detection whose
    corners no homography of the board's grid fits (:func:`grid_misfit`: the classic detector
    sometimes reports ragged boards with their corners out of order) is passed over.

    Parameters
    ----------
    img : (h, w) array
    pattern_size : (cols, rows)
        Inner corners per row and per column (OpenCV's ``patternSize``), from the
        checkerboard capture's sidecar (the target's datasheet).
    flips : tuple of int
        Axes to reverse before detection (the view's mirror flips), so that the order of the
        corners matches the centre view's.
    win : int, optional
        Half-size of the ``cornerSubPix`` search window; default about a third of the corner
        spacing, at most 5 (a window reaching the next corner biases the refinement).

    Returns
    -------
    (rows*cols, 2) float64
        (x, y) per corner, row-major from the top-left of the *unflipped* board.

    Raises
    ------
    InputError
        If the board is not found.
    """
    h, w = img.shape
    u8 = _to_u8(_flip(np.asarray(img, dtype=np.float32), flips))
    size = (int(pattern_size[0]), int(pattern_size[1]))
    if min(size) < 3:
        raise InputError(f"pattern_size {size}: OpenCV needs more than 2 inner corners per side")
    corners = _detect(u8, size)
    if corners is None:
        big = cv2.resize(u8, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
        corners = _detect(big, size)
        if corners is not None:
            # Pixel centres: x_big = 2 x + 0.5.
            corners = (corners - 0.5) / 2.0
    if corners is None:
        raise InputError(f"checkerboard with {size[0]}x{size[1]} inner corners not found "
                         f"in a {h}x{w} px view")
    corners = np.ascontiguousarray(corners.reshape(-1, 1, 2).astype(np.float32))
    spacing = corner_spacing(corners, size)
    half = int(win) if win is not None else int(np.clip(round(spacing / 3.0), 2, 5))
    corners = cv2.cornerSubPix(u8, corners, (half, half), (-1, -1), _SUBPIX_CRITERIA)
    # OpenCV 5 returns (N, 2), 4.x (N, 1, 2).
    pts = np.asarray(corners, dtype=np.float64).reshape(size[1], size[0], 2)
    # OpenCV may start from any end of the board: make it row-major from the top-left.
    if pts[:, -1, 0].mean() < pts[:, 0, 0].mean():
        pts = pts[:, ::-1]
    if pts[-1, :, 1].mean() < pts[0, :, 1].mean():
        pts = pts[::-1]
    pts = pts.reshape(-1, 2).copy()
    if 1 in flips:
        pts[:, 0] = (w - 1) - pts[:, 0]
    if 0 in flips:
        pts[:, 1] = (h - 1) - pts[:, 1]
    return pts


def corner_spacing(corners, pattern_size) -> float:
    """Median distance between neighbouring corners (along rows and columns) of (N, 2) or
    (K, N, 2) corners, row-major boards of ``pattern_size`` (cols, rows)."""
    cols, rows = int(pattern_size[0]), int(pattern_size[1])
    grid = np.asarray(corners, dtype=np.float64).reshape(-1, rows, cols, 2)
    return float(np.median(np.concatenate([
        np.linalg.norm(np.diff(grid, axis=2), axis=3).ravel(),
        np.linalg.norm(np.diff(grid, axis=1), axis=3).ravel()])))


#: Largest r.m.s. distance, in corner spacings, of a detection's corners from the best
#: homography image of the board's grid (:func:`grid_misfit`).  Boards found in blurred,
#: hole-filled 78 px views (``small`` reduced, f/60) fit to 0.02–0.17; the classic detector
#: has also reported boards whose corners were out of order, at 0.60 and 1.18.
GRID_MISFIT_MAX = 0.3


def grid_misfit(corners, size) -> float:
    r"""How far detected corners are from a board: the r.m.s. distance of the corners
    :math:`c_{ij}` from :math:`H(i, j)`, the least-squares homography image of the grid, over
    the median spacing of neighbouring corners.

    A board seen through any homography fits to its corners' noise; corners that a detector
    reported out of order, or off the board, do not.
    """
    cols, rows = int(size[0]), int(size[1])
    c = np.asarray(corners, dtype=np.float64).reshape(rows * cols, 2)
    gx, gy = np.meshgrid(np.arange(cols, dtype=np.float64), np.arange(rows, dtype=np.float64))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    h, _ = cv2.findHomography(grid, c, 0)
    if h is None:
        return np.inf
    fit = cv2.perspectiveTransform(grid[None], h)[0]
    spacing = corner_spacing(c, size)
    if not spacing > 0:
        return np.inf
    return float(np.sqrt(np.mean(np.sum((fit - c) ** 2, axis=1)))) / spacing


def _detect(u8: np.ndarray, size) -> np.ndarray | None:
    """(N, 2) float64 corners from the classic detector, else the sector-based one, or None.

    A detection whose corners are not a board (:func:`grid_misfit` above
    :data:`GRID_MISFIT_MAX`) counts as none: the next detector is tried."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    for find in (lambda: cv2.findChessboardCorners(u8, size, flags=flags),
                 lambda: cv2.findChessboardCornersSB(u8, size)):
        ok, corners = find()
        if ok and corners is not None:
            pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
            if grid_misfit(pts, size) <= GRID_MISFIT_MAX:
                return pts
    return None


def view_homographies(checker, white, view_boxes, view_ids, pattern_size,
                      dark=None, sigma: float = 1.5, method: str = "ecc",
                      refine: str | None = None, return_corners: bool = False,
                      return_fields: bool = False):
    r"""Homographies from the centre view's box to every view's box.

    Parameters
    ----------
    checker : (H, W) or (N, H, W) array_like
        Checkerboard capture(s) at one wavelength (averaged).
    white : (H, W) or (N, H, W) array_like
        White capture(s) at the same wavelength.
    view_boxes : (K, 4) array_like
        ``y0, x0, h, w`` per view (see :func:`recon.calibration.views.find_view_boxes`).
    view_ids : sequence of int
        Ids of the boxes; must include 0 (the centre).
    pattern_size : (cols, rows)
        Inner corners of the board.
    dark : array_like, optional
        Dark frame subtracted from both captures.
    sigma : float
        Hole-filling Gaussian width (px).
    method : {"ecc", "corners"}
        ``"ecc"`` (default) refines each view's board homography by ECC alignment with an ideal
        board (:func:`board_homography`); ``"corners"`` uses the detected corners only.
    refine : {None, "farneback", "dis"}
        Optional optical-flow refinement (:func:`refine_homography`).
    return_corners : bool
        Also return the (K, N, 2) detected corners (box coordinates).
    return_fields : bool
        Also return each view's :func:`board_field` (box coordinates; ECC boards only).

    Returns
    -------
    H : (K, 3, 3) float64
        :math:`H_k` maps centre-box :math:`(x, y, 1)` to view-box coordinates; ``H`` of the
        centre is the identity.
    corners : (K, N, 2) float64, only with ``return_corners``
    fields : list of DisplacementField or None, only with ``return_fields``
        ``None`` for all views when any view's field could not be measured.
    """
    ids = check_view_ids(view_ids)
    if 0 not in ids:
        raise InputError("geometric calibration needs the centre view (id 0)")
    if method not in ("ecc", "corners"):
        raise InputError(f"method must be 'ecc' or 'corners', got {method!r}")
    if refine not in (None, "farneback", "dis"):
        raise InputError(f"refine must be None, 'farneback' or 'dis', got {refine!r}")
    chk = as_frame_stack(checker, "checkerboard capture").mean(axis=0)
    wht = as_frame_stack(white, "white capture").mean(axis=0)
    if chk.shape != wht.shape:
        raise InputError(f"checkerboard {chk.shape} and white {wht.shape} captures differ in shape")
    if dark is not None:
        d = as_frame_stack(dark, "dark frame").mean(axis=0)
        if d.shape != chk.shape:
            raise InputError(f"dark frame shape {d.shape} != capture shape {chk.shape}")
        chk, wht = chk - d, wht - d
    boxes = check_boxes(view_boxes, chk.shape, len(ids))
    unmasked = [unmask(crop(chk, b), crop(wht, b), sigma=sigma, return_valid=True)
                for b in boxes]
    images = [u[0] for u in unmasked]
    corners = np.stack([find_corners(im, pattern_size, VIEW_FLIPS[v])
                        for im, v in zip(images, ids)])
    # One ideal board for all views: B_k B_0^-1 needs a common board frame.
    square = board_square_px(corners, pattern_size)
    boards = [board_homography(im, valid, cor, pattern_size, square, ecc=(method == "ecc"))
              for (im, valid), cor in zip(unmasked, corners)]
    c0 = ids.index(0)
    inv0 = np.linalg.inv(boards[c0])
    hs = np.empty((len(ids), 3, 3), dtype=np.float64)
    for k in range(len(ids)):
        if k == c0:
            hs[k] = np.eye(3)
            continue
        m = boards[k] @ inv0
        if refine is not None:
            m = refine_homography(images[c0], images[k], m, method=refine)
        hs[k] = m / m[2, 2]
    out = (hs,) + ((corners,) if return_corners else ())
    if return_fields:
        fields = [board_field(im, valid, b, pattern_size, square)
                  for (im, valid), b in zip(unmasked, boards)] if method == "ecc" else [None]
        out += (None if any(f is None for f in fields) else fields,)
    return out if len(out) > 1 else hs


def board_template(pattern_size, square_px: int = 16, parity: int = 0,
                   oversample: int = 4) -> np.ndarray:
    r"""An ideal anti-aliased checkerboard of (cols+1)×(rows+1) squares.

    Square :math:`(u, v)` covers :math:`[u s, (u+1) s) \times [v s, (v+1) s)` (pixel centres at
    integers), so inner corner :math:`(i, j)`, :math:`1 \le i \le` cols, lies at
    :math:`(i s, j s)`.  Square (0, 0) is white (1) for ``parity`` 0, black (0) for 1.
    """
    cols, rows = int(pattern_size[0]), int(pattern_size[1])
    s = int(square_px)
    off = (np.arange(oversample) + 0.5) / oversample - 0.5
    yy, xx = np.mgrid[0:(rows + 1) * s, 0:(cols + 1) * s].astype(np.float64)
    acc = np.zeros(yy.shape)
    for dy in off:
        for dx in off:
            acc += (np.floor((xx + dx) / s) + np.floor((yy + dy) / s) + parity) % 2 == 0
    return (acc / oversample ** 2).astype(np.float32)


def board_square_px(corners, pattern_size) -> int:
    """Ideal-board square size: 1.3 × the median corner spacing of (K, N, 2) or (N, 2) corners.

    A board sampled a little finer than the view warps well under bilinear interpolation;
    much coarser or much finer ones alias.
    """
    return max(8, int(round(1.3 * corner_spacing(corners, pattern_size))))


def board_homography(img: np.ndarray, valid: np.ndarray, corners: np.ndarray, pattern_size,
                     square_px: int | None = None, ecc: bool = True) -> np.ndarray:
    r"""Homography :math:`B` from the ideal board (:func:`board_template`) to a view image.

    Starts from the least-squares fit to the detected ``corners`` (row-major, as from
    :func:`find_corners`).  With ``ecc`` it is refined by ECC alignment
    (``cv2.findTransformECCWithMask``, homography motion) in the direction that never
    interpolates the masked capture: the *view* is the template, restricted to its open pixels
    ``valid``, and the ideal board is warped onto it through :math:`B` — the correlation is
    evaluated exactly where the mask let light through.  (Aligning the other way, or aligning
    hole-filled images, biases :math:`B` by a few tenths of a pixel.)  If ECC does not converge
    the corner fit is returned.

    Parameters
    ----------
    img, valid : (h, w) arrays
        Unmasked view and open-pixel indicator (:func:`unmask` with ``return_valid``).
    corners : (N, 2)
    pattern_size : (cols, rows)
    square_px : int, optional
        Square size of the ideal board (default :func:`board_square_px` of ``corners``).  Views
        whose :math:`B` are combined must use the same value.
    ecc : bool
    """
    cols, rows = int(pattern_size[0]), int(pattern_size[1])
    pts = np.asarray(corners, dtype=np.float64)
    s = int(square_px) if square_px is not None else board_square_px(pts, pattern_size)
    gx, gy = np.meshgrid(np.arange(1, cols + 1) * s, np.arange(1, rows + 1) * s)
    ideal = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float64)
    b, _ = cv2.findHomography(ideal, pts, 0)
    if b is None:
        raise InputError("no homography fits the detected checkerboard corners")
    b = b / b[2, 2]
    if not ecc:
        return b
    im = np.asarray(img, dtype=np.float32)
    board = _ideal_board(im, b, pattern_size, s)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 300, 1e-8)
    w0 = np.linalg.inv(b)
    try:
        # gaussFiltSize 1: smoothing would mix closed cells into the open pixels.
        _, w = cv2.findTransformECCWithMask(im, board, np.asarray(valid, dtype=np.uint8),
                                            np.ones(board.shape, np.uint8),
                                            (w0 / w0[2, 2]).astype(np.float32),
                                            cv2.MOTION_HOMOGRAPHY, criteria, 1)
    except cv2.error:
        return b
    m = np.linalg.inv(np.asarray(w, dtype=np.float64))
    return m / m[2, 2]


def _ideal_board(im: np.ndarray, board_h: np.ndarray, pattern_size, square_px: int) -> np.ndarray:
    """:func:`board_template` with the view's colour in its top-left square (that square
    compared with its right-hand neighbour, both seen through ``board_h``)."""
    s = int(square_px)
    centres = apply_homography(board_h, [[0.5 * s, 0.5 * s], [1.5 * s, 0.5 * s]])
    vals = [cv2.getRectSubPix(im, (3, 3), (float(x), float(y))).mean() for x, y in centres]
    return board_template(pattern_size, s, parity=0 if vals[0] > vals[1] else 1)


def board_field(img: np.ndarray, valid: np.ndarray, board_h, pattern_size, square_px: int,
                tile: int = 2, degree: int = 2, min_open: float = 0.25, min_snr: float = 2.0):
    r"""What a board homography :math:`B` misses of a view: a smooth displacement field.

    The ideal board (:func:`board_template`) is warped onto the view through :math:`B`; every
    tile of ``tile`` × ``tile`` squares is aligned with the view by ECC (translation only, on
    the open pixels ``valid``), and a :class:`~recon.operators.warp.DisplacementField` of total
    degree ``degree`` is fitted to the tiles' shifts at their centres, so that the board's
    point :math:`t` lies at :math:`B t + d(B t)` in the view.  A tile whose open pixels cover
    less than ``min_open`` of it is left out.  The field is kept only where its bend (the part
    of degree ≥ 2, rms over the tiles) stands ``min_snr`` times above the tiles' scatter about
    the fit (the residuals' rms with the fit's degrees of freedom taken out): a bend the board
    does not resolve would only add the tiles' noise to the model (``paper``, 16 tiles: bend
    0.17–0.20 px, 2.3–3.7 times the scatter; ``small``, 16 tiles: 0.08–0.11 px, 1.1–2.2 times;
    the 78 px views of the golden test, 12 tiles: 0.06–0.10 px, 1.5–2.9 times — in the last
    two :func:`view_homographies` keeps none).

    Returns
    -------
    DisplacementField or None
        In the view image's coordinates; ``None`` when fewer than twice the field's terms of
        tiles could be aligned (a small board) or the bend is not resolved.
    """
    from recon.operators.warp import DisplacementField

    cols, rows = int(pattern_size[0]), int(pattern_size[1])
    s = int(square_px)
    im = np.asarray(img, dtype=np.float32)
    h, w = im.shape
    b = np.asarray(board_h, dtype=np.float64)
    board = _ideal_board(im, b, pattern_size, s)
    pred = cv2.warpPerspective(board, b, (w, h), flags=cv2.INTER_LINEAR, borderValue=-1.0)
    usable = (np.asarray(valid, dtype=bool) & (pred >= 0)).astype(np.uint8)
    pred = np.maximum(pred, 0.0)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-6)
    points, shifts = [], []
    for ty in range(0, rows + 1, tile):
        for tx in range(0, cols + 1, tile):
            x1, y1 = min(tx + tile, cols + 1), min(ty + tile, rows + 1)
            quad = apply_homography(b, [[tx * s, ty * s], [x1 * s, ty * s], [x1 * s, y1 * s],
                                        [tx * s, y1 * s]])
            m = np.zeros((h, w), np.uint8)
            cv2.fillConvexPoly(m, np.round(quad).astype(np.int32), 1)
            area = int(m.sum())
            m &= usable
            if area == 0 or int(m.sum()) < min_open * area:
                continue
            warp = np.eye(2, 3, dtype=np.float32)
            try:
                # pred(x + t) ~ view(x): the board lies at -t from where B puts it.
                _, warp = cv2.findTransformECCWithMask(im, pred, m, np.ones((h, w), np.uint8),
                                                       warp, cv2.MOTION_TRANSLATION, criteria, 1)
            except cv2.error:
                continue
            points.append(quad.mean(axis=0))
            shifts.append((-float(warp[0, 2]), -float(warp[1, 2])))
    n_terms = len(DisplacementField.terms(degree))
    if len(points) < 2 * n_terms:
        return None
    points, shifts = np.array(points), np.array(shifts)
    field = DisplacementField.fit(points, shifts, degree, frame=(0.5 * w, 0.5 * h, 0.5 * w,
                                                                0.5 * h))
    resid = shifts - np.stack(field(*points.T), axis=1)
    scatter = np.sqrt(np.sum(resid ** 2) / (resid.size - 2 * n_terms))
    bend = np.stack(field.bend()(*points.T), axis=1)
    bend = np.sqrt(np.mean((bend - bend.mean(axis=0)) ** 2))
    return field if bend >= min_snr * scatter else None


def refine_homography(centre: np.ndarray, view: np.ndarray, matrix, method: str = "farneback",
                      step: int = 4, border: int = 8) -> np.ndarray:
    r"""Correct a homography with dense optical flow.

    The view is pulled back onto the centre grid with the current :math:`H`
    (``cv2.warpPerspective`` with ``WARP_INVERSE_MAP``); the flow :math:`u` from the centre
    image to that pulled-back image gives, at every centre pixel :math:`p`, a better
    correspondence :math:`p \mapsto H(p + u(p))`; a least-squares homography through those
    correspondences (on a grid of step ``step``, away from the border) is returned.

    Parameters
    ----------
    centre, view : 2-D arrays
        Unmasked images of the centre view and of view :math:`k` (box coordinates).
    matrix : (3, 3)
        Current centre → view homography.
    method : {"farneback", "dis"}
    step, border : int
        Sampling grid step and excluded border (px) for the fit.

    Returns
    -------
    (3, 3) float64
    """
    m = np.asarray(matrix, dtype=np.float64)
    h, w = centre.shape
    a = _to_u8(np.asarray(centre, dtype=np.float32))
    back = cv2.warpPerspective(np.asarray(view, dtype=np.float32), m, (w, h),
                               flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    b = _to_u8(back)
    if method == "farneback":
        flow = cv2.calcOpticalFlowFarneback(a, b, None, 0.5, 3, 15, 5, 5, 1.1, 0)
    elif method == "dis":
        dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        flow = dis.calc(a, b, None)
    else:
        raise InputError(f"unknown optical-flow method {method!r}")
    ys, xs = np.mgrid[border:h - border:step, border:w - border:step]
    src = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    f = flow[ys.ravel(), xs.ravel()].astype(np.float64)
    # Only textured pixels carry flow information; flat regions just follow the smoothing.
    gy, gx = np.gradient(a.astype(np.float64))
    tex = np.hypot(gx, gy)[ys.ravel(), xs.ravel()]
    keep = tex > np.percentile(tex, 50)
    if keep.sum() < 8:
        return m
    dst = apply_homography(m, src[keep] + f[keep])
    r, _ = cv2.findHomography(src[keep], dst, 0)
    return m if r is None else r / r[2, 2]


def apply_homography(matrix, points) -> np.ndarray:
    r"""Map (N, 2) points (x, y) through a 3×3 homography: :math:`\pi(H (x, y, 1)^\top)`."""
    m = np.asarray(matrix, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    q = p @ m[:, :2].T + m[:, 2]
    return q[:, :2] / q[:, 2:3]


def to_view_coordinates(box_homographies, offsets_at_capture, centre: int = 0) -> np.ndarray:
    r"""Convert box-coordinate homographies to the operator's view coordinates.

    In the operator, view pixel column :math:`x_v` of band :math:`l` lands on box column
    :math:`x_v + o_{k,l}` (``offsets`` normalised so that the smallest is 0).  A board captured
    at a wavelength where the offsets are :math:`o_k` therefore has
    :math:`H^\text{view}_k = T(-o_k)\, H^\text{box}_k\, T(o_0)` with :math:`T(t)` the
    translation by :math:`t` along x.

    Parameters
    ----------
    box_homographies : (K, 3, 3)
        From :func:`view_homographies`.
    offsets_at_capture : (K,)
        :math:`o_k` at the checkerboard's wavelength, same view order.
    centre : int
        Index of the centre view in that order.

    Returns
    -------
    (K, 3, 3) float64
    """
    hb = np.asarray(box_homographies, dtype=np.float64)
    o = np.asarray(offsets_at_capture, dtype=np.float64)
    if hb.ndim != 3 or hb.shape[1:] != (3, 3) or o.shape != (hb.shape[0],):
        raise InputError(f"need (K, 3, 3) homographies and (K,) offsets, got {hb.shape}, "
                         f"{o.shape}")
    if not 0 <= centre < hb.shape[0]:
        raise InputError(f"centre index {centre} out of range for {hb.shape[0]} views")
    out = np.empty_like(hb)
    t0 = _tx(o[centre])
    for k in range(hb.shape[0]):
        m = _tx(-o[k]) @ hb[k] @ t0
        out[k] = m / m[2, 2]
    return out


def _tx(t: float) -> np.ndarray:
    return np.array([[1.0, 0.0, t], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
