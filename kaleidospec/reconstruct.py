r"""A raw frame and a calibration → cubes, for any number of views (and, for reference, the
same frame through the design's exact operator).

:func:`reconstruct_views` cuts the first ``n`` views (:data:`recon.view_ids.VIEW_ORDER`:
centre, left, right, top, bottom, corners) out of the frame and solves

.. math:: \hat f = \arg\min_f \tfrac12 \|s\,(g/e) - s\,H\,\mathrm{diag}(c)^{-1} f\|^2
                    + \varphi(f),

with :math:`H` the calibrated ``model``'s operator (:mod:`kaleidospec.models`), :math:`c` its
radiometric gains, :math:`e` the frame's exposure factor (``radiance_scale`` in its sidecar),
so that :math:`\hat f` is in the scene cube's own units (comparable with the truth, and about
[0, 1], the range the solvers' :math:`\tau` is meant for), and :math:`s` the scale that gives
the rows of :math:`sH` unit mean squared norm (:func:`unit_row_scale`), so that one TV weight
rule (:func:`tv_weight`) serves every model, operator and design: :math:`\tau = \kappa\, n\,
\bar\sigma`, with :math:`n` the views and :math:`\bar\sigma` the root-mean-square noise of
:math:`s\,g/e`, from the sensor's photon-transfer curve (the calibration's
:mod:`recon.calibration.noise`; the design's own sensor for the exact operator).  The prior
:math:`\varphi` is named by ``prior`` (:mod:`recon.priors`): ``"tv"`` (the default) is
:math:`\tau\,\mathrm{TV}` with that weight; another prior gets ``tau`` as its strength when
given, else the noise :math:`\bar\sigma` and the views to set its own.

:func:`reconstruct_oracle` solves the same problem with the design's exact operator
(:func:`kaleidospec.instrument.oracle_operator`) on the ground-truth grid: the reference that
separates calibration errors from the reconstruction's own.  :class:`Reconstructor` sets either
problem up once and solves many frames (a video), warm-started and optionally with a temporal
term.  Every path ends in :func:`solve_views` (or the same scaling, weight and step metric
in :class:`Reconstructor`), so a frame is reconstructed alike wherever it comes from.
"""

from __future__ import annotations

import math
import time

import numpy as np

from recon.errors import InputError

__all__ = ["DEFAULTS", "TAU_PER_VIEW", "TAU_PER_NOISE", "first_views", "tv_weight",
           "prior_weight", "unit_row_scale", "row_scale", "normalised", "measurement_noise",
           "design_noise", "solver_metric", "solve_views", "calibrated_operator",
           "frame_measurements", "reconstruct_views", "reconstruct_oracle", "Reconstructor"]

#: Reconstruction defaults: FISTA-TV run until the relative change of the cube
#: :math:`\|f_k-f_{k-1}\|/\|f_{k-1}\|` falls below ``tol``, at most ``iters`` iterations: a fixed
#: count either stops far from converged (``paper``) or runs on after it, while ``tol = 1e-3``
#: stops close to the PSNR the cap reaches (docs/reconstruction.md, "The stopping rule"; the
#: rule is held for a few iterations after a momentum restart, :mod:`recon.solvers.base`).
#: The cap is a guard, not the rule: one ``paper`` view needs 370-630 iterations (the eight
#: CAVE development scenes, docs/priors.md), and a solve stopped before it converges
#: under-reports what the instrument gives.
#: ``metric``: FISTA's step metric (:func:`recon.solvers.fista_tv`): ``"auto"`` takes a step
#: per band (:mod:`recon.solvers.band_metric`) where the prior allows it: TV, the same
#: objective reached in fewer iterations (docs/speed_product.md); ``subspace-tv``, taken on
#: the band-weighted cube (docs/priors.md).
DEFAULTS = {"solver": "fista-tv", "iters": 1000, "tol": 1e-3, "tau": None, "metric": "auto"}
#: The application's TV weight rule, in its unit-row-norm units (:func:`tv_weight`); the
#: solvers' own defaults and the weight's valid range are :mod:`recon.priors.tv`'s.
#: Default TV weight per solver (per view for the solvers whose data term sums over views) where
#: the measurement's noise is not known: measured on the ``small`` design, see :func:`tv_weight`.
TAU_PER_VIEW = {"fista-tv": 0.005, "twist": 0.005, "admm": 0.005}
#: TV weight per view and per unit of the measurement's rms noise (unit-row-norm units), for the
#: solvers whose data term is a least-squares fit: :math:`\tau = \kappa\, n\, \bar\sigma`.
#: Chosen on a scene no reported figure uses (the colour wheel, ``small``, five views;
#: docs/reconstruction.md, "The TV weight follows the noise").  ADMM minimises the same
#: objective as FISTA and TwIST, so it shares their rule.
TAU_PER_NOISE = {"fista-tv": 0.15, "twist": 0.15, "admm": 0.15}


