r"""One calibration file: arrays in ``.npz``, metadata in a JSON sidecar, cached by design hash.

``<name>.npz`` (loaded with ``allow_pickle=False``) holds

===============  ==================  ===========================================================
view_boxes       (K, 4) int64        ``y0, x0, h, w`` of every view on the sensor
homographies     (K, 3, 3) float64   centre-view → view coordinates (operator convention)
mask_images      (K, L, Hv, Wm) f32  calibrated per-band mask images, box coordinates
offsets          (K, L) float64      column where the view image's column 0 lands, min 0
gains            (L,) float64        radiometric gains (radiance = gain × reconstruction)
wavelengths      (L,) float64        band centres, nm
===============  ==================  ===========================================================

and, optionally (the "mask, then shift and smear" model,
:class:`~recon.operators.smeared.SmearedCassi`; files without them still load),

===============  ==================  ===========================================================
tap_start        (K, L) int64        first box column of each band's smear kernel
tap_weights      (K, L, T) float64   the kernels (zero-padded), from the dispersion fit
view_masks       (K, Hv, Wv) f32     every view's mask in view coordinates
smear_gains      (L,) float64        radiometric gains of that model
===============  ==================  ===========================================================

and, optionally (the footprint model, :mod:`~recon.calibration.footprint`: a sparse system
matrix :math:`A`, rows the boxes' pixels view-major, columns the target's texels band-major),

=================  ================  =========================================================
footprint_grid     (2,) int64        the target's texel grid (Ht, Wt): that model's cube grid
footprint_indptr   (K·Hv·Wm+1,) i64  CSR row pointers of :math:`A`
footprint_indices  (nnz,) int32      CSR columns, :math:`l H_t W_t + y W_t + x`
footprint_data     (nnz,) float32    the weights, >= 0
footprint_gains    (L,) float64      radiometric gains of that model
=================  ================  =========================================================

and, optionally (the mask images were deconvolved for diffraction: the shifted and smeared
models blur their measurement again, :class:`~recon.operators.blur.BlurredOperator`),

===============  ==================  ===========================================================
psf              (m, m) float32      the sensor's point-spread function, ``m`` odd, sum 1
===============  ==================  ===========================================================

and, optionally (views whose light begins before their offsets,
:mod:`~recon.calibration.extent`; the shifted model starts their view images earlier),

===============  ==================  ===========================================================
view_leads       (K,) int64          columns each view image starts before its offsets, >= 0
===============  ==================  ===========================================================

and, optionally (what the homographies cannot hold of each view's geometry, measured on the
checkerboard; :class:`~recon.operators.warp.DisplacementField` in view coordinates),

=================  =================  ========================================================
view_fields        (K, 2, T) float64  polynomial coefficients of each view's displacement
view_field_frames  (K, 4) float64     their frames (x_c, y_c, s_x, s_y)
=================  =================  ========================================================
and, optionally (the sensor's photon-transfer curve, :mod:`~recon.calibration.noise`),
===============  ==================  ===========================================================
noise            (2,) float64        ``[a, b]``: a raw pixel's variance a·DN + b (DN²)
===============  ==================  ===========================================================

and ``<name>.json`` holds ``design_hash``, ``cube_shape`` ([H, W, L], the API layout),
``view_ids``, ``captures`` (what it was made from) and ``created`` (UTC, ISO 8601).  Both files
are written atomically (image first, then sidecar); loading validates every field and shape.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from recon.calibration.dispersion import normalise_offsets, normalise_offsets_phase
from recon.calibration.geometry import to_view_coordinates
from recon.calibration.views import check_boxes, check_view_ids
from recon.errors import InputError
from recon.io.arrays import read_json_object

if TYPE_CHECKING:              # for the annotation only: SciPy loads when a footprint is used
    import scipy.sparse

FORMAT = "kaleidospec-calibration"
VERSION = 1
#: Calibration code version (part of the cache key, :func:`calibration_path`): bump it when the
#: capture renderer or the application's calibration steps (kaleidospec.calibrate) change.
CODE_VERSION = 13
_CODE_VERSION: str | None = None
ARRAY_FIELDS = ("view_boxes", "homographies", "mask_images", "offsets", "gains", "wavelengths")
#: Arrays a calibration may hold (saved only when set).
OPTIONAL_ARRAY_FIELDS = ("tap_start", "tap_weights", "view_masks", "smear_gains",
                         "footprint_grid", "footprint_indptr", "footprint_indices",
                         "footprint_data", "footprint_gains", "psf", "view_leads", "view_fields",
                         "view_field_frames", "noise")
_FOOTPRINT = ("footprint_grid", "footprint_indptr", "footprint_indices", "footprint_data")
JSON_FIELDS = ("design_hash", "cube_shape", "view_ids", "captures", "created")
_HASH_RE = re.compile(r"^[0-9A-Za-z_-]{1,128}$")
#: Same tolerance as the operators' offset snapping.
_SNAP = 1e-6


@dataclass
class Calibration:
    """A complete instrument calibration (see the module docstring for the fields).

    Construction validates shapes and values; bad input raises :class:`InputError`.
    """

    view_ids: tuple
    view_boxes: np.ndarray
    homographies: np.ndarray
    mask_images: np.ndarray
    offsets: np.ndarray
    gains: np.ndarray
    wavelengths: np.ndarray
    cube_shape: tuple
    design_hash: str | None = None
    captures: list = field(default_factory=list)
    created: str = ""
    tap_start: np.ndarray | None = None
    tap_weights: np.ndarray | None = None
    view_masks: np.ndarray | None = None
    smear_gains: np.ndarray | None = None
    footprint_grid: np.ndarray | None = None
    footprint_indptr: np.ndarray | None = None
    footprint_indices: np.ndarray | None = None
    footprint_data: np.ndarray | None = None
    footprint_gains: np.ndarray | None = None
    psf: np.ndarray | None = None
    view_leads: np.ndarray | None = None
    view_fields: np.ndarray | None = None
    view_field_frames: np.ndarray | None = None
    noise: np.ndarray | None = None

    def __post_init__(self):
        self.view_ids = check_view_ids(self.view_ids)
        k = len(self.view_ids)
        self.view_boxes = check_boxes(self.view_boxes, n_views=k)
        self.homographies = _array(self.homographies, "homographies", np.float64, (k, 3, 3))
        self.mask_images = _array(self.mask_images, "mask_images", np.float32, None, ndim=4)
        kk, n_bands, hv, wm = self.mask_images.shape
        if kk != k:
            raise InputError(f"mask_images has {kk} views, view_ids has {k}")
        if (hv, wm) != tuple(self.view_boxes[0, 2:]):
            raise InputError(f"mask_images are {hv}x{wm} but the view boxes are "
                             f"{self.view_boxes[0, 2]}x{self.view_boxes[0, 3]}")
        self.offsets = _array(self.offsets, "offsets", np.float64, (k, n_bands))
        self.gains = _array(self.gains, "gains", np.float64, (n_bands,))
        self.wavelengths = _array(self.wavelengths, "wavelengths", np.float64, (n_bands,))
        if np.any(self.wavelengths <= 0) or np.any(np.diff(self.wavelengths) <= 0):
            raise InputError("wavelengths must be positive and increasing")
        if np.min(self.offsets) < -_SNAP:
            raise InputError(f"offsets must be >= 0 (normalised), got min {self.offsets.min():g}")
        try:
            cs = tuple(int(v) for v in self.cube_shape)
        except (TypeError, ValueError):
            raise InputError(f"cube_shape must be [H, W, L], got {self.cube_shape!r}") from None
        if len(cs) != 3 or min(cs) < 1 or cs[2] != n_bands:
            raise InputError(f"cube_shape must be [H, W, L={n_bands}], got {list(cs)}")
        self.cube_shape = cs
        if self.design_hash is not None:
            self.design_hash = check_hash(self.design_hash)
        self.captures = [str(c) for c in self.captures]
        self._check_smeared()
        self._check_footprint()
        if self.view_leads is not None:
            leads = _array(self.view_leads, "view_leads", np.float64, (k,))
            if np.any(leads != np.round(leads)) or np.min(leads) < 0:
                raise InputError("view_leads must hold non-negative integers")
            if np.max(leads) >= self.view_shape[1]:
                raise InputError(f"view_leads up to {int(np.max(leads))} columns: longer than "
                                 f"the view ({self.view_shape[1]} columns)")
            self.view_leads = leads.astype(np.int64)
        self._check_fields()
        if self.noise is not None:
            from recon.calibration.noise import check_noise_model

            self.noise = check_noise_model(self.noise)
        if self.psf is not None:
            from recon.operators.blur import check_kernel

            self.psf = check_kernel(self.psf)
            self.psf /= self.psf.sum(dtype=np.float64)
        if not self.created:
            self.created = datetime.now(timezone.utc).isoformat(timespec="seconds")

    def _check_smeared(self) -> None:
        k, n_bands = self.offsets.shape
        if (self.tap_start is None) != (self.tap_weights is None):
            raise InputError("tap_start and tap_weights come together")
        if self.tap_start is None:
            if self.view_masks is not None or self.smear_gains is not None:
                raise InputError("view_masks and smear_gains need tap_start and tap_weights")
            return
        start = _array(self.tap_start, "tap_start", np.float64, (k, n_bands))
        if np.any(start != np.round(start)) or np.min(start) < 0:
            raise InputError("tap_start must hold non-negative integers")
        self.tap_start = start.astype(np.int64)
        self.tap_weights = _array(self.tap_weights, "tap_weights", np.float64, None, ndim=3)
        if self.tap_weights.shape[:2] != (k, n_bands) or self.tap_weights.shape[2] < 1:
            raise InputError(f"tap_weights has shape {self.tap_weights.shape}, expected "
                             f"({k}, {n_bands}, T)")
        if np.any(self.tap_weights < 0):
            raise InputError("tap_weights must be >= 0")
        hv, wv = self.view_shape
        wm = self.mask_images.shape[3]
        last = np.array([[np.max(np.nonzero(w)[0], initial=0) for w in row]
                         for row in self.tap_weights])
        if np.max(self.tap_start + last) + wv > wm:
            raise InputError(f"smear kernels reach column {int(np.max(self.tap_start + last))}:"
                             f" with view width {wv} they do not fit in boxes {wm} px wide")
        if self.view_masks is not None:
            self.view_masks = _array(self.view_masks, "view_masks", np.float32, (k, hv, wv))
        if self.smear_gains is not None:
            self.smear_gains = _array(self.smear_gains, "smear_gains", np.float64, (n_bands,))

    def _check_fields(self) -> None:
        if (self.view_fields is None) != (self.view_field_frames is None):
            raise InputError("view_fields and view_field_frames go together")
        if self.view_fields is None:
            return
        from recon.operators.warp import DisplacementField

        k = len(self.view_ids)
        c = np.asarray(self.view_fields, dtype=np.float64)
        if c.ndim != 3 or c.shape[:2] != (k, 2):
            raise InputError(f"view_fields must be (K={k}, 2, T), got shape {c.shape}")
        self.view_fields = c
        self.view_field_frames = _array(self.view_field_frames, "view_field_frames", np.float64,
                                        (k, 4))
        for i in range(k):
            DisplacementField(c[i], self.view_field_frames[i])     # validates

    def view_indices(self, view_ids=None) -> list[int]:
        """The indices in :attr:`view_ids` of the views ``view_ids`` (default: all of them).

        Raises
        ------
        InputError
            Invalid ids (:func:`~recon.calibration.views.check_view_ids`) or views the
            calibration does not hold.
        """
        ids = self.view_ids if view_ids is None else check_view_ids(view_ids)
        missing = [v for v in ids if v not in self.view_ids]
        if missing:
            raise InputError(f"views {missing} are not in the calibration (it has "
                             f"{list(self.view_ids)})")
        return [self.view_ids.index(v) for v in ids]

    def field(self, i: int):
        """View ``i``'s (index in ``view_ids``) :class:`~recon.operators.warp.DisplacementField`
        in view coordinates, or None when the calibration holds none."""
        if self.view_fields is None:
            return None
        from recon.operators.warp import DisplacementField

        return DisplacementField(self.view_fields[i], self.view_field_frames[i])

    def _check_footprint(self) -> None:
        given = [getattr(self, n) is not None for n in _FOOTPRINT]
        if not any(given):
            if self.footprint_gains is not None:
                raise InputError("footprint_gains needs the footprint matrix")
            return
        if not all(given):
            raise InputError(f"{', '.join(_FOOTPRINT)} come together")
        grid = _array(self.footprint_grid, "footprint_grid", np.int64, (2,))
        if np.min(grid) < 1:
            raise InputError(f"footprint_grid must be positive, got {grid.tolist()}")
        self.footprint_grid = grid
        k, n_bands = self.offsets.shape
        n_rows = k * int(self.view_boxes[0, 2]) * int(self.view_boxes[0, 3])
        ptr = _array(self.footprint_indptr, "footprint_indptr", np.int64, (n_rows + 1,))
        n_cols = n_bands * int(grid[0]) * int(grid[1])
        if n_cols > np.iinfo(np.int32).max:
            raise InputError(f"a footprint matrix of {n_cols} columns is too large")
        # int32 columns (as scipy's own CSR): half the file of int64.
        idx = _array(self.footprint_indices, "footprint_indices", np.int64, None, ndim=1)
        data = _array(self.footprint_data, "footprint_data", np.float32, idx.shape)
        if ptr[0] != 0 or ptr[-1] != idx.size or np.any(np.diff(ptr) < 0):
            raise InputError("footprint_indptr must rise from 0 to the number of weights")
        if idx.size and (idx.min() < 0 or idx.max() >= n_cols):
            raise InputError(f"footprint_indices must lie in [0, {n_cols})")
        idx = idx.astype(np.int32)
        if np.any(data < 0):
            raise InputError("footprint_data must be >= 0")
        self.footprint_indptr, self.footprint_indices, self.footprint_data = ptr, idx, data
        if self.footprint_gains is not None:
            self.footprint_gains = _array(self.footprint_gains, "footprint_gains", np.float64,
                                          (n_bands,))

    @property
    def has_footprint(self) -> bool:
        """Whether the footprint model's system matrix is present."""
        return self.footprint_indptr is not None

    def footprint_rows(self, index) -> "scipy.sparse.csr_matrix":
        """The footprint matrix's rows of the views at positions ``index`` (in that order),
        ``(len(index)·Hv·Wm, L·Ht·Wt)`` float32 CSR."""
        import scipy.sparse as sp

        if not self.has_footprint:
            raise InputError("the calibration has no footprint matrix (calibrate with the "
                             "comb captures)")
        n_px = int(self.view_boxes[0, 2]) * int(self.view_boxes[0, 3])
        n_cols = self.n_bands * int(self.footprint_grid[0]) * int(self.footprint_grid[1])
        m = sp.csr_matrix((self.footprint_data, self.footprint_indices, self.footprint_indptr),
                          shape=(self.n_views * n_px, n_cols))
        return sp.vstack([m[i * n_px:(i + 1) * n_px] for i in index], format="csr")

    @property
    def has_smeared(self) -> bool:
        """Whether the "mask, then shift and smear" model is complete (taps and view masks)."""
        return self.tap_start is not None and self.view_masks is not None

    @property
    def n_views(self) -> int:
        return len(self.view_ids)

    @property
    def n_bands(self) -> int:
        return int(self.wavelengths.size)

    @property
    def view_shape(self) -> tuple[int, int]:
        """(Hv, Wv): the undispersed view image inside a box of width Wm."""
        wv = self.mask_images.shape[3] - math.ceil(float(self.offsets.max()) - _SNAP)
        return int(self.mask_images.shape[2]), int(wv)

    def metadata(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "design_hash": self.design_hash,
                "cube_shape": list(self.cube_shape), "view_ids": list(self.view_ids),
                "captures": list(self.captures), "created": self.created}


