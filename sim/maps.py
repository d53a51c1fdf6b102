r"""The optical maps of a design: where each sensor point looks, traced with Mitsuba.

With ideal lenses every element after the diffuser images exactly (:mod:`sim.rays` explains why
the tracer must continue rays without Mitsuba's sideways ``spawn_ray`` step for that to hold):
at wavelength :math:`\lambda` all rays from a sensor point :math:`s`, whatever point of the
aperture they pass, cross the mask at one point :math:`m(s, \lambda)` and reach the diffuser at
one point, and in view :math:`k` that point is an axis-aligned affine image of :math:`m`,

.. math:: u = \alpha_k + \beta_k\, m

(the relay's minification and the mirror flips of the view; :math:`u` the diffuser position in
units of the scene's side, so independent of the cube's resolution).  Only the throughput
depends on the aperture: a pixel receives

.. math:: \tau(s, \lambda) = V(s, \lambda)\; T(s, \lambda)\; T_d\, \frac{\pi}{1 + 4N^2},

with :math:`V` the fraction of the aperture whose rays pass the kaleidoscope's only stop, the
tube's exit (the beam of a sensor point crosses the exit plane in an affine image of the
aperture disc, :math:`b + A\,(u, v)`, so :math:`V` is the area of a disc cut by a parallelogram,
:func:`sim.pixel_integral.disc_fraction`), and :math:`T` the mean throughput of the rays that pass
it (mirrors' reflectance, the prism's Fresnel losses, the quartz plate; smooth).

:func:`trace_maps` traces, for every used view and every wavelength node, a jittered grid of
sensor points (the chief ray, two more rays that give :math:`A`, and ``aperture_rays``
stratified rays for :math:`T`) and fits each quantity with a 2-D Legendre polynomial of
``degree`` over the view's rectangle.  The fit is least squares over many more points than
coefficients, which also averages out the float32 round-off of the traced positions (~0.003 px on
``paper``, whose coordinates are ~500 mm); ``fit_rms`` keeps each fit's residual, which the
tests hold to that round-off.  Wavelength nodes are chosen by :func:`band_nodes`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from recon.errors import InputError

__all__ = ["OpticalMaps", "band_nodes", "panel_path_error", "trace_maps", "legendre_values",
           "evaluate", "mask_coordinates", "diffuser_coordinates", "N_EXIT"]

#: Quantities of the exit-plane map, in order: b_x, b_y, A[0,0], A[1,0], A[0,1], A[1,1] (mm; the
#: columns of A are the exit-plane steps of the aperture disc's unit vectors).
N_EXIT = 6


@dataclass
class OpticalMaps:
    """Traced optical maps of a design's used views at a set of wavelength nodes.

    Polynomials are 2-D Legendre series in normalised sensor coordinates
    :math:`\\hat r = (r - r_c)/s_r`, :math:`\\hat c = (c - c_c)/s_c` (:meth:`normalise`), stored as
    coefficient matrices ``(degree + 1, degree + 1)`` (row power i, column power j, only
    :math:`i + j \\le` degree non-zero).
    """

    design_hash: str
    views: tuple                 #: view ids, in the order of the arrays' first axis
    nodes_nm: np.ndarray         #: (N,) wavelength nodes
    rects: np.ndarray            #: (V, 4) view rectangles (row0, col0, height, width)
    norm: np.ndarray             #: (V, 4) r_c, s_r, c_c, s_c
    degree: int
    mask: np.ndarray             #: (V, N, 2, D, D) mask column (m_x) and row (m_y), cell units
    exit: np.ndarray             #: (V, N, 6, D, D) exit-plane map b, A (mm), NaN if no view
    throughput: np.ndarray       #: (V, N, D, D) T times T_d π/(1+4N²)
    relay: np.ndarray            #: (V, 4) α_x, β_x, α_y, β_y: diffuser u = α + β m
    has_stop: bool               #: False without the kaleidoscope (no tube: V = 1)
    stop_half: float             #: half the tube width (mm)
    fit_rms: np.ndarray          #: (V, 4) RMS residuals: m_x, m_y (px), relay (px), T (relative)
    seed: int = 0
    seconds: float = 0.0


def panel_path_error(phi, t) -> float:
    r"""How far (px) the pixel integral's path across a panel leaves the dispersion
    :math:`\varphi(t)` (``phi`` at the panel parameters ``t`` in [0, 1], which include 0, ½
    and 1): the largest :math:`|t_q(\varphi) - t|\,|D|` of the path whose :math:`t_q` is
    quadratic in the position through the panel's three nodes (:mod:`sim.pixel_integral`)."""
    phi, t = np.asarray(phi, np.float64), np.asarray(t, np.float64)
    x0, xm, x1 = (float(np.interp(v, t, phi)) for v in (0.0, 0.5, 1.0))
    D = x1 - x0
    if abs(D) < 1e-12:
        return float(np.abs(phi - x0).max())
    # sim.pixel_integral._panel_factors' κ, written here again: the kernels import this module
    # (Legendre values), so this module may not import them.
    a = xm - x0
    kappa = (0.5 * D - a) / (D * a * (a - D))
    tq = (phi - x0) / D + kappa * (phi - x0) * (phi - x1)
    return float(np.abs(tq - t).max() * abs(D))