def first_views(n_views) -> tuple[int, ...]:
    """The ids of the first ``n_views`` views (an integer 1..9) in the order views are added."""
    from recon.view_ids import VIEW_ORDER

    try:
        n = int(n_views)
    except (TypeError, ValueError):
        raise InputError(f"the number of views must be an integer 1..9, got {n_views!r}") from None
    if n != n_views or not 1 <= n <= 9:
        raise InputError(f"the number of views must be an integer 1..9, got {n_views!r}")
    return VIEW_ORDER[:n]


#: Name of GAP-TV's preconditioned step in an operator's constants (float32).
GAP_STEP = "gap_step_float32"


def _gap_step(op) -> float:
    r"""GAP-TV's step :math:`1/\|\Phi^{-1/2} H\|^2` (:math:`\Phi` the rows' squared norms)."""
    from recon.solvers.base import preconditioned_norm_sq, row_norms_sq, safe_reciprocal

    phi_inv = safe_reciprocal(row_norms_sq(op), np.float32)
    return 1.0 / preconditioned_norm_sq(op, phi_inv, dtype=np.float32)


def _takes_band_metric(prior) -> bool:
    """Whether FISTA-TV solves with ``prior`` (None: TV from the weight) in the band metric
    under :data:`DEFAULTS`'s ``metric``, as the solver decides it
    (:func:`recon.solvers.fista_tv.uses_band_metric`), a prior of two stages aside (see
    :meth:`Reconstructor.solver_options`)."""
    from recon.priors import TVPrior
    from recon.priors.base import stages
    from recon.solvers.fista_tv import uses_band_metric

    if prior is not None and stages(prior) is not None:
        return False
    return uses_band_metric(DEFAULTS["metric"], TVPrior if prior is None else prior)


def _check_calibrated(cal, view_ids) -> None:
    """Raise :class:`recon.errors.InputError` unless the calibration holds every view."""
    missing = [v for v in view_ids if v not in cal.view_ids]
    if missing:
        raise InputError(f"view(s) {missing} missing: the calibration has views "
                         f"{list(cal.view_ids)} (recalibrate with the views the run needs)")


def tv_weight(solver, tau, n_views, noise=None):
    r"""The TV weight: ``tau`` if given; else, for the least-squares solvers
    (:data:`TAU_PER_NOISE`) with the measurement's rms ``noise`` (unit-row-norm units) known,
    :math:`\kappa\, n\, \bar\sigma`; else the solver's fixed default per view × the views.

    The data term sums over the views' pixels, hence the factor :math:`n` (GAP-TV's
    projection step does not: its weight is per view, and fixed).  The weight follows the
    noise because the best one does: the presets' best fixed weights differ as their noise in
    these units does (docs/reconstruction.md, "The TV weight follows the noise").
    """
    if tau is not None:
        from recon.priors.tv import check_weight

        check_weight(tau, "the TV weight tau")
        return tau
    if noise is not None and solver in TAU_PER_NOISE:
        if not (math.isfinite(noise) and noise > 0):
            raise InputError(f"the measurement's noise must be positive, got {noise}")
        return TAU_PER_NOISE[solver] * float(noise) * int(n_views)
    from recon.app import default_tau

    base = TAU_PER_VIEW.get(solver, default_tau(solver))
    return base if solver == "gap-tv" else base * int(n_views)