def build_calibration(*, view_ids, view_boxes, box_homographies, mask_images, wavelengths,
                      dispersion, checker_dispersion, gains=None, design_hash=None,
                      captures=(), snap_px: float = 0.05, grid: str = "union",
                      phase: bool = False, band_positions=None, box_fields=None) -> Calibration:
    r"""Assemble a :class:`Calibration` from the results of the individual steps.

    Normalises the offsets (smallest 0, :func:`~recon.calibration.dispersion.normalise_offsets`),
    converts the box homographies (and the views' displacement fields, if given) to view
    coordinates at the checkerboard's wavelength
    (:func:`~recon.calibration.geometry.to_view_coordinates`) and sets the cube to the centre
    view's rows and the columns that the views code together (``grid``); every view image is
    :math:`H_v \times W_v`, :math:`W_v = W_m - \lceil\max o\rceil`.

    Parameters
    ----------
    view_ids : sequence of int
        Must contain 0 (the centre).
    view_boxes : (K, 4)
    box_homographies : (K, 3, 3)
        From :func:`~recon.calibration.geometry.view_homographies` (box coordinates).
    mask_images : (K, L, Hv, Wm)
        From :func:`~recon.calibration.mask.mask_images`.
    wavelengths : (L,)
    dispersion : (K, L)
        :math:`\varphi_k(\lambda_l)` relative to any reference (e.g. a
        :class:`~recon.calibration.dispersion.DispersionFit` evaluated at the bands).
    checker_dispersion : (K,)
        :math:`\varphi_k` at the checkerboard's wavelength, same reference.
    gains : (L,), optional
        Radiometric gains (ones when not yet calibrated).
    design_hash : str, optional
    captures : sequence of str
        Names of the captures used (recorded in the sidecar).
    snap_px : float
        Offsets within this distance of an integer are rounded to it.  It is below what a line
        centroid resolves, keeps integer shifts exact copies (no interpolation blur) and stops a
        measurement of 11.02 px for a true 11 px from costing the cube a column
        (:math:`W_v = W_m - \lceil\max o\rceil`).  0 disables it.
    phase : bool
        ``dispersion`` holds absolute line positions (box columns,
        :meth:`~recon.calibration.dispersion.DispersionFit.positions`): keep each view's
        sub-pixel phase (:func:`~recon.calibration.dispersion.normalise_offsets_phase`, whole
        columns removed per view) instead of shifting all offsets so that the smallest is 0.
    grid : {"union", "centre"}
        The reconstruction grid: ``"union"`` (default) the centre view's rows and every column
        that some view's mask codes (:func:`union_width`: the mirrored views see the scene
        under the centre's guard stripe), ``"centre"`` only the centre view's view image
        (:math:`W_v` columns; those scene columns are then missing from the model of the
        mirrored views).
    band_positions : (K, L, S), optional
        The same reference as ``dispersion``, sampled evenly across every band's wavelength
        interval (:func:`~recon.calibration.dispersion.band_positions`): normalised with the
        same shift, clipped to the box (``[0, ⌈max o⌉]``: light beyond it is not measured) and
        turned into smear kernels (``tap_start``, ``tap_weights``,
        :func:`~recon.operators.smeared.taps_from_positions`).  The view masks are recovered
        afterwards (:func:`~recon.calibration.mask.view_masks`).
    box_fields : sequence of DisplacementField, optional
        Each view's :func:`~recon.calibration.geometry.board_field` (box coordinates).
    """
    ids = check_view_ids(view_ids)
    if 0 not in ids:
        raise InputError("a calibration needs the centre view (id 0)")
    phi = np.asarray(dispersion, dtype=np.float64)
    if not 0.0 <= snap_px < 0.5:
        raise InputError(f"snap_px must be in [0, 0.5), got {snap_px}")
    if phase:
        offsets, shift = normalise_offsets_phase(phi)
    else:
        offsets, shift = normalise_offsets(phi)
    offsets = _snap(offsets, snap_px)
    chk = _snap(np.asarray(checker_dispersion, dtype=np.float64) - shift, snap_px)
    hv_ = to_view_coordinates(box_homographies, chk, centre=ids.index(0))
    masks = np.asarray(mask_images, dtype=np.float32)
    n_bands = np.asarray(wavelengths).size
    if masks.ndim != 4:
        raise InputError(f"mask_images must be (K, L, Hv, Wm), got shape {masks.shape}")
    wv = masks.shape[3] - math.ceil(float(offsets.max()) - _SNAP)
    if wv < 1:
        raise InputError(f"the dispersion span {offsets.max():.1f} px leaves no view width in "
                         f"boxes {masks.shape[3]} px wide")
    if grid not in ("union", "centre"):
        raise InputError(f"grid must be 'union' or 'centre', got {grid!r}")
    width = union_width(masks, offsets, hv_, wv) if grid == "union" else wv
    tap_start = tap_weights = None
    if band_positions is not None:
        from recon.operators.smeared import taps_from_positions

        bp = np.asarray(band_positions, dtype=np.float64)
        if bp.ndim != 3 or bp.shape[:2] != phi.shape:
            raise InputError(f"band_positions must be (K, L, S) with (K, L) = {phi.shape}, "
                             f"got shape {bp.shape}")
        shift = shift[:, None, None] if np.ndim(shift) else shift
        bp = np.clip(bp - shift, 0.0, math.ceil(float(offsets.max()) - _SNAP))
        tap_start, tap_weights = taps_from_positions(bp)
    fields = frames = None
    if box_fields is not None:
        if len(box_fields) != len(ids):
            raise InputError(f"box_fields has {len(box_fields)} entries for {len(ids)} views")
        # View column x_v is box column x_v + o_k at the board's wavelength.
        moved = [f.moved(-float(chk[k])) for k, f in enumerate(box_fields)]
        hv_, moved = _anchor_fields(hv_, moved, ids.index(0))
        fields = np.stack([f.coeffs for f in moved])
        frames = np.stack([f.frame for f in moved])
    return Calibration(view_ids=ids, view_boxes=view_boxes, homographies=hv_,
                       mask_images=masks, offsets=offsets,
                       gains=np.ones(n_bands) if gains is None else gains,
                       wavelengths=wavelengths, cube_shape=(masks.shape[2], width, n_bands),
                       design_hash=design_hash, captures=list(captures),
                       tap_start=tap_start, tap_weights=tap_weights, view_fields=fields,
                       view_field_frames=frames)