def band_nodes(design, intervals, tolerance_px: float = 0.003):
    """Wavelength nodes for every band: its interval cut into equal panels, each with nodes at
    its ends and its middle, as few panels as keep the pixel integral's path (quadratic across
    a panel, :func:`panel_path_error`) within ``tolerance_px`` of the dispersion.

    The prism's dispersion is not linear (its rate changes by ~25 % across a blue band of
    ``small``) but smooth: one panel a band holds it to 2·10⁻⁴ px on ``paper`` and 9·10⁻⁴ on
    ``small``.  The panels are chosen from the design's Sellmeier dispersion (a design
    quantity: it only picks the nodes, the maps themselves are traced).

    Returns
    -------
    nodes : ndarray (N,)
        Sorted distinct wavelengths (shared band edges once).
    index : list of int arrays
        Node indices of each band, 2S + 1 for S panels, in increasing wavelength (one node for
        a monochromatic band).
    """
    iv = np.asarray(intervals, np.float64).reshape(-1, 2)
    per_band = []
    t = np.linspace(0.0, 1.0, 101)
    for lo, hi in iv:
        if hi - lo < 1e-9:
            per_band.append(np.array([lo]))
            continue
        for n in range(1, 17):
            edges = np.linspace(lo, hi, n + 1)
            if max(panel_path_error(design.dispersion_px_at(a + t * (b - a)), t)
                   for a, b in zip(edges[:-1], edges[1:])) <= tolerance_px:
                break
        per_band.append(np.linspace(lo, hi, 2 * n + 1))
    allnodes = np.unique(np.round(np.concatenate(per_band), 9))
    index = [np.searchsorted(allnodes, np.round(b, 9)) for b in per_band]
    return allnodes, index


# ---------------------------------------------------------------------------------- polynomials
def legendre_values(x, degree: int) -> np.ndarray:
    """(n, degree+1) Legendre polynomials P_0..P_degree at ``x`` (Bonnet's recursion)."""
    x = np.asarray(x, np.float64).ravel()
    out = np.empty((x.size, degree + 1))
    out[:, 0] = 1.0
    if degree >= 1:
        out[:, 1] = x
    for k in range(1, degree):
        out[:, k + 1] = ((2 * k + 1) * x * out[:, k] - k * out[:, k - 1]) / (k + 1)
    return out


def _terms(degree):
    return [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]


