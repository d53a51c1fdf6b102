r"""From a calibration to the forward operator and to the per-view measurements of a raw frame.

:func:`operator_from_calibration` builds :class:`recon.operators.CalibratedCassi` with

.. math:: g_k = \sum_l C_{k,l} \odot S_{o_{k,l}}\big(W_k f_l\big),

:math:`C` the calibrated mask images, :math:`o` the normalised offsets (absolute columns in the
view's box) and :math:`W_k` the homography warp (the identity for the centre view; where the
calibration holds the views' displacement fields, :func:`~recon.calibration.board_field`, every
view's homography bent by its field, the centre's too, so that the grid is the board's plane
undistorted), each view's image started ``view_leads`` columns before its offsets where the
calibration holds them (:mod:`recon.calibration.extent`) — the "shifted-mask" model — or, when
the calibration holds it, the "mask, then shift and smear" model
:class:`recon.operators.smeared.SmearedCassi`

.. math:: g_k = \sum_l D_{k,l}\big(M_k \odot W_k f_l\big),

:math:`M_k` the view masks and :math:`D_{k,l}` the bands' smear kernels.  The shifted-mask model
multiplies a smeared mask image by a shifted scene, while the instrument masks the scene first
and then smears each band over its dispersion; where the scene varies within a band's smear
(a few pixels for 25 nm bands in the blue) only the second is right.  The "footprint" model
is the system matrix measured with comb targets (:mod:`recon.calibration.footprint`),

.. math:: g = A f, \qquad f \text{ on the target's texel grid } (H_t, W_t),

with every pixel's own weights on the texels it sees: it needs no geometry or smear model, but
its cube lives on the comb target's grid, not on the centre view's.  When the calibration's mask
images were deconvolved for diffraction (``cal.psf`` is set), the shifted and smeared models
blur their measurement with that PSF again (:class:`recon.operators.blur.BlurredOperator`):
the lens blurs the coded, dispersed image, after the mask; the footprint model measured the
blur with everything else.
:func:`measurements` cuts the matching (K, Hv, Wm) stack out of a raw frame with the same boxes.
"""

from __future__ import annotations

import numpy as np

from recon.calibration.store import Calibration
from recon.calibration.views import crop
from recon.errors import InputError


def _select(cal: Calibration, view_ids) -> list[int]:
    if not isinstance(cal, Calibration):
        raise InputError(f"expected a Calibration, got {type(cal).__name__}")
    return cal.view_indices(view_ids)


#: The calibrated forward models: "footprint" (the system matrix measured with comb targets),
#: "smeared" (mask, then shift and smear) and "shifted" (per-band mask images times the
#: shifted scene); "auto" is the first of these that the calibration holds.
MODELS = ("auto", "footprint", "smeared", "shifted")


def resolve_model(cal: Calibration, model: str = "auto") -> str:
    """``"footprint"``, ``"smeared"`` or ``"shifted"``: the model ``model`` names for this
    calibration."""
    if not isinstance(cal, Calibration):
        raise InputError(f"expected a Calibration, got {type(cal).__name__}")
    if model not in MODELS:
        raise InputError(f"the calibrated model must be one of {', '.join(MODELS)}, got {model!r}")
    if model == "auto":
        return "footprint" if cal.has_footprint else "smeared" if cal.has_smeared else "shifted"
    if model == "footprint" and not cal.has_footprint:
        raise InputError("the calibration has no footprint matrix: recalibrate with the comb "
                         "captures (kaleidospec: --model footprint), or use another model")
    if model == "smeared" and not cal.has_smeared:
        raise InputError("the calibration has no view masks and smear kernels (made by older "
                         "code): recalibrate, or use the 'shifted' model")
    return model


def operator_from_calibration(cal: Calibration, view_ids=None, model: str = "auto",
                              band_scale=None):
    """The calibrated forward operator for some of the calibrated views.

    Parameters
    ----------
    cal : Calibration
    view_ids : sequence of int, optional
        Views to use, in this order (default: all of the calibration's).
    model : {"auto", "footprint", "smeared", "shifted"}
        See :data:`MODELS` and the module docstring.
    band_scale : (L,) array_like, optional
        Multiplies band ``l`` of the model (e.g. the inverse radiometric gains).

    Returns
    -------
    recon.operators.SparseMatrixOperator, SmearedCassi, CalibratedCassi or BlurredOperator
        ``(L, H, W) -> (K, Hv, Wm)`` with ``(H, W, L) = cal.cube_shape``, or
        ``(H, W) = cal.footprint_grid`` for the footprint model; the shifted and smeared
        models inside a :class:`~recon.operators.blur.BlurredOperator` when ``cal.psf`` is set.
    """
    kind = resolve_model(cal, model)
    op = _unblurred(cal, view_ids, kind, band_scale)
    if cal.psf is None or kind == "footprint":
        return op
    from recon.operators.blur import BlurredOperator

    return BlurredOperator(op, cal.psf)