def _anchor_fields(homographies, fields, centre: int):
    r"""Keep the grid on the centre view's pixels, up to the fields' bend.

    With fields every view maps grid point :math:`g` to :math:`H_k g + d_k(H_k g)` (the centre
    :math:`g + d_0(g)`).  The affine part :math:`A` of :math:`d_0` (its terms of degree ≤ 1)
    would move and stretch the grid against the centre's pixels, where the truth and the
    offsets place it; it moves into the homographies instead: :math:`d_0 \leftarrow d_0 - A`,
    :math:`H_k \leftarrow H_k (I - A)` for the other views (to first order in the fields, as they
    are applied).
    """
    c0 = fields[centre]
    xc, yc, sx, sy = c0.frame
    # Terms in order 1, xi, eta, ...: A(x, y) = a + b (x - xc)/sx + c (y - yc)/sy.
    a, b, c = c0.coeffs[:, 0], c0.coeffs[:, 1], c0.coeffs[:, 2]
    lin = np.stack([b / sx, c / sy], axis=1)                         # (2, 2)
    off = a - lin @ np.array([xc, yc])
    i_minus_a = np.eye(3)
    i_minus_a[:2, :2] -= lin
    i_minus_a[:2, 2] -= off
    hs = np.array(homographies, dtype=np.float64)
    for k, h in enumerate(homographies):
        if k != centre:                 # the centre's map stays g + d_0(g)
            m = h @ i_minus_a
            hs[k] = m / m[2, 2]
    out = list(fields)
    out[centre] = c0.bend()
    return hs, out


