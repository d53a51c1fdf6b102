r"""The exact (oracle) forward operator of a design: the simulator's own linear map.

Every element between the diffuser and the sensor is specular and the sensor is linear before
noise, so the expected raw frame of a cube :math:`f` on the ground-truth grid (the centre view's
:math:`v \times v` square, :func:`sim.frame.ground_truth`) is, in DN at ``radiance_scale`` 1,

.. math:: \bar g(p) = \sum_l q_l\, (A_l f_l)(p),

with :math:`A_l` the band's sparse transport matrix (:mod:`sim.transport`: which diffuser texel
every sensor sample sees, with the mirrors', mask's and prism's throughput) and :math:`q_l` the
sensor's DN per unit irradiance in band :math:`l` (QE, pixel area, exposure, band width, ADC
gain; :func:`sim.sensor.mean_electrons`).  :class:`TransportOperator` is that map restricted to
the views' rectangles, ``(L, v, v) -> (K, v, v)``, with its exact adjoint and row norms.  So
``frame / radiance_scale`` cut into the view rectangles (:func:`oracle_measurements`) is the
oracle's measurement, and the only differences from a rendered frame are noise, quantisation
and the sensor's Airy blur (not modelled here: 0.3 px for the ``small`` design, 1.65 px for
``paper``).  This is the reference for "reconstruction from calibration is within 1 dB of the
exact operator": calibration has to recover what :math:`A_l` holds (mask, dispersion per view,
the mirror geometry, vignetting) from captures.

``inversion=False`` composes every view with the mirror flips of its grid position
(:math:`A_{k,l} F_k`), so every view sees the scene upright: the same masks and dispersion
without the dispersion inversion of the mirrored views (paper Fig. 8c), a hypothetical system.

Memory: the transport entries of the views (about ``views × v² × spp`` per band): ~25 MB for the
``small`` design with 5 views, several GB for ``paper``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from recon.errors import InputError
from recon.operators.sparse import SparseMatrixOperator

__all__ = ["TransportOperator", "oracle_operator", "oracle_measurements", "band_gains"]

VIEW_ORDER = (0, 1, 2, 3, 4, 5, 6, 7, 8)


def _view_ids(n_views, design) -> tuple[int, ...]:
    try:
        n = int(n_views)
    except (TypeError, ValueError):
        raise InputError(f"n_views must be an integer 1..9, got {n_views!r}") from None
    if not 1 <= n <= 9 or n != n_views:
        raise InputError(f"n_views must be an integer 1..9, got {n_views!r}")
    ids = VIEW_ORDER[:n]
    missing = [v for v in ids if v not in design.views]
    if missing:
        raise InputError(f"view(s) {missing} are not traced by this design (views "
                         f"{list(design.views)}); widen its 'views' field")
    return ids


def band_gains(design, wavelengths=None) -> np.ndarray:
    """(L,) DN per unit sensor irradiance of each band (:func:`sim.sensor.mean_electrons` of a
    unit image, over the ADC gain ``full_well_e / max_dn``)."""
    from sim.sensor import mean_electrons

    wl = design.wavelengths if wavelengths is None else np.asarray(wavelengths, np.float64)
    one = np.zeros((1, 1, wl.size), np.float32)
    out = np.empty(wl.size)
    for l in range(wl.size):
        one[:] = 0.0
        one[0, 0, l] = 1.0
        out[l] = float(mean_electrons(one, design, wl)[0, 0])
    return out * design.max_dn / design.full_well_e


class TransportOperator(SparseMatrixOperator):
    r"""The simulator's expected frame restricted to some views, ``(L, v, v) -> (K, v, v)``.

    Parameters
    ----------
    matrices : list of L scipy.sparse matrices, each (K·v·v, H·W)
        :math:`q_l A_l` restricted to the views' rectangles (rows: view-major, row-major),
        placed side by side as one band-major matrix.
    cube_shape : (L, H, W)
    out_shape : (K, v, v)
    """

    def __init__(self, matrices, cube_shape, out_shape):
        super().__init__(sp.hstack(list(matrices), format="csr"), cube_shape, out_shape)

    def __repr__(self):
        return f"TransportOperator({self.ishape} -> {self.oshape})"


def _flip_perm(h: int, w: int, axes) -> np.ndarray:
    """Texel index permutation of a flip of an (h, w) image along ``axes``."""
    idx = np.arange(h * w).reshape(h, w)
    for a in axes:
        idx = np.flip(idx, axis=a)
    return np.ascontiguousarray(idx).ravel()


def oracle_operator(design, n_views: int, *, inversion: bool = True, spp: int = 4,
                    seed: int = 0):
    """The exact operator of ``design`` for its first ``n_views`` views (module notes).

    Parameters
    ----------
    design : sim.design.Design
        Its ``views`` must include the first ``n_views`` ids (0..n-1).
    n_views : int
        1..9, views in the order centre, left, right, top, bottom, corners.
    inversion : bool
        ``False``: every view composed with its mirror flips (no dispersion inversion).
    spp : int
        Samples per pixel of the transport (the scene frames' default, so the same cache).
    seed : int
        Random seed of the transport's trace.  0 is the trace the frames are rendered with:
        the operator then knows which texel and wavelength each of a pixel's ``spp`` rays met
        (the frame's Monte Carlo draw).  Another seed traces the same optics afresh: the
        instrument's physics without that draw (``tools/exp_calibration_gap.py``).

    Returns
    -------
    TransportOperator
    """
    from sim.design import VIEW_GRID
    from sim.transport import load_or_build

    ids = _view_ids(n_views, design)
    v = design.view_size_px
    wl = design.wavelengths
    tr = load_or_build(design, (v, v), wl, spp=spp, seed=seed, sampling="box")
    hs, ws = tr.sensor
    # Sensor pixel -> output row (view-major), -1 outside the chosen views.
    where = np.full(hs * ws, -1, dtype=np.int64)
    for k, vid in enumerate(ids):
        r0, c0, h, w = design.view_rect(vid)
        rr, cc = np.mgrid[r0:r0 + h, c0:c0 + w]
        where[(rr * ws + cc).ravel()] = k * v * v + np.arange(v * v)
    q = band_gains(design, wl)
    ntex = v * v
    perms = {}
    for k, vid in enumerate(ids):
        r, c = VIEW_GRID[vid]
        axes = tuple(a for a, g in ((0, r), (1, c)) if g != 1)
        perms[k] = _flip_perm(v, v, axes) if (axes and not inversion) else None
    mats = []
    for l in range(wl.size):
        rows = where[tr.pix[l].astype(np.int64)]
        keep = rows >= 0
        rows, tex, w = rows[keep], tr.tex[l][keep].astype(np.int64), tr.w[l][keep]
        if not inversion:
            view_of = rows // (v * v)
            for k, p in perms.items():
                if p is not None:
                    sel = view_of == k
                    tex[sel] = p[tex[sel]]
        mats.append(sp.csr_matrix((w.astype(np.float64) * q[l], (rows, tex)),
                                  shape=(len(ids) * v * v, ntex)))
    return TransportOperator(mats, (wl.size, v, v), (len(ids), v, v))


def oracle_measurements(frame, metadata, design, n_views: int) -> np.ndarray:
    """The (K, v, v) view rectangles of a raw frame divided by its ``radiance_scale``."""
    ids = _view_ids(n_views, design)
    f = np.asarray(frame, dtype=np.float32)
    if metadata and metadata.get("design_hash") not in (None, design.hash):
        raise InputError(f"raw frame was taken with design {metadata.get('design_hash')}, not "
                         f"{design.hash}")
    if f.shape != (design.sensor_height_px, design.sensor_width_px):
        raise InputError(f"raw frame shape {f.shape} is not the design's sensor "
                         f"{(design.sensor_height_px, design.sensor_width_px)}")
    s = float((metadata or {}).get("radiance_scale") or 1.0)
    out = np.empty((len(ids), design.view_size_px, design.view_size_px), dtype=np.float32)
    for k, vid in enumerate(ids):
        r0, c0, h, w = design.view_rect(vid)
        out[k] = f[r0:r0 + h, c0:c0 + w] / np.float32(s)
    return out