def measurement_noise(g, metadata, noise_model):
    r"""The rms noise of a measurement ``g`` (a raw frame's pixels over its ``radiance_scale``
    :math:`e`): :math:`\sqrt{\overline{a\, e g + b}}/e` for the photon-transfer curve
    ``noise_model`` ``[a, b]`` (:mod:`recon.calibration.noise`); None without one."""
    if noise_model is None:
        return None
    from recon.calibration.noise import noise_rms

    e = float((metadata or {}).get("radiance_scale") or 1.0)
    return noise_rms(np.asarray(g, np.float32) * np.float32(e), noise_model) / e


def design_noise(design) -> np.ndarray:
    r"""The photon-transfer curve ``[a, b]`` of ``design``'s own sensor (the exact operator's:
    no measurement): :math:`a = 1/G`, :math:`b = (\sigma_r/G)^2 + 1/12`, :math:`G` e⁻/DN."""
    gain = design.gain_e_per_dn
    return np.array([1.0 / gain, (float(design.read_noise_e) / gain) ** 2 + 1.0 / 12.0])


def unit_row_scale(op) -> float:
    r"""The :math:`s` that makes the mean squared norm of the measured rows of :math:`sH` one.

    The data term :math:`\tfrac12\|s g - s H f\|^2` then weighs a measurement pixel alike
    whatever the exposure units of :math:`H`, so one TV weight :math:`\tau` serves the
    calibrated and the exact operator, the ``small`` and the ``paper`` design.
    """
    mean = getattr(op, "mean_row_norm_sq", None)
    if mean is not None:        # the exact operator estimates it (its row norms are costly)
        m = float(mean())
        return 1.0 if m <= 0 else 1.0 / math.sqrt(m)
    rn = np.asarray(op.row_norms_sq(), dtype=np.float64)
    pos = rn[rn > 0]
    return 1.0 if pos.size == 0 else 1.0 / math.sqrt(float(pos.mean()))


#: Name of the row scale :math:`s` (:func:`unit_row_scale`) in an operator's constants.
ROW_SCALE = "row_scale"


def row_scale(op, constants=None) -> float:
    """:func:`unit_row_scale` of ``op``, read from its ``constants``
    (:class:`recon.solvers.constants.OperatorConstants`) where they hold it, else estimated
    (and added to them)."""
    if constants is None:
        return unit_row_scale(op)
    return constants.get(ROW_SCALE, lambda: unit_row_scale(op), check=lambda v: np.ndim(v) == 0)


def normalised(op, g, constants=None):
    """``(s·H, s·g)`` with :math:`s` from :func:`unit_row_scale` (read from the operator's
    ``constants``, :func:`row_scale`, where given)."""
    from recon.operators import ScaledOperator

    s = row_scale(op, constants)
    return ScaledOperator(op, s), (g * np.float32(s)).astype(g.dtype, copy=False)


def prior_weight(prior, solver, tau, n_views, noise=None):
    """The weight handed to ``prior``: for TV (``None`` or ``"tv"``) :func:`tv_weight`; for
    another prior ``tau`` as given (None lets the prior set its strength from the noise)."""
    if prior is None or prior == "tv":
        return tv_weight(solver, tau, n_views, noise)
    if tau is not None:
        from recon.priors.tv import check_weight

        check_weight(tau, f"the {prior} prior's weight")
    return tau