def coded_columns(mask_images, offsets, view_width: int, level: float = 0.1) -> np.ndarray:
    r"""(K, 2) first and last view-image column that the mask codes in each view.

    View column :math:`x` of band :math:`l` lands on box column :math:`x + o_{k,l}`; a column
    is coded when, in some band, the mean of its mask-image column exceeds ``level`` × the
    view's typical open column mean (the median over the columns with any light).
    """
    c = np.asarray(mask_images, dtype=np.float32)
    o = np.asarray(offsets, dtype=np.float64)
    k, n_bands, _, wm = c.shape
    out = np.empty((k, 2), dtype=np.int64)
    x = np.arange(view_width)
    for i in range(k):
        prof = c[i].mean(axis=1)                                   # (L, Wm)
        lit = prof[prof > 0]
        ref = float(np.median(lit)) if lit.size else 0.0
        coded = np.zeros(view_width, dtype=bool)
        for l in range(n_bands):
            cols = np.clip(np.round(x + o[i, l]).astype(np.int64), 0, wm - 1)
            coded |= prof[l, cols] > level * ref
        on = np.nonzero(coded)[0]
        out[i] = (on[0], on[-1]) if on.size else (0, view_width - 1)
    return out


def union_width(mask_images, offsets, homographies, view_width: int,
                limit: float = 1.5) -> int:
    r"""Width of the reconstruction grid that holds every view's coded columns.

    The grid starts at the centre view's column 0 (the first column its mask codes, at the
    band with the smallest offset).  A mirrored view's mask codes the scene columns under the
    centre's guard stripe instead of the centre's first ones: every view's coded rectangle
    (:func:`coded_columns` × all rows), pulled back to centre coordinates through
    :math:`H_k^{-1}`, must lie on the grid, so the grid is as wide as the largest pulled-back
    column (at least ``view_width``, at most ``limit`` × it, against a wild homography).
    Columns a view sees left of the centre's column 0 stay off the grid (a pixel or two of
    shear at the top and bottom views).
    """
    hs = np.asarray(homographies, dtype=np.float64)
    c = np.asarray(mask_images)
    hv = c.shape[2]
    cols = coded_columns(c, offsets, view_width)
    right = float(view_width - 1)
    for i in range(hs.shape[0]):
        x0, x1 = (float(v) for v in cols[i])
        pts = np.array([[x0, 0.0], [x0, hv - 1.0], [x1, 0.0], [x1, hv - 1.0]])
        inv = np.linalg.inv(hs[i])
        q = pts @ inv[:, :2].T + inv[:, 2]
        right = max(right, float(np.max(q[:, 0] / q[:, 2])))
    # A quarter-pixel tolerance: the homographies are good to a few tenths of a pixel.
    return int(min(math.ceil(right - 0.25) + 1, math.floor(limit * view_width)))