def _fit(pr, pc, values, degree):
    """Least-squares Legendre coefficients (D, D) of each column of ``values`` (P, Q) (or of
    ``values`` (P,)) and the RMS residuals.

    Normal equations (the Legendre basis is well conditioned over the fitted square) summed
    with ``einsum``: LAPACK's least squares hands these tiny systems to a thread pool that,
    beside Mitsuba's and Numba's, took 28 ms a fit instead of 0.2.
    """
    terms = _terms(degree)
    a = np.stack([pr[:, i] * pc[:, j] for i, j in terms], axis=1)
    v = np.asarray(values, np.float64)
    vec = v.ndim == 1
    v = v[:, None] if vec else v
    sol = np.linalg.solve(np.einsum("pi,pj->ij", a, a), np.einsum("pi,pq->iq", a, v))
    rms = np.sqrt(np.mean((np.einsum("pi,iq->pq", a, sol) - v) ** 2, axis=0))
    coef = np.zeros((v.shape[1], degree + 1, degree + 1))
    for t, (i, j) in enumerate(terms):
        coef[:, i, j] = sol[t]
    return (coef[0], float(rms[0])) if vec else (coef, rms)


def evaluate(coef, pr, pc) -> np.ndarray:
    """Values of a Legendre series on a grid: ``pr`` (h, D) row and ``pc`` (w, D) column
    polynomials give (h, w) = pr · coef · pcᵀ."""
    return pr @ coef @ pc.T


# ---------------------------------------------------------------------------------- coordinates
def mask_coordinates(design, xy) -> np.ndarray:
    """(2, n) continuous mask-cell coordinates (column m_x, row m_y) of mask-plane world points
    ``xy`` (2, n), as the sensor sees the mask (:func:`sim.mask.cell_index` without the floor)."""
    from sim.diffuser import SENSOR_FROM_DIFFUSER

    sx, sy = SENSOR_FROM_DIFFUSER
    M = design.mask_to_sensor
    pix = design.sensor_pixel_um * 1e-3
    r0, c0 = design.mask_origin_px
    col = 0.5 * design.sensor_width_px + M * (-sx) * xy[0] / pix
    row = 0.5 * design.sensor_height_px + M * (-sy) * xy[1] / pix
    return np.stack([(col - c0) / design.mask_cell_px, (row - r0) / design.mask_cell_px])


def diffuser_coordinates(design, xy) -> np.ndarray:
    """(2, n) diffuser positions in units of the scene's side (0..1 across the cube, column
    then row: :func:`sim.diffuser.cube_region` of any shape, divided by the side)."""
    from sim.diffuser import cube_region

    reg = cube_region(design, (1, 1))
    return np.stack([(reg.sx * xy[0] - reg.x0) / reg.dx, (reg.sy * xy[1] - reg.y0) / reg.dy])


