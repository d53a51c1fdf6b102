r"""The exact (oracle) forward operator of a design: the simulator's own converged linear map.

Every element between the diffuser and the sensor is specular and the sensor is linear before
noise, so the expected raw frame of a cube :math:`f` on a grid, in DN at ``radiance_scale`` 1,
is

.. math:: \bar g = \sum_l q_l\, K_l * (T_l f_l),

with :math:`T_l` the band's exact pixel integrals (:mod:`sim.transport.exact`: mask, dispersion per
view, the mirror geometry, vignetting and losses), :math:`K_l` its Airy kernel and :math:`q_l`
the sensor's DN per unit irradiance (QE, pixel area, exposure, the band's width inside the
filter, ADC gain).  :class:`ExactOperator` is that map restricted to the views' rectangles,
``(L, H, W) -> (K, v, v)``, with its exact adjoint (a dot test checks it), so ``frame /
radiance_scale`` cut into the rectangles (:func:`oracle_measurements`) differs from it only by
the sensor's noise and quantisation.  This is the reference for "reconstruction from
calibration is within 1 dB of the exact operator".

It is traced with its own seed (:data:`sim.transport.exact.SEEDS`): neither the captures' nor the
scene frames' realisation, though all three converge to the same optics.

``inversion=False`` composes every view with the mirror flips of its grid position, so every
view sees the scene upright: the same masks and dispersion without the dispersion inversion of
the mirrored views (paper Fig. 8c), a hypothetical system.

Each application runs view by view, as a frame does (:meth:`sim.frame.FrameModel.electrons`):
the view's bands integrated exactly (:func:`sim.transport.pixel_integral.band_forward`, bands on
threads), then weighted, blurred and summed by FFT (:class:`sim.sensor.BlurredSum`: one
transform a band and one a view); the adjoint blurs the measurement once a view and takes one
inverse transform a band (:meth:`~sim.sensor.BlurredSum.adjoint`).  Only the views whose
blurred light reaches a measured rectangle are integrated.

Memory: the transport's maps and throughput images (``views × v² × L`` floats: 5 MB for
``small``, 420 MB for ``paper``), one view's bands at the transforms' size (96 MB for
``paper``) and the sensor widened by the blur's reach.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.view_ids import VIEW_ORDER

__all__ = ["ExactOperator", "oracle_operator", "oracle_measurements", "band_gains"]

#: Rademacher probes of :meth:`ExactOperator.mean_row_norm_sq`.
NORM_PROBES = 8


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
    """(L,) DN per unit sensor irradiance of each band (:func:`sim.sensor.electron_scale` over
    the ADC gain ``full_well_e / max_dn``)."""
    from sim.sensor import electron_scale

    return electron_scale(design, wavelengths) * design.max_dn / design.full_well_e


class ExactOperator(LinearOperator):
    r"""The simulator's expected frame restricted to some views, ``(L, H, W) -> (K, v, v)``.

    Parameters
    ----------
    design : sim.optics.design.Design
    transport : sim.transport.exact.Transport
        Traced for the design's bands (box sampling).
    view_ids : sequence of int
        The views, in measurement order.
    grid : (H, W)
        The cube's grid on the diffuser (the centre view's ``v × v`` by default).
    inversion : bool
        ``False``: every view composed with its mirror flips (no dispersion inversion).
    diffraction : bool
        The sensor's Airy blur per band.
    """

    def __init__(self, design, transport, view_ids, grid=None, *, inversion: bool = True,
                 diffraction: bool = True):
        from sim.optics.design import VIEW_GRID
        from sim.sensor import BlurredSum, airy_kernel

        v = design.view_size_px
        grid = (v, v) if grid is None else tuple(int(x) for x in grid)
        wl = design.wavelengths
        if transport.n_bands != wl.size:
            raise InputError(f"the transport has {transport.n_bands} bands, the design {wl.size}")
        super().__init__((wl.size,) + grid, (len(view_ids), v, v))
        self.tr = transport
        self.index = [transport.views.index(int(i)) for i in view_ids]
        self.rects = [tuple(int(x) for x in transport.maps.rects[k]) for k in self.index]
        self.all_rects = [tuple(int(x) for x in r) for r in transport.maps.rects]
        self.q = band_gains(design, wl).astype(np.float32)
        self.cell_px = float(design.mask_cell_px)
        self.kernels = ([airy_kernel(float(design.airy_radius_um(lam)) / design.sensor_pixel_um)
                         for lam in wl] if diffraction else None)
        self.blur = BlurredSum(self.kernels, self.q)
        # The traced views whose blurred light reaches a measured rectangle: only theirs is
        # integrated (the blur carries light across the rectangles' borders, by R at most).
        R = self.blur.reach(range(wl.size))
        self.lit_views = [k for k, (r0, c0, h, w) in enumerate(self.all_rects)
                          if any(r0 - R < a0 + ha and a0 < r0 + h + R
                                 and c0 - R < b0 + wa and b0 < c0 + w + R
                                 for a0, b0, ha, wa in self.rects)]
        self.flip_of = []
        for i in transport.views:
            r, c = VIEW_GRID[int(i)] if design.kaleidoscope else (1, 1)
            self.flip_of.append(tuple(a for a, g in ((0, r), (1, c)) if g != 1)
                                if not inversion else ())
        self._rn = None
        transport.prepare(range(wl.size), grid[1])

    def _flip(self, img, axes):
        return np.ascontiguousarray(np.flip(img, axis=axes)) if axes else img

    def _forward(self, x):
        from sim.transport.exact import each

        dt = np.float64 if x.dtype == np.float64 else np.float32
        x32 = np.asarray(x, np.float32)
        bands = range(self.ishape[0])
        R = self.blur.reach(bands)
        # The sensor widened by R on every side, so that no view's blur is clipped.
        total = np.zeros((self.tr.sensor[0] + 2 * R, self.tr.sensor[1] + 2 * R), np.float32)
        irr = size = None
        for k in self.lit_views:
            r0, c0, h, w = self.all_rects[k]
            # View by view: every band's exact pixel integrals, then the bands' blurs weighted
            # and summed by FFT (sim.sensor.BlurredSum, as a frame's), added where they fall.
            # One zero-padded buffer serves views of one size: only their (h, w) is written.
            if irr is None or size != (h, w):
                irr = np.zeros((len(bands),) + self.blur.shape(h, w, bands), np.float32)
                size = (h, w)

            def one(l, k=k, irr=irr, h=h, w=w):
                irr[l, :h, :w] = self.tr.view_band(self._flip(x32[l], self.flip_of[k]), k, l)

            each(one, bands)
            total[r0:r0 + h + 2 * R, c0:c0 + w + 2 * R] += self.blur(irr, bands, size=(h, w))
        out = np.stack([total[r0 + R:r0 + R + h, c0 + R:c0 + R + w]
                        for r0, c0, h, w in self.rects]).astype(np.float64)
        return out.astype(dt)

    def _adjoint(self, y):
        from sim.transport.exact import each

        dt = np.float64 if y.dtype == np.float64 else np.float32
        bands = range(self.ishape[0])
        R = self.blur.reach(bands)
        img0 = np.zeros((self.tr.sensor[0] + 2 * R, self.tr.sensor[1] + 2 * R), np.float32)
        for j, (r0, c0, h, w) in enumerate(self.rects):
            img0[r0 + R:r0 + R + h, c0 + R:c0 + R + w] = y[j]
        out = np.zeros(self.ishape, np.float64)
        for k in self.lit_views:
            r0, c0, h, w = self.all_rects[k]
            # Every band's weighted blur of the measurement over this view (the Airy kernel is
            # symmetric: blurring is its own adjoint), then the pixel integrals' adjoints.
            e = self.blur.adjoint(img0[r0:r0 + h + 2 * R, c0:c0 + w + 2 * R], bands, (h, w))

            def one(l, k=k, e=e):
                if not e[l].any():
                    return
                acc = out[l]             # each band its own slice: no two threads share one
                if self.flip_of[k]:
                    flipped = self.tr.view_band_adjoint(e[l], k, l, self.ishape[1:])
                    acc += np.flip(flipped, axis=self.flip_of[k])
                else:
                    self.tr.view_band_adjoint(e[l], k, l, self.ishape[1:], fbar=acc)

            each(one, bands)
        return out.astype(dt)

    def mean_row_norm_sq(self) -> float:
        r"""Mean of :math:`\|a_i\|^2` over the measured rows (those with any weight):
        :math:`\|A\|_F^2 / n` by Hutchinson's estimator, :math:`\mathbb E\|A z\|^2` over
        Rademacher probes :math:`z` (:data:`NORM_PROBES`, fixed seed; relative error
        ~10⁻³ here: a row couples only the few texels of its footprint)."""
        rng = np.random.default_rng(0)
        acc = 0.0
        lit = np.zeros(self.oshape, bool)
        for _ in range(NORM_PROBES):
            z = rng.choice(np.array([-1.0, 1.0], np.float32), size=self.ishape)
            az = self.forward(z).astype(np.float64)
            acc += float(np.sum(az ** 2))
            lit |= az != 0
        n = int(lit.sum())
        return acc / NORM_PROBES / max(n, 1)

    def row_norms_sq(self):
        r"""Diagonal of :math:`AA^\top`, exactly, by coloured probing: two rows of one view
        further apart than a footprint, its smear and the blur share no texel, so a probe that
        lights one view's rows on a lattice of that spacing returns each of their norms
        (``views × lattice`` probes, each a forward and an adjoint: slow for ``paper``; only
        GAP-TV needs it)."""
        if self._rn is None:
            reach = max(k.shape[0] // 2 for k in self.kernels) if self.kernels else 0
            smear = max(float(np.ptp(self.tr.intervals[l]) > 0) * self._smear_px(l)
                        for l in range(self.ishape[0]))
            texel = max(self.oshape[1] / self.ishape[1], self.oshape[2] / self.ishape[2])
            py = int(math.ceil(2 * reach + 2 + 2 * texel)) + 1
            px = int(math.ceil(2 * reach + 2 + 2 * texel + 2 * smear)) + 1
            K, v, _ = self.oshape
            yy, xx = np.mgrid[0:v, 0:v]
            rn = np.zeros(self.oshape, np.float64)
            for j in range(K):
                for a in range(py):
                    for b in range(px):
                        z = np.zeros(self.oshape, np.float64)
                        z[j] = ((yy % py) == a) & ((xx % px) == b)
                        rn += z * self.forward(self.adjoint(z))
            # The kernels run in float32: a row with next to no weight can come out a rounding
            # error below zero.
            self._rn = np.maximum(rn, 0.0)
        return self._rn

    def _smear_px(self, l) -> float:
        """How far (px) a pixel's footprint moves across band ``l`` (its first and last node)."""
        m, nodes = self.tr.maps, self.tr.band_nodes[l]
        a, b = int(nodes[0]), int(nodes[-1])
        # The constant Legendre term is the map's mean over the view (mask cells).
        return abs(float(m.mask[0, b, 0, 0, 0] - m.mask[0, a, 0, 0, 0])) * self.cell_px + 1.0

    def __repr__(self):
        return f"ExactOperator({self.ishape} -> {self.oshape})"


def oracle_operator(design, n_views: int, *, inversion: bool = True, seed: int | None = None,
                    grid=None, diffraction: bool = True) -> ExactOperator:
    """The exact operator of ``design`` for its first ``n_views`` views (module notes).

    Parameters
    ----------
    design : sim.optics.design.Design
        Its ``views`` must include the first ``n_views`` ids (0..n-1).
    n_views : int
        1..9, views in the order centre, left, right, top, bottom, corners.
    inversion : bool
        ``False``: every view composed with its mirror flips (no dispersion inversion).
    seed : int, optional
        The transport's realisation (default: the oracle's own, :data:`sim.transport.exact.SEEDS`).
    grid : (H, W), optional
        The cube's grid (default the centre view's ``v × v``).
    """
    from sim.transport.exact import SEEDS, load_or_build

    ids = _view_ids(n_views, design)
    tr = load_or_build(design, design.wavelengths, seed=SEEDS["oracle"] if seed is None
                       else int(seed))
    return ExactOperator(design, tr, ids, grid, inversion=inversion, diffraction=diffraction)


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