def _snap(o: np.ndarray, tol: float) -> np.ndarray:
    r = np.round(o)
    return np.where(np.abs(o - r) < tol, r, o)


def check_hash(design_hash) -> str:
    """A design hash usable in a file name (letters, digits, ``_``, ``-``)."""
    h = str(design_hash)
    if not _HASH_RE.match(h):
        raise InputError(f"design hash {h!r} is not a plain token (letters, digits, _ and -)")
    return h


def _paths(path) -> tuple[Path, Path]:
    p = Path(path)
    if p.suffix.lower() in (".npz", ".json"):
        p = p.with_suffix("")
    return p.with_name(p.name + ".npz"), p.with_name(p.name + ".json")


def code_version() -> str:
    """The calibration code's version: :data:`CODE_VERSION` and a digest of the sources of
    :mod:`recon.calibration`, so that a cached calibration made by other code is not reused.

    :data:`CODE_VERSION` covers what the digest cannot see: bump it when the capture renderer
    or the application layer that runs the steps (``kaleidospec.calibrate``) changes what a
    calibration holds.
    """
    global _CODE_VERSION
    if _CODE_VERSION is None:
        import hashlib

        h = hashlib.sha256()
        for p in sorted(Path(__file__).resolve().parent.glob("*.py")):
            h.update(p.name.encode())
            h.update(p.read_bytes())
        _CODE_VERSION = f"{CODE_VERSION}-{h.hexdigest()[:10]}"
    return _CODE_VERSION


