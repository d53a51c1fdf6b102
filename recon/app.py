r"""High-level reconstruction: measurement + operator in, cube (H, W, L) out.

This is the one place where the layouts meet: callers (the command line, the simulator's
experiments, notebooks) speak (H, W, L) cubes; operators and solvers work band-major on
(L, H, W) so every band is a contiguous image.  :func:`reconstruct` transposes once on the way in
(``x0``, ``truth``) and once on the way out, validates shapes, runs a solver from
:mod:`recon.solvers` and reports timing and, given a reference, quality metrics.

The problem solved is

.. math::

    \hat f = \arg\min_f \tfrac12 \lVert g - H f\rVert_2^2 + \varphi(f)

with the prior :math:`\varphi` named by ``prior`` (:mod:`recon.priors`); the default ``"tv"``
is the paper's (Eq. 6–7), :math:`\tau\,\mathrm{TV}(f)` with TV spatial and summed over bands.

Negative measurements.  A CASSI frame is a non-negative intensity, but after dark-frame
subtraction read noise leaves some pixels slightly below zero, and those must be accepted as
they are (clipping them would bias the data).  So :func:`reconstruct`

- accepts any negative values down to :data:`NEGATIVE_WARN_FRACTION` (10 %) of the frame's
  peak (a read noise of 2.5 % of full scale, ~100 DN at 12 bits, far more than a real sensor,
  leaves its minimum above that);
- warns (:class:`NegativeMeasurementWarning`) when values go further below zero: that is
  beyond noise (a double dark subtraction, a wrong offset) but may still be deliberate
  (simulated heavy noise);
- raises :class:`~recon.errors.InputError` when the frame is not an intensity at all: negative
  values with a mean that is not positive (a difference image, a sign error).
"""

from __future__ import annotations

import math
import time

import numpy as np

from recon.errors import InputError

__all__ = ["reconstruct", "reconstruct_standard", "standard_n_bands", "default_tau", "solver_names",
           "prior_names", "build_prior", "check_measurement_sign", "NegativeMeasurementWarning", "NEGATIVE_WARN_FRACTION"]

#: Negative values below ``-NEGATIVE_WARN_FRACTION * max(g)`` are beyond read noise (warning).
NEGATIVE_WARN_FRACTION = 0.1
#: Seconds between the PSNRs a progress bar shows when no history is kept (a PSNR is a pass
#: over the cube and the truth).
PSNR_SHOWN_EVERY = 1.0


class NegativeMeasurementWarning(UserWarning):
    """The measurement goes further below zero than read noise explains (see the module notes)."""


def check_measurement_sign(g) -> None:
    """Apply the negative-measurement policy of the module notes to a finite array.

    Raises
    ------
    InputError
        Negative values and a mean that is not positive: not an intensity.

    Warns
    -----
    NegativeMeasurementWarning
        Values below ``-NEGATIVE_WARN_FRACTION * max(g)``.
    """
    import warnings

    g = np.asarray(g)
    lo = float(g.min())
    if lo >= 0:
        return
    peak = float(g.max())
    mean = float(np.mean(g, dtype=np.float64))
    if mean <= 0:
        raise InputError(
            f"measurement is not an intensity: it has negative values (down to {lo:.4g}) and a "
            f"mean of {mean:.4g} <= 0 (a difference image or a sign error?)")
    if lo < -NEGATIVE_WARN_FRACTION * peak:
        warnings.warn(
            f"measurement has values down to {lo:.4g}, {100 * -lo / peak:.0f} % of its peak "
            f"{peak:.4g}: beyond read noise (dark frame subtracted twice?); using it as it is",
            NegativeMeasurementWarning, stacklevel=3)


def solver_names() -> tuple[str, ...]:
    """The solver names :func:`recon.solvers.solve` knows."""
    from recon.solvers import SOLVERS

    return tuple(SOLVERS)


def prior_names() -> tuple[str, ...]:
    """The prior names :func:`recon.priors.make_prior` knows."""
    from recon.priors import prior_names as names

    return names()