# ---------------------------------------------------------------------------------- tracing
def trace_maps(design, nodes_nm, *, seed: int = 0, degree: int = 5, grid: int | None = None,
               aperture_rays: int = 16, batch: int = 1 << 20, progress: bool = False
               ) -> OpticalMaps:
    """Trace and fit the optical maps of ``design``'s used views at ``nodes_nm``.

    Parameters
    ----------
    design : sim.design.Design
    nodes_nm : array_like (N,)
        Wavelengths (nm) to trace at (:func:`band_nodes`).
    seed : int
        Seeds the jitter of the sensor points and the aperture samples: another seed is an
        independent realisation of the same optics.
    degree : int
        Degree of the Legendre fits (5: residuals at the float32 round-off, tests).
    grid : int, optional
        Sensor points per side of a view (default: 24 for views under 300 px, else 40).
    aperture_rays : int
        Stratified aperture samples per point for the throughput T (a perfect square).
    """
    from sim.design import VIEW_GRID
    from sim.rays import sensor_rays, walk
    from sim.scene import trace_setup

    t0 = time.perf_counter()
    nodes = np.asarray(nodes_nm, np.float64).ravel()
    if nodes.size == 0 or not np.all(np.isfinite(nodes)):
        raise InputError("trace_maps needs at least one finite wavelength node")
    na = int(round(np.sqrt(aperture_rays))) ** 2
    if na != aperture_rays or na < 1:
        raise InputError(f"aperture_rays must be a perfect square, got {aperture_rays}")
    setup = trace_setup(design, open_mask=True)
    views = tuple(sorted(design.views))
    D = degree + 1
    V, N = len(views), nodes.size
    rects = np.array([design.view_rect(v) for v in views], np.float64)
    norm = np.empty((V, 4))
    mask = np.zeros((V, N, 2, D, D))
    exit_ = np.full((V, N, N_EXIT, D, D), np.nan)
    thr = np.zeros((V, N, D, D))
    relay = np.zeros((V, 4))
    fit_rms = np.zeros((V, 4))
    n_pts = grid or (24 if design.view_size_px < 300 else 40)
    s = int(np.sqrt(na))
    # Aperture samples: the chief ray, the disc's (1/2, 0) and (0, 1/2) (concentric mapping:
    # Mitsuba's thin lens), then a jittered s x s grid for the throughput.
    fixed = np.array([[0.5, 0.75, 0.5], [0.5, 0.5, 0.75]])
    bar = None
    if progress:
        from recon.progress import progress_bar

        bar = progress_bar(total=V * N, desc="optical maps", unit="map")
    try:
        for k, vid in enumerate(views):
            gr, gc = VIEW_GRID[vid] if design.kaleidoscope else (1, 1)
            want = np.array([abs(gc - 1), abs(gr - 1)])[:, None]
            r0, c0, h, w = rects[k]
            norm[k] = (r0 + h / 2, h / 2 + 1.0, c0 + w / 2, w / 2 + 1.0)
            rel_m, rel_u = [], []
            # All nodes of the view in one trace (a batch of rays is one JIT launch per
            # bounce, whatever its wavelengths).
            pts, rays = [], []
            for j, lam in enumerate(nodes):
                rng = np.random.default_rng([int(seed), int(vid), j, int(round(lam * 1000))])
                # A jittered grid of sensor points over the rectangle and a pixel around it.
                gy = (np.arange(n_pts) + rng.random(n_pts)) / n_pts
                gx = (np.arange(n_pts) + rng.random(n_pts)) / n_pts
                rr, cc = np.meshgrid(r0 - 1 + gy * (h + 2), c0 - 1 + gx * (w + 2), indexing="ij")
                rr, cc = rr.ravel(), cc.ravel()
                ay = (np.arange(s)[:, None] + rng.random((s, s))) / s
                ax = (np.arange(s)[None, :] + rng.random((s, s))) / s
                aps = np.concatenate([fixed, np.stack([ay.ravel(), ax.ravel()])], axis=1)
                pts.append((rr, cc))
                rays.append((np.repeat(rr, aps.shape[1]), np.repeat(cc, aps.shape[1]),
                             np.tile(aps, rr.size), np.full(rr.size * aps.shape[1], lam)))
            R, C, A, LAM = (np.concatenate([r[q] for r in rays], axis=-1) for q in range(4))
            parts = []
            for b0 in range(0, R.size, batch):
                sl = slice(b0, b0 + batch)
                parts.append(walk(setup, sensor_rays(setup, R[sl], C[sl], A[:, sl], LAM[sl])))
            whole = _concat(parts)
            per = n_pts * n_pts * (3 + na)
            for j in range(N):
                rr, cc = pts[j]
                P = rr.size
                wk = _slice(whole, slice(j * per, (j + 1) * per))
                m = wk.mask.reshape(2, P, -1)
                pr = legendre_values((rr - norm[k, 0]) / norm[k, 1], degree)
                pc = legendre_values((cc - norm[k, 2]) / norm[k, 3], degree)
                chief_m = mask_coordinates(design, m[:, :, 0])
                ok = np.all(np.isfinite(chief_m), axis=0)
                mask[k, j], rms = _fit(pr[ok], pc[ok], chief_m[:, ok].T, degree)
                fit_rms[k, :2] = np.maximum(fit_rms[k, :2], rms * design.mask_cell_px)
                walls = wk.walls.reshape(2, P, -1)
                reached = wk.reached.reshape(P, -1)
                mine = reached & np.all(walls == want[:, :, None], axis=0)
                inc = mine[:, 0]
                if inc.sum() >= 2 * len(_terms(degree)):
                    rel_m.append(chief_m[:, inc])
                    rel_u.append(diffuser_coordinates(design,
                                                      wk.diffuser.reshape(2, P, -1)[:, inc, 0]))
                    e = wk.exit.reshape(2, P, -1)
                    # The exit map of the points whose three fixed rays all reach this view.
                    eok = np.all(mine[:, :3], axis=1) & np.all(np.isfinite(e[:, :, :3]),
                                                                axis=(0, 2))
                    if setup.tube_length is not None and eok.sum() >= 2 * len(_terms(degree)):
                        b = e[:, eok, 0]
                        a0 = (e[:, eok, 1] - b) / 0.5
                        a1 = (e[:, eok, 2] - b) / 0.5
                        exit_[k, j], _ = _fit(pr[eok], pc[eok],
                                              np.stack([b[0], b[1], a0[0], a0[1], a1[0], a1[1]],
                                                       axis=1), degree)
                wt = wk.weight.reshape(P, -1)[:, 3:]
                cnt = mine[:, 3:].sum(axis=1)
                tok = cnt > 0
                tmean = np.where(tok, (wt * mine[:, 3:]).sum(axis=1) / np.maximum(cnt, 1), 0.0)
                if tok.sum() >= 2 * len(_terms(degree)):
                    thr[k, j], rms = _fit(pr[tok], pc[tok], tmean[tok], degree)
                    fit_rms[k, 3] = max(fit_rms[k, 3], rms / max(tmean[tok].mean(), 1e-12))
                if bar is not None:
                    bar.update(1)
            if not rel_m:
                raise InputError(f"no ray of view {vid} reaches the diffuser through its copy; "
                                 "the design does not image this view")
            mm, uu = np.concatenate(rel_m, axis=1), np.concatenate(rel_u, axis=1)
            for q in range(2):
                a = np.stack([np.ones(mm.shape[1]), mm[q]], axis=1)
                sol = np.linalg.solve(np.einsum("pi,pj->ij", a, a), np.einsum("pi,p->i", a, uu[q]))
                relay[k, 2 * q:2 * q + 2] = sol
                # Residual in sensor pixels: u is in scene sides, a view is v pixels.
                res = (a @ sol - uu[q]) * design.view_size_px
                fit_rms[k, 2] = max(fit_rms[k, 2], float(np.sqrt(np.mean(res ** 2))))
    finally:
        if bar is not None:
            bar.close()
    from sim.camera import irradiance_factor

    thr *= irradiance_factor(design) * design.diffuser_transmittance
    return OpticalMaps(design_hash=design.hash, views=views, nodes_nm=nodes, rects=rects,
                       norm=norm, degree=int(degree), mask=mask, exit=exit_, throughput=thr,
                       relay=relay, has_stop=setup.tube_length is not None,
                       stop_half=0.5 * float(design.tube_width_mm), fit_rms=fit_rms,
                       seed=int(seed), seconds=time.perf_counter() - t0)


def _slice(wk, sl):
    from sim.rays import Walk

    return Walk(weight=wk.weight[sl], reached=wk.reached[sl], diffuser=wk.diffuser[:, sl],
                mask=wk.mask[:, sl], exit=wk.exit[:, sl], walls=wk.walls[:, sl])


def _concat(parts):
    from sim.rays import Walk

    if len(parts) == 1:
        return parts[0]
    return Walk(weight=np.concatenate([p.weight for p in parts]),
                reached=np.concatenate([p.reached for p in parts]),
                diffuser=np.concatenate([p.diffuser for p in parts], axis=1),
                mask=np.concatenate([p.mask for p in parts], axis=1),
                exit=np.concatenate([p.exit for p in parts], axis=1),
                walls=np.concatenate([p.walls for p in parts], axis=1))