def calibration_path(cache_dir, design_hash, version: str | None = None) -> Path:
    """``<cache_dir>/calibration-<design_hash>-v<version>.npz`` (sidecar: same name,
    ``.json``); ``version`` defaults to :func:`code_version`."""
    v = code_version() if version is None else check_hash(version)
    return Path(cache_dir) / f"calibration-{check_hash(design_hash)}-v{v}.npz"


def save_calibration(path, cal: Calibration, *, protect=()) -> tuple[Path, Path]:
    """Write ``cal`` as ``<path>.npz`` + ``<path>.json``, each atomically.

    Returns
    -------
    (npz_path, json_path)
    """
    from recon.io.atomic import atomic_path, write_text

    if not isinstance(cal, Calibration):
        raise InputError(f"expected a Calibration, got {type(cal).__name__}")
    npz, side = _paths(path)
    text = json.dumps(cal.metadata(), indent=2, sort_keys=True) + "\n"
    with atomic_path(npz, protect=protect) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **{name: getattr(cal, name) for name in ARRAY_FIELDS
                            + OPTIONAL_ARRAY_FIELDS if getattr(cal, name) is not None})
    write_text(side, text, protect=protect)
    return npz, side


def load_calibration(path) -> Calibration:
    """Read and validate a calibration written by :func:`save_calibration`.

    Raises
    ------
    InputError
        Missing file, missing or malformed field (named in the message), inconsistent shapes.
    """
    npz, side = _paths(path)
    for p in (npz, side):
        if not p.is_file():
            raise InputError(f"{p}: calibration file not found")
    meta = read_json_object(side)
    if meta.get("format", FORMAT) != FORMAT:
        raise InputError(f"{side}: not a calibration sidecar (format {meta.get('format')!r})")
    for name in JSON_FIELDS:
        if name not in meta:
            raise InputError(f"{side}: missing field {name!r}")
    try:
        with np.load(npz, allow_pickle=False) as z:
            missing = [n for n in ARRAY_FIELDS if n not in z.files]
            if missing:
                raise InputError(f"{npz}: missing field {missing[0]!r}")
            arrays = {n: z[n] for n in ARRAY_FIELDS + OPTIONAL_ARRAY_FIELDS if n in z.files}
    except InputError:
        raise
    except (OSError, ValueError) as exc:
        raise InputError(f"{npz}: not a readable calibration archive: {exc}") from None
    try:
        return Calibration(view_ids=meta["view_ids"], cube_shape=meta["cube_shape"],
                           design_hash=meta["design_hash"], captures=meta["captures"] or [],
                           created=str(meta["created"]), **arrays)
    except InputError as exc:
        raise InputError(f"{npz}: {exc}") from None