def solver_metric(solver: str, metric) -> dict:
    """The solver keywords of ``metric`` (FISTA's step metric, :data:`DEFAULTS`): ``{"metric":
    metric}`` for FISTA-TV; nothing for the other solvers, which have no metric to choose (an
    input error unless ``metric`` is ``"auto"``, ``"scalar"`` or None)."""
    if solver == "fista-tv":
        return {} if metric is None else {"metric": metric}
    if metric not in (None, "auto", "scalar"):
        raise InputError(f"metric {metric!r} is FISTA-TV's option; solver {solver!r} has none")
    return {}


def solve_views(op, g, n_views: int, *, solver: str = DEFAULTS["solver"],
                iters: int = DEFAULTS["iters"], tol=DEFAULTS["tol"], tau=None, x0=None, truth=None,
                wavelengths=None, progress: bool = False, noise=None, prior=None,
                metric=DEFAULTS["metric"], history: bool = False, constants=None):
    """Reconstruct measurements ``g`` of ``n_views`` views through ``op`` the way every path of
    the application does: operator and data brought to unit mean row norm (:func:`normalised`),
    the prior ``prior`` (a :data:`recon.priors.PRIORS` name; None: ``"tv"``) with the weight
    from :func:`prior_weight` (``noise``: the rms noise of ``g``, in its units, e.g.
    :func:`measurement_noise`), then :func:`recon.app.reconstruct` (at most ``iters``
    iterations, fewer once the relative change falls below ``tol``; ``None`` runs them all;
    FISTA's step ``metric``, :func:`solver_metric`; with ``truth``, the final metrics and,
    with ``history``, the PSNR after every iteration, which the application's outputs do not
    use).  ``constants``: the operator's constants from earlier solves
    (:func:`kaleidospec.solve_constants.constants_for`), the row scale and FISTA's step taken
    from them where they hold them.  Adds ``seconds``, ``noise`` (in the unit-row-norm
    units) and, with ``constants``, ``constants_estimated`` (the names this solve estimated;
    empty when it read them all)."""
    from recon.app import reconstruct

    op, g = normalised(op, g, constants)
    options = solver_metric(solver, metric)
    if constants is not None and solver == "fista-tv":
        options["constants"] = constants
    noise = None if noise is None else float(noise) * op.scale
    t0 = time.perf_counter()
    tau = prior_weight(prior, solver, tau, n_views, noise)
    cube, info = reconstruct(g, op, solver=solver, iters=iters, tol=tol, tau=tau, x0=x0,
                             truth=truth, wavelengths=wavelengths, progress=progress,
                             prior=prior, noise=noise, history=history, **options)
    info["seconds"] = time.perf_counter() - t0
    info["noise"] = noise
    if constants is not None:
        info["constants_estimated"] = list(constants.estimated)
    return cube, info


# ------------------------------------------------------------------------------- calibrated
def calibrated_operator(cal, view_ids, model: str | None = None):
    """:func:`recon.calibration.operator_from_calibration` with the gains folded in: the
    operator maps a cube in radiance (cube) units to exposure-normalised DN.

    ``model`` is one of :data:`kaleidospec.models.MODELS` or ``None``
    (:func:`kaleidospec.models.model_of`).
    """
    from kaleidospec.models import model_gains, model_of
    from recon.calibration.operator import operator_from_calibration

    kind = model_of(cal, model)
    gains = model_gains(cal, kind)
    if not np.all(gains > 0):
        raise InputError("the calibration's radiometric gains must be positive")
    return operator_from_calibration(cal, view_ids, model=kind, band_scale=1.0 / gains)


def frame_measurements(frame, metadata, cal, view_ids) -> np.ndarray:
    """The (K, Hv, Wm) views ``view_ids`` cut out of a raw frame with the calibration's boxes,
    divided by the frame's exposure factor ``radiance_scale`` (1 when the sidecar has none):
    the calibration divided its captures' out, so frames and calibration share one
    radiometric scale."""
    from recon.calibration import measurements

    s = (metadata or {}).get("radiance_scale")
    s = 1.0 if s is None else float(s)
    if not (math.isfinite(s) and s > 0):
        raise InputError(f"the frame's radiance_scale must be positive, got {s}")
    return measurements(frame, cal, view_ids, metadata=metadata) / np.float32(s)