def build_prior(prior, op, dtype, solver: str, tau=None, noise=None, threads=None):
    r"""The solver keywords for ``prior``: ``{"tau": ...}`` for the TV prior (the solvers build
    it, so its arithmetic is theirs), else ``{"prior": <Prior>}`` built by
    :func:`recon.priors.make_prior` with ``tau`` as its weight (None: the prior's own rule,
    which may follow ``noise``, the measurement's rms noise).  A :class:`~recon.priors.Prior`
    object is passed through.  Returns ``(keywords, name)``.
    """
    from recon.priors import check_prior_name, make_prior
    from recon.priors.tv import check_weight

    if tau is not None:
        tau = check_weight(tau, "tau")
    if prior is None or prior == "tv":
        return {"tau": default_tau(solver) if tau is None else tau}, "tv"
    if not isinstance(prior, str):
        if tau is not None:
            raise InputError("tau sets the TV prior's weight; with a prior object, set it there")
        return {"prior": prior}, getattr(prior, "name", type(prior).__name__)
    check_prior_name(prior)
    return {"prior": make_prior(prior, shape=op.ishape, dtype=dtype, weight=tau, solver=solver,
                                noise=noise, n_views=op.oshape[0], threads=threads)}, prior


def default_tau(solver: str) -> float:
    """The default TV weight of a solver (:data:`recon.priors.tv.DEFAULT_WEIGHT`)."""
    from recon.priors.tv import default_weight
    from recon.solvers import SOLVERS

    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    return default_weight(solver)


def _as_measurement(measurement, oshape) -> np.ndarray:
    g = np.asarray(measurement)
    if g.dtype == bool or not (np.issubdtype(g.dtype, np.floating) or np.issubdtype(g.dtype, np.integer)):
        raise InputError(f"measurement has dtype {g.dtype}, expected real numbers")
    if g.shape != tuple(oshape):
        if oshape[0] == 1 and g.shape == tuple(oshape[1:]):
            g = g[None]  # a 2-D single-view frame (Hv, Wm) for K = 1
        else:
            raise InputError(
                f"measurement shape {g.shape} does not match the operator's {tuple(oshape)}"
                + (f" (or {tuple(oshape[1:])})" if oshape[0] == 1 else "")
            )
    dtype = np.float64 if g.dtype == np.float64 else np.float32
    g = np.ascontiguousarray(g, dtype=dtype)
    if not np.all(np.isfinite(g)):
        raise InputError("measurement contains NaN or Inf")
    check_measurement_sign(g)
    return g


def _to_band_major(cube, ishape, what: str, dtype) -> np.ndarray:
    c = np.asarray(cube)
    L, H, W = ishape
    if c.shape != (H, W, L):
        raise InputError(f"{what} shape {c.shape} does not match the operator's cube (H, W, L) = {(H, W, L)}")
    if c.dtype == bool or not (np.issubdtype(c.dtype, np.floating) or np.issubdtype(c.dtype, np.integer)):
        raise InputError(f"{what} has dtype {c.dtype}, expected real numbers")
    c = np.ascontiguousarray(np.moveaxis(c, 2, 0), dtype=dtype)
    if not np.all(np.isfinite(c)):
        raise InputError(f"{what} contains NaN or Inf")
    return c