#: What a cached calibration must hold (:func:`recon.io.cache.read_npz`'s ``expect``).
_EXPECT = {"view_boxes": (np.integer, 2), "homographies": (np.floating, 3),
           "mask_images": (np.float32, 4), "offsets": (np.floating, 2),
           "gains": (np.floating, 1), "wavelengths": (np.floating, 1)}


def save_cached(cache_dir, cal: Calibration) -> Path:
    """Write ``cal`` into the cache folder (:func:`calibration_path` of its design hash): the
    ``.npz`` a checked cache entry (:func:`recon.io.cache.write_npz`: a checksum, the design
    hash, :func:`code_version` and the sidecar's metadata inside), then the JSON sidecar, each
    atomically.  Returns the ``.npz`` path."""
    from recon.io import cache
    from recon.io.atomic import write_text

    if not isinstance(cal, Calibration) or cal.design_hash is None:
        raise InputError("only a Calibration with its design hash is cached")
    npz, side = _paths(calibration_path(cache_dir, cal.design_hash))
    cache.write_npz(npz, {name: getattr(cal, name) for name in ARRAY_FIELDS
                          + OPTIONAL_ARRAY_FIELDS if getattr(cal, name) is not None},
                    kind="calibration", design_hash=cal.design_hash, version=code_version(),
                    meta=cal.metadata())
    write_text(side, json.dumps(cal.metadata(), indent=2, sort_keys=True) + "\n")
    return npz