def reconstruct_views(frame, metadata, cal, n_views, *, solver: str = DEFAULTS["solver"],
                      iters: int = DEFAULTS["iters"], tol=DEFAULTS["tol"], tau=None, x0=None,
                      truth=None, progress: bool = False, design=None,
                      model: str | None = None, prior: str | None = None,
                      metric=DEFAULTS["metric"], history: bool = False,
                      cached_constants: bool = True):
    """Reconstruct from the first ``n_views`` views of a raw frame with a calibration.

    Parameters
    ----------
    frame : (Hs, Ws) array
        Raw frame (DN).
    metadata : dict
        Its sidecar: ``design_hash`` must match the calibration's; ``radiance_scale`` (the
        exposure factor) is divided out.
    cal : recon.calibration.Calibration
    n_views : int
        1..9, views taken in the order centre, left, right, top, bottom, corners; all must be
        in the calibration.
    solver, iters, tau, x0, progress, prior, metric, history
        As for :func:`recon.app.reconstruct` (``tau``, ``prior``, ``metric`` and ``history``:
        :func:`solve_views`).
    tol : float or None
        Stop once the relative change of the cube falls below it (:func:`solve_views`).
    truth : (v, v, L) or (H, W, L) array, optional
        Ground truth on the design's grid (moved onto the model's grid
        :func:`kaleidospec.models.cube_grid` with :func:`kaleidospec.models.truth_on_grid`,
        using ``design`` or the design in the sidecar) or already on it.
    model : str, optional
        The calibrated forward model (:func:`calibrated_operator`).
    cached_constants : bool
        Take the operator's constants (its row scale, FISTA's step) from the cache folder and
        keep the ones estimated there (:mod:`kaleidospec.solve_constants`); False estimates
        them and keeps nothing.

    Returns
    -------
    cube : (H, W, L) float32, on :func:`kaleidospec.models.cube_grid`, cube units
    info : dict
        :func:`recon.app.reconstruct`'s, plus ``view_ids``, ``seconds`` and, with a truth,
        ``metrics`` and ``truth_grid`` (the truth on the reconstruction grid).
    """
    from kaleidospec.instrument import design_of
    from kaleidospec.models import cube_grid, model_of, truth_on_grid
    from kaleidospec.solve_constants import constants_for
    from recon.calibration import check_design

    ids = first_views(n_views)
    check_design(cal, metadata)
    _check_calibrated(cal, ids)
    g = frame_measurements(frame, metadata, cal, ids)
    tg = None
    if truth is not None:
        t = np.asarray(truth, dtype=np.float32)
        tg = t if t.shape == cube_grid(cal, model) + (cal.n_bands,) else \
            truth_on_grid(t, design_of(metadata, design), cal, model, ids)
    cube, info = solve_views(calibrated_operator(cal, ids, model), g, len(ids), solver=solver,
                             iters=iters, tol=tol, tau=tau, x0=x0, truth=tg,
                             wavelengths=cal.wavelengths, progress=progress,
                             noise=measurement_noise(g, metadata, cal.noise), prior=prior,
                             metric=metric, history=history,
                             constants=constants_for(cal, ids, model_of(cal, model))
                             if cached_constants else None)
    info["view_ids"] = list(ids)
    if tg is not None:
        info["truth_grid"] = tg
    return cube, info