def _unblurred(cal: Calibration, view_ids, kind: str, band_scale):
    """:func:`operator_from_calibration` of the resolved model ``kind`` without the sensor's
    PSF."""
    from recon.calibration.extent import led_view
    from recon.operators.calibrated import CalibratedCassi
    from recon.operators.smeared import SmearedCassi
    from recon.operators.sparse import SparseMatrixOperator
    from recon.operators.warp import HomographyWarp

    idx = _select(cal, view_ids)
    h, w, n_bands = cal.cube_shape
    view_shape = cal.view_shape
    scale = np.ones(n_bands) if band_scale is None else np.asarray(band_scale, np.float64)
    if scale.shape != (n_bands,) or not np.all(np.isfinite(scale)):
        raise InputError(f"band_scale must be {n_bands} finite numbers")
    if kind == "footprint":
        ht, wt = (int(v) for v in cal.footprint_grid)
        a = cal.footprint_rows(idx)
        # Band l's columns are l·Ht·Wt ... (l+1)·Ht·Wt - 1: scale each weight by its band's.
        a.data *= scale[a.indices // (ht * wt)].astype(np.float32)
        return SparseMatrixOperator(a, (n_bands, ht, wt),
                                    (len(idx),) + tuple(cal.view_boxes[0, 2:]))

    def warp(m, shape, i, lead=0):
        # With the views' displacement fields the grid is the board's plane seen through the
        # centre's homography, undistorted: every view, the centre too, bends it by its field.
        if cal.view_fields is None:
            if np.allclose(m, np.eye(3), atol=1e-9) and shape == (h, w):
                return None
            return HomographyWarp(m, (h, w), shape)
        return HomographyWarp(m, (h, w), shape, view_field=cal.field(i).moved(lead))

    if kind == "smeared":
        warps = [warp(cal.homographies[i], view_shape, i) for i in idx]
        # A band's scale multiplies its kernel: D_kl (M_k * W_k f_l) is linear in the weights.
        return SmearedCassi(cal.view_masks[idx], cal.tap_start[idx],
                            cal.tap_weights[idx] * scale[None, :, None], warps=warps,
                            cube_shape=(n_bands, h, w), width=cal.mask_images.shape[3])
    # Views whose light begins before their offsets start their images earlier
    # (recon.calibration.extent): each view its own width.
    warps, offsets = [], []
    for i in idx:
        lead = 0 if cal.view_leads is None else int(cal.view_leads[i])
        m, o = led_view(cal.homographies[i], cal.offsets[i], lead)
        warps.append(warp(m, (view_shape[0], view_shape[1] + lead), i, lead))
        offsets.append(o)
    # The scale goes into the operator's interpolation weights: a scaled copy of the used
    # views' mask images would be (K, L, Hv, Wm) float32 more (0.3 GB for 5 paper views).
    # Indexing with a contiguous run of views is a slice, not a copy.
    masks = (cal.mask_images[idx[0]:idx[-1] + 1] if idx == list(range(idx[0], idx[-1] + 1))
             else cal.mask_images[idx])
    return CalibratedCassi(masks, np.stack(offsets), warps=warps, cube_shape=(n_bands, h, w),
                           band_scale=None if band_scale is None else scale)


def check_design(cal: Calibration, metadata: dict | None, what: str = "raw frame") -> None:
    """Raise :class:`InputError` when a frame's ``design_hash`` differs from the calibration's.

    A missing hash on either side is accepted (real captures may carry none).
    """
    if not metadata:
        return
    h = metadata.get("design_hash")
    if h is not None and cal.design_hash is not None and str(h) != cal.design_hash:
        raise InputError(f"{what} was taken with design {h}, but the calibration is for design "
                         f"{cal.design_hash}")


def measurements(frame, cal: Calibration, view_ids=None, metadata: dict | None = None,
                 dark=None) -> np.ndarray:
    """Cut the per-view measurements out of a raw frame.

    Parameters
    ----------
    frame : (H, W) array_like
        Full-sensor raw frame (DN).
    cal : Calibration
    view_ids : sequence of int, optional
        Same meaning and order as for :func:`operator_from_calibration`.
    metadata : dict, optional
        The frame's sidecar; its ``design_hash`` must match the calibration's.
    dark : (H, W) array_like, optional
        Dark frame subtracted first.

    Returns
    -------
    (K, Hv, Wm) float32
    """
    check_design(cal, metadata)
    idx = _select(cal, view_ids)
    f = np.asarray(frame, dtype=np.float32)
    if f.ndim != 2:
        raise InputError(f"a raw frame must be 2-D, got shape {f.shape}")
    if dark is not None:
        d = np.asarray(dark, dtype=np.float32)
        if d.shape != f.shape:
            raise InputError(f"dark frame shape {d.shape} != frame shape {f.shape}")
        f = f - d
    boxes = cal.view_boxes[idx]
    if (np.any(boxes[:, 0] + boxes[:, 2] > f.shape[0])
            or np.any(boxes[:, 1] + boxes[:, 3] > f.shape[1])):
        raise InputError(f"frame {f.shape} is smaller than the calibrated sensor area")
    return np.ascontiguousarray(np.stack([crop(f, b) for b in boxes]), dtype=np.float32)


def read_measurements(path, cal: Calibration, view_ids=None, dark=None) -> np.ndarray:
    """:func:`measurements` of a raw frame file (``.exr`` + JSON sidecar)."""
    from recon.io.raw import read_raw

    frame, meta = read_raw(path)
    return measurements(frame, cal, view_ids, metadata=meta, dark=dark)