def reconstruct(
    measurement,
    op,
    *,
    solver: str = "gap-tv",
    iters: int = 50,
    tau: float | None = None,
    prior=None,
    noise: float | None = None,
    x0=None,
    truth=None,
    wavelengths=None,
    progress: bool = False,
    history: bool = True,
    **solver_options,
) -> tuple[np.ndarray, dict]:
    r"""Reconstruct a cube from a (multi-view) CASSI measurement.

    Parameters
    ----------
    measurement : array (K, Hv, Wm), or (Hv, Wm) when the operator has one view
        The frame(s) :math:`g`.
    op : recon.operators.LinearOperator
        Forward model with ``ishape`` (L, H, W) and ``oshape`` (K, Hv, Wm).
    solver : {"gap-tv", "fista-tv", "twist", "admm"}
        A name known to :func:`recon.solvers.solve`.
    iters : int
        Outer iterations.
    tau : float, optional
        The prior's weight: for TV :math:`\tau`, None using the solver's default
        (:func:`default_tau`); for another prior its strength, None letting the prior choose.
    prior : str or Prior, optional
        A name of :data:`recon.priors.PRIORS` (default ``"tv"``) or a prior object.
    noise : float, optional
        The measurement's rms noise, for priors whose strength follows it.
    x0 : array (H, W, L), optional
        Initial guess (the solver's default, usually :math:`H^\top g`, otherwise).
    truth : array (H, W, L), optional
        Reference cube: the final :func:`recon.metrics.all_metrics` go to ``info["metrics"]``
        and, with ``history``, the PSNR after each iteration to ``info["psnr_history"]``.
    wavelengths : array (L,), optional
        Only used for the colour metric (CIEDE2000) when ``truth`` is given.
    progress : bool
        Report progress on stderr (a bar on a terminal, one line at the end elsewhere:
        :func:`recon.progress.progress_bar`); with ``truth`` the bar shows the PSNR, taken
        at most every :data:`PSNR_SHOWN_EVERY` seconds where there is no history.
    history : bool
        With ``truth``, the PSNR after every iteration (one pass over the cube and the truth
        an iteration).
    **solver_options
        Passed on to the solver.

    Raises
    ------
    InputError
        Shapes, dtypes (bool, complex, object, strings), NaN/Inf, a measurement that is not an
        intensity (see the module notes), unknown solver, prior or options, an all-zero
        operator.

    Warns
    -----
    NegativeMeasurementWarning
        Negative values beyond read noise (see the module notes).

    Returns
    -------
    cube : float32 array (H, W, L), C-contiguous
    info : dict
        ``solver``, ``prior`` (its name), ``iters`` (done), ``tau`` (the TV weight, or the
        weight given to another prior), ``seconds`` (wall time of the solve), ``converged``,
        ``objective`` (list, may be empty), ``solver_info``; with ``truth`` also ``metrics``
        and, with ``history``, ``psnr_history``.
    """
    from recon.solvers import SOLVERS, solve

    if not hasattr(op, "ishape") or not hasattr(op, "oshape") or len(op.ishape) != 3:
        raise InputError("op must be a recon operator on (L, H, W) cubes")
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    g = _as_measurement(measurement, op.oshape)
    dtype = g.dtype
    x0_bm = None if x0 is None else _to_band_major(x0, op.ishape, "x0", dtype)
    truth_bm = None if truth is None else _to_band_major(truth, op.ishape, "truth", np.float32)

    psnrs: list[float] = []
    shown = [-math.inf]      # when the bar last showed a PSNR (without a history)
    if truth_bm is not None:
        from recon import kernels
        from recon.kernels import vector as kvec

        # The PSNR's peak, the truth's maximum: once, not a pass over the truth an iteration.
        peak = float(truth_bm.max())
    bar = None

    def psnr_of(x) -> float:
        # Global PSNR (peak = max of the truth), computed band-major without a transpose.
        # Band by band in float64: a float64 copy of a paper-size cube and its difference
        # would be 0.3 GB more memory, and a few tenths of a second, every iteration.
        if kernels.usable(x) and x.flags.c_contiguous and x.shape == truth_bm.shape:
            sq = kvec.squared_distance(x, truth_bm)     # one pass, float64 sums
        else:
            sq = sum(float(np.sum((np.asarray(xl, dtype=np.float64) - tl) ** 2))
                     for xl, tl in zip(x, truth_bm))
        mse = sq / truth_bm.size / (peak * peak)
        return float(10 * np.log10(1.0 / mse)) if mse > 0 else float("inf")

    def callback(it, x, info):
        now = time.perf_counter()
        if truth_bm is not None and (history or (bar is not None
                                                 and now - shown[0] >= PSNR_SHOWN_EVERY)):
            shown[0] = now
            value = psnr_of(x)
            if history:
                psnrs.append(value)
            if bar is not None:
                bar.set_postfix(psnr=f"{value:.2f}")
        if bar is not None:
            bar.update(1)
        return None

    kwargs = dict(solver_options)
    kwargs["iters"] = iters
    prior_kw, prior_name = build_prior(prior, op, dtype, solver, tau, noise,
                                       solver_options.get("threads"))
    kwargs.update(prior_kw)
    if progress:
        from recon.priors.base import stages
        from recon.progress import progress_bar

        # A prior of two stages adds its second stage's iterations (recon.solvers.solve).
        plan = stages(prior_kw.get("prior"))
        bar = progress_bar(total=int(iters) + (0 if plan is None else int(plan[1])),
                           desc=solver, unit="it")
    if x0_bm is not None:
        kwargs["x0"] = x0_bm
    if (truth_bm is not None and history) or bar is not None:
        kwargs["callback"] = callback

    t0 = time.perf_counter()
    try:
        res = solve(solver, op, g, **kwargs)
        if bar is not None and truth_bm is not None and not history:
            # The bar's last PSNR may be a second old: its closing line shows the result's.
            bar.set_postfix(psnr=f"{psnr_of(getattr(res, 'x', res)):.2f}")
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t0

    x = getattr(res, "x", res)
    cube = np.ascontiguousarray(np.moveaxis(np.asarray(x), 0, 2), dtype=np.float32)
    if not np.all(np.isfinite(cube)):
        # Not the user's input (that was checked): the iteration diverged.
        raise RuntimeError(f"solver {solver!r} diverged (non-finite values) on {op!r}")
    info = {
        "solver": solver,
        "prior": prior_name,
        "iters": int(getattr(res, "iterations", iters)),
        "tau": kwargs.get("tau", tau),
        "seconds": float(getattr(res, "seconds", wall)),
        "wall_seconds": wall,
        "converged": bool(getattr(res, "converged", False)),
        "objective": [float(v) for v in getattr(res, "objective", [])],
        "solver_info": dict(getattr(res, "info", {}) or {}),
        "cube_shape": cube.shape,
        "measurement_shape": tuple(g.shape),
    }
    # The solver's result and the prior's workspace go before the metrics' float64 work (the
    # end of a `paper` solve is one of a run's two peaks).
    del res, x, kwargs, prior_kw
    if truth is not None:
        from recon.metrics import all_metrics

        if history:
            info["psnr_history"] = psnrs
        info["metrics"] = all_metrics(cube, np.moveaxis(truth_bm, 0, 2), wavelengths)
    return cube, info