# ------------------------------------------------------------------------------- exact operator
def reconstruct_oracle(frame, metadata, design, n_views, *, solver: str = DEFAULTS["solver"],
                       iters: int = DEFAULTS["iters"], tol=DEFAULTS["tol"], tau=None,
                       truth=None, progress: bool = False, inversion: bool = True, op=None,
                       prior: str | None = None, metric=DEFAULTS["metric"],
                       history: bool = False):
    """Reconstruct a frame with the design's exact operator
    (:func:`kaleidospec.instrument.oracle_operator`, or ``op``), on the ground-truth grid
    (``history``: :func:`solve_views`).  Returns ``(cube (v, v, L), info)``."""
    from kaleidospec.instrument import oracle_measurements, oracle_operator

    first_views(n_views)
    check_oracle_solver(solver)
    g = oracle_measurements(frame, metadata, design, n_views)
    if op is None:
        op = oracle_operator(design, n_views, inversion=inversion)
    return solve_views(op, g, n_views, solver=solver, iters=iters, tol=tol, tau=tau,
                       truth=truth, wavelengths=design.wavelengths, progress=progress,
                       noise=measurement_noise(g, metadata, design_noise(design)), prior=prior,
                       metric=metric, history=history)


def check_oracle_solver(solver: str) -> str:
    """``solver`` if it can reconstruct with the exact operator: GAP-TV projects onto each
    measurement row with diag(HHᵀ)⁻¹, exact only when rows share no voxel (the shifted model);
    the exact operator's pixels share texels (footprints, smear, blur) and GAP-TV diverges."""
    if solver == "gap-tv":
        raise InputError("gap-tv cannot reconstruct with the exact operator (its measurement "
                         "rows share texels); use fista-tv or twist, or leave the oracle out "
                         "(--no-oracle)")
    return solver