def is_cached(cache_dir, design_hash) -> bool:
    """Whether the cache holds an entry for the design that :func:`load_cached` will most
    likely load: the sidecar there, the ``.npz`` readable with this design's hash and
    :func:`code_version` in its header (its arrays and checksum are checked on load)."""
    from recon.io.cache import read_header

    npz, side = _paths(calibration_path(cache_dir, design_hash))
    return side.is_file() and read_header(npz, kind="calibration",
                                          design_hash=check_hash(design_hash),
                                          version=code_version()) is not None


def load_cached(cache_dir, design_hash) -> Calibration | None:
    """The cached calibration of a design, or ``None`` when there is none yet, or when the entry
    fails a check (:func:`recon.io.cache.read_npz`: cut short, garbled, another design's or code
    version's, written without a checksum, a missing or mismatched sidecar): that entry is
    removed with one warning line, and the caller calibrates again."""
    from recon.io import cache

    npz, side = _paths(calibration_path(cache_dir, design_hash))
    got = cache.read_npz(npz, kind="calibration", design_hash=check_hash(design_hash),
                         version=code_version(), expect=_EXPECT, meta=True, companions=[side])
    if got is None:
        return None
    arrays, meta = got
    try:
        side_meta = read_json_object(side)
        if side_meta.get("design_hash") != design_hash:
            raise InputError("its sidecar is missing or names another design")
        meta = meta if isinstance(meta, dict) else {}
        return Calibration(view_ids=meta["view_ids"], cube_shape=meta["cube_shape"],
                           design_hash=meta["design_hash"], captures=meta["captures"] or [],
                           created=str(meta["created"]),
                           **{n: a for n, a in arrays.items() if n in ARRAY_FIELDS
                              + OPTIONAL_ARRAY_FIELDS})
    except (InputError, KeyError, TypeError) as exc:
        cache.discard(npz, f"not a valid calibration: {exc}", companions=[side])
        return None


def _array(a, name, dtype, shape, ndim=None) -> np.ndarray:
    try:
        arr = np.ascontiguousarray(a, dtype=dtype)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a numeric array") from None
    if shape is not None and arr.shape != tuple(shape):
        raise InputError(f"{name} has shape {arr.shape}, expected {tuple(shape)}")
    if ndim is not None and arr.ndim != ndim:
        raise InputError(f"{name} must be {ndim}-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} contains non-finite values")
    return arr