def standard_n_bands(mask_width: int, measurement_width: int, step: int) -> int:
    r"""Bands implied by the widths in the standard convention: :math:`L = (W_m - W)/s + 1`.

    Raises
    ------
    InputError
        If the step is not a positive integer or does not divide :math:`W_m - W`.
    """
    if isinstance(step, bool) or int(step) != step or step < 1:
        raise InputError(f"step must be a positive integer number of pixels, got {step!r}")
    step = int(step)
    extra = int(measurement_width) - int(mask_width)
    if extra < 0:
        raise InputError(
            f"the measurement ({measurement_width} px wide) is narrower than the mask ({mask_width} px)"
        )
    if extra % step:
        raise InputError(
            f"step {step} does not fit: measurement width {measurement_width} - mask width {mask_width} "
            f"= {extra} is not a multiple of {step}"
        )
    return extra // step + 1


def reconstruct_standard(measurement_2d, mask, step: int, n_bands: int | None = None, **kwargs):
    r"""Reconstruct in the standard single-view convention (MST / TSA-Net, KAIST benchmark).

    Mask (H, W); band :math:`l` shifted right by :math:`\mathrm{step}\cdot l`; measurement
    (H, W + step·(L − 1)).  ``n_bands`` defaults to what the widths imply
    (:func:`standard_n_bands`); if given it must agree.  Other keyword arguments go to
    :func:`reconstruct`.

    Returns
    -------
    cube : float32 (H, W, L)
    info : dict (see :func:`reconstruct`)
    """
    from recon.operators import standard_cassi

    g = np.asarray(measurement_2d)
    m = np.asarray(mask)
    if g.ndim != 2:
        raise InputError(f"the measurement must be 2-D (H, W + step*(L-1)), got shape {g.shape}")
    if m.ndim != 2:
        raise InputError(f"the mask must be 2-D (H, W), got shape {m.shape}")
    if g.shape[0] != m.shape[0]:
        raise InputError(f"measurement height {g.shape[0]} != mask height {m.shape[0]}")
    implied = standard_n_bands(m.shape[1], g.shape[1], step)
    if n_bands is not None and int(n_bands) != implied:
        raise InputError(
            f"{n_bands} bands do not fit: mask width {m.shape[1]}, measurement width {g.shape[1]} "
            f"and step {step} imply {implied}"
        )
    if m.dtype == bool:
        m = m.astype(np.float32)  # a binary mask: True = open
    if not (np.issubdtype(m.dtype, np.floating) or np.issubdtype(m.dtype, np.integer)):
        raise InputError(f"mask has dtype {m.dtype}, expected real numbers (or bool)")
    if not np.all(np.isfinite(m)):
        raise InputError("mask contains NaN or Inf")
    op = standard_cassi(m, int(step), implied)
    return reconstruct(g, op, **kwargs)