# ------------------------------------------------------------------------------- many frames
class Reconstructor:
    r"""One frame's inverse problem, set up once and reused for every frame of a sequence.

    Two kinds (constructors):

    - :meth:`calibrated` — what the instrument does: the problem of :func:`reconstruct_views`
      (operator :func:`calibrated_operator`, gains folded in; the measurement over the frame's
      ``radiance_scale``), on the calibration's grid;
    - :meth:`oracle` — the exact operator of the design
      (:func:`kaleidospec.instrument.oracle_operator`) on the ground-truth grid, to separate
      the engine's behaviour from calibration errors.

    Either way the operator and the solver's step are computed once, not per frame: GAP-TV's
    :math:`1/\lVert\Phi^{-1/2}H\rVert^2`, FISTA-TV's band metric (where the prior takes it,
    as :func:`solve_views` takes it for a still) or :math:`\lVert H\rVert^2`
    (:meth:`solver_options`).

    Parameters
    ----------
    op : LinearOperator
        ``(L, H, W) -> (K, Hv, Wm)``.
    measure : callable
        ``measure(frame, metadata) -> g`` (K, Hv, Wm) float32.
    solver : str
        A :mod:`recon.solvers` name.
    tau : float, optional
        TV weight (:func:`tv_weight`'s default if None: with ``noise``, set by the first
        frame measured and kept for the sequence); another prior's strength (None: the prior
        sets it from the first frame's noise).
    prior : str, optional
        A :data:`recon.priors.PRIORS` name (None: ``"tv"``).
    threads : int, optional
        Threads of the TV prox (GAP-TV and the temporal variant).
    to_grid : callable, optional
        ``to_grid(truth (v, v, L), metadata) -> truth on the operator's grid``.
    offset : callable, optional
        ``offset(metadata) -> (oy, ox)``: where the operator's grid sits on the truth's.
    noise : (2,) array_like, optional
        The sensor's photon-transfer curve (:func:`measurement_noise`).
    constants : recon.solvers.constants.OperatorConstants, optional
        The operator's constants from earlier solves (:mod:`kaleidospec.solve_constants`):
        the row scale and the solvers' steps are taken from it where it holds them.
    """

    def __init__(self, op, measure, *, solver: str = "gap-tv", tau: float | None = None,
                 threads: int | None = None, to_grid=None, offset=None, kind: str = "",
                 noise=None, prior: str | None = None, constants=None):
        from recon.operators import ScaledOperator
        from recon.priors import check_prior_name
        from recon.solvers.constants import OperatorConstants

        # The scaling and TV weight of solve_views, so that a video frame is reconstructed
        # exactly as `kaleidospec run` reconstructs a still.
        self.constants = OperatorConstants() if constants is None else constants
        scale = row_scale(op, self.constants)
        self.op = ScaledOperator(op, scale)
        self._raw = measure
        self.solver = solver
        self.prior = check_prior_name("tv" if prior is None else prior)
        self._noise_model = noise
        #: The measurement's rms noise (unit-row-norm units), set by the first frame measured.
        self.noise = None
        self._prior = None
        self.tau = None
        if self.prior != "tv":
            self.tau = prior_weight(self.prior, solver, tau, op.oshape[0])
        elif tau is not None or noise is None or solver not in TAU_PER_NOISE:
            self.tau = tv_weight(solver, tau, op.oshape[0])
        self.threads = threads
        self._to_grid = to_grid
        self._offset = offset
        self.kind = kind

    @classmethod
    def calibrated(cls, cal, n_views: int, **kw) -> "Reconstructor":
        """From a calibration: the first ``n_views`` views (centre, left, right, top, ...)."""
        from kaleidospec.instrument import design_of
        from kaleidospec.models import grid_offset, model_of, truth_mover
        from kaleidospec.solve_constants import constants_for

        ids = first_views(n_views)
        _check_calibrated(cal, ids)
        # Gains folded into the masks: the cube comes out in the scene's radiance units.
        op = calibrated_operator(cal, ids)
        # Where the grid lies on the scene, once per design (a video's frames share it).
        movers = {}

        def to_grid(t, meta):
            d = design_of(meta)
            if d.hash not in movers:
                movers[d.hash] = truth_mover(d, cal, view_ids=ids)
            return movers[d.hash](t)

        return cls(op, lambda frame, meta: frame_measurements(frame, meta, cal, ids),
                   to_grid=to_grid,
                   offset=lambda meta: grid_offset(design_of(meta), cal), kind="calibrated",
                   noise=cal.noise, constants=constants_for(cal, ids, model_of(cal, None)), **kw)

    @classmethod
    def oracle(cls, design, n_views: int, **kw) -> "Reconstructor":
        """The exact operator of ``design`` (on the ground-truth grid)."""
        from kaleidospec.instrument import oracle_measurements, oracle_operator

        op = oracle_operator(design, n_views)
        return cls(op, lambda frame, meta: oracle_measurements(frame, meta, design, n_views),
                   kind="oracle", noise=design_noise(design), **kw)

    def measurement(self, frame, metadata) -> np.ndarray:
        """The (K, Hv, Wm) measurement in the operator's units (the first one measured sets
        the TV weight where it follows the noise)."""
        g = self._raw(frame, metadata)
        if self.noise is None and self._noise_model is not None:
            self.noise = measurement_noise(g, metadata, self._noise_model) * self.op.scale
        if self.tau is None and self.prior == "tv":
            self.tau = tv_weight(self.solver, None, self.op.oshape[0], self.noise)
        return g * np.float32(self.op.scale)

    def truth_on_grid(self, truth, metadata) -> np.ndarray:
        """The ground truth (v, v, L) on the reconstruction grid."""
        t = np.asarray(truth, np.float32)
        want = (self.op.ishape[1], self.op.ishape[2], self.op.ishape[0])
        if t.shape == want or self._to_grid is None:
            return t
        return self._to_grid(t, metadata)

    def grid_offset(self, metadata) -> tuple[float, float]:
        """(oy, ox): reconstruction pixel (y, x) is truth pixel (y + oy, x + ox)."""
        return (0.0, 0.0) if self._offset is None else self._offset(metadata)

    def prior_options(self) -> dict:
        """The solver's prior keywords: ``tau`` for TV (the solvers build it), else the prior
        (built on first use, with the first frame's noise)."""
        if self.prior == "tv":
            return {"tau": self.tau}
        if self._prior is None:
            from recon.priors import make_prior

            self._prior = make_prior(self.prior, shape=self.op.ishape, dtype=np.float32,
                                     weight=self.tau, solver=self.solver, noise=self.noise,
                                     n_views=self.op.oshape[0], threads=self.threads)
        return {"prior": self._prior}

    def solver_options(self, prior=None) -> dict:
        """GAP-TV's step and prox threads, or FISTA-TV's step: the band metric where the
        prior takes it, as :func:`solve_views` solves a still (:data:`DEFAULTS`'s
        ``metric``), else the Lipschitz constant ‖H‖².  Each is computed on first use and
        kept in :attr:`constants`: the operator is the sequence's, so a frame does not
        repeat the estimate (15 or 16 forward/adjoint pairs, as many as a warm frame's
        iterations).

        ``prior`` is the prior object the solve takes (None: TV, built by the solver from
        ``tau``).  A prior of two stages keeps the scalar step for both (the band metric
        would leave the second stage to estimate ‖H‖² at every frame)."""
        opts = {}
        if self.solver == "fista-tv":
            # FISTA reads its step (the band metric, or ||H||^2) from the memo, or estimates it
            # there once for the sequence.
            opts["constants"] = self.constants
            if _takes_band_metric(prior):
                opts["metric"] = DEFAULTS["metric"]
        if self.solver == "gap-tv":
            opts["step"] = self.constants.get(GAP_STEP, lambda: _gap_step(self.op),
                                              check=lambda v: np.ndim(v) == 0)
            if self.threads is not None:
                opts["threads"] = self.threads
        return opts

    def solve(self, g, *, iters: int, x0=None, mu: float = 0.0, callback=None
              ) -> tuple[np.ndarray, dict]:
        r"""Reconstruct one frame → (cube (H, W, L), info).

        ``x0`` (H, W, L) warm-starts the solver; ``mu`` > 0 (with ``x0``) adds the temporal
        term :math:`\mu\lVert f - x_0\rVert_1` (:mod:`recon.temporal`: GAP carries its
        iteration's state into it; the other solvers take it as a prior around the spatial
        one, :class:`~recon.temporal.TemporalPrior`).
        """
        if self.tau is None and self.prior == "tv":
            raise InputError("the TV weight follows the noise: measure a frame "
                             "(Reconstructor.measurement) before solving, or give tau")
        t0 = time.perf_counter()
        x0_bm = None if x0 is None else np.ascontiguousarray(
            np.moveaxis(np.asarray(x0, np.float32), 2, 0))
        g = np.asarray(g, np.float32)
        if mu > 0 and x0_bm is not None and self.solver == "gap-tv":
            from recon.temporal import gap_tv_temporal

            res = gap_tv_temporal(self.op, g, ref=x0_bm, mu=float(mu), iters=int(iters),
                                  x0=x0_bm, callback=callback, **self.prior_options(),
                                  **self.solver_options())
        elif mu > 0 and x0_bm is not None:
            # Any other solver: the temporal term as a prior around the spatial one.
            from recon.priors import TVPrior
            from recon.solvers import solve
            from recon.temporal import TemporalPrior

            spatial = self.prior_options().get("prior") or TVPrior(self.tau,
                                                                   threads=self.threads)
            temporal = TemporalPrior(spatial, x0_bm, float(mu))
            res = solve(self.solver, self.op, g, iters=int(iters), x0=x0_bm,
                        callback=callback, prior=temporal, **self.solver_options(temporal))
        else:
            from recon.solvers import solve

            mu = 0.0
            prior_kw = self.prior_options()
            res = solve(self.solver, self.op, g, iters=int(iters), x0=x0_bm,
                        callback=callback, **prior_kw,
                        **self.solver_options(prior_kw.get("prior")))
        cube = np.ascontiguousarray(np.moveaxis(res.x, 0, 2), dtype=np.float32)
        if not np.all(np.isfinite(cube)):
            raise RuntimeError(f"solver {self.solver!r} diverged (non-finite values)")
        return cube, {"iters": int(res.iterations), "wall_seconds": time.perf_counter() - t0,
                      "tau": self.tau, "mu": float(mu), "prior": self.prior}
