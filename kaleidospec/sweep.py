"""Design sweeps: one design parameter varied over a range, each point rendered and measured.

For every value of the swept field (``mirror_length_mm`` or ``prism_apex_deg``) the engine builds
the design, then, in a worker process (or on a Dask cluster):

1. measures the design in monochromatic renders of the physical simulator
   (:func:`sim.measure.measure_all`): view size (the pitch between copies, predicted
   :math:`p_v = m\\, w\\, f_{\\text{img}}/(f_{\\text{col}}\\Delta)` with :math:`m = b/a`,
   :math:`1/a + 1/b = 1/f_r`), minification, gaps/overlap between neighbouring copies,
   clipping by the sensor, vignetting, and the dispersion span (predicted by Sellmeier +
   prism geometry);
2. reconstructs a scene from the first ``n_views`` views as ``kaleidospec run`` does
   (:func:`kaleidospec.calibrate.calibrate` from rendered captures,
   :func:`kaleidospec.instrument.render_scene`,
   :func:`kaleidospec.reconstruct.reconstruct_views`) and scores it (PSNR, peak 1 on the cube
   scaled to [0, 1]; SAM in degrees).

Points that make no physical sense are recorded, not crashed on: a design that cannot be built
(the relay forms no real image because ``mirror_length_mm + relay_gap_mm ≤ relay_focal_mm`` —
with ``relay_gap_mm = 0`` that is a mirror shorter than the relay's focal length — or total
internal reflection in the prism) is ``invalid``; a design whose views do not fit the sensor is
``views-do-not-fit`` (measured, so the clipping shows, but not reconstructed).

Result store
------------
``<out>/points/<key>.json``, one file per point, a checked entry of :mod:`recon.io.cache` (written
atomically with a checksum; a damaged one is removed with a warning and computed again); ``key``
is the design hash
(:attr:`sim.design.Design.hash`, which covers the swept value and every override) plus a hash of
the settings that change the result (scene, views, solver, iterations, τ, seed, samples, what
was computed). A point whose file exists is never recomputed: rerunning a sweep, or extending
its range or refining its step, computes only the new points. Failures (status ``error``) are
reported but not stored, so a rerun retries them. ``<out>/<kind>.csv`` and ``<out>/<kind>.png``
collect every point of the current range (:func:`kaleidospec.report.write_sweep_csv`,
:func:`kaleidospec.report.plot_sweep`); for an apex sweep, the smallest apex reaching a 60 px
span is found by :func:`kaleidospec.evaluate.apex_reaching`.

Parallelism
-----------
Points are independent. Locally they run in a ``spawn`` process pool (default: one worker per
core, each drjit limited to ``cores // workers`` threads); with ``scheduler="tcp://host:port"``
they run on a Dask cluster (``dask.distributed``, an optional dependency imported only then;
the workers need this package installed and see their own ``KALEIDOSPEC_CACHE``). Workers
receive and return JSON-ready dicts only, and only the driver writes files.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from kaleidospec.reconstruct import DEFAULTS
from recon import kernels
from recon.errors import InputError

__all__ = ["SWEEPS", "MEASURE_VERSION", "SweepSettings", "SweepResult", "sweep_values",
           "make_points", "point_key", "evaluate_point", "run_sweep"]

#: Sweep kind → (design field, unit, label).
SWEEPS: dict[str, tuple[str, str, str]] = {
    "mirror-length": ("mirror_length_mm", "mm", "mirror length"),
    "prism-apex": ("prism_apex_deg", "°", "prism apex angle"),
}
#: Bumped when what a point computes changes, so old stored results are not reused.
MEASURE_VERSION = 4


@dataclass(frozen=True)
class SweepSettings:
    """What a sweep computes at each point (everything except the swept values).

    Attributes
    ----------
    kind : {"mirror-length", "prism-apex"}
    design : str
        Preset name (``small`` or ``paper``).
    overrides : dict
        ``--set`` overrides (name → value string), applied before the swept field.
    scene : str
        Scene reconstructed at each point (built-in name or cube file).
    n_views : int
        Views used for the reconstruction (1..9, order centre, left, right, top, bottom, corners).
    solver, iters, tol, tau, seed
        Reconstruction settings (at most ``iters`` iterations, fewer once the relative change
        falls below ``tol``) and the noise seed.
    spp : int
        Samples per pixel of the measurement renders.
    reconstruct : bool
        Calibrate, render and reconstruct at each point (PSNR/SAM) or only measure.
    """

    kind: str
    design: str = "small"
    overrides: dict = field(default_factory=dict)
    scene: str = "colorchecker"
    n_views: int = 5
    solver: str = DEFAULTS["solver"]
    iters: int = DEFAULTS["iters"]
    tol: float | None = DEFAULTS["tol"]
    tau: float | None = None
    seed: int = 0
    spp: int = 8
    reconstruct: bool = True

    def __post_init__(self):
        if self.kind not in SWEEPS:
            raise InputError(f"unknown sweep {self.kind!r}; known: {', '.join(SWEEPS)}")
        if not 1 <= int(self.n_views) <= 9:
            raise InputError(f"the number of views must be 1..9, got {self.n_views}")
        if int(self.iters) < 1 or int(self.spp) < 1:
            raise InputError("iterations and samples per pixel must be at least 1")
        if SWEEPS[self.kind][0] in self.overrides:
            raise InputError(f"{SWEEPS[self.kind][0]} is the swept field; do not --set it")

    @property
    def field(self) -> str:
        """The swept design field."""
        return SWEEPS[self.kind][0]

    @property
    def unit(self) -> str:
        """The swept field's unit."""
        return SWEEPS[self.kind][1]

    @property
    def label(self) -> str:
        """The swept field in words."""
        return SWEEPS[self.kind][2]

    def base_design(self):
        """The design before the swept value: the preset with the overrides (this checks
        them: unknown fields and bad values raise :class:`recon.errors.InputError`)."""
        from kaleidospec.instrument import get_design

        return get_design(self.design, self.overrides)

    def key(self) -> str:
        """Hash of the settings that change a point's result (not the design: it has its own)."""
        blob = json.dumps({
            "v": MEASURE_VERSION, "scene": str(self.scene), "n_views": int(self.n_views),
            "solver": self.solver, "iters": int(self.iters),
            "tol": None if self.tol is None else float(self.tol),
            "tau": None if self.tau is None else float(self.tau), "seed": int(self.seed),
            "spp": int(self.spp), "reconstruct": bool(self.reconstruct),
        }, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]

    def to_dict(self) -> dict:
        return {"kind": self.kind, "design": self.design, "overrides": dict(self.overrides),
                "scene": str(self.scene), "n_views": int(self.n_views), "solver": self.solver,
                "iters": int(self.iters), "tol": self.tol, "tau": self.tau,
                "seed": int(self.seed), "spp": int(self.spp),
                "reconstruct": bool(self.reconstruct)}


def sweep_values(start: float, stop: float, step: float) -> np.ndarray:
    """``start, start + step, …`` up to ``stop`` inclusive (float64, rounded to 1e-9).

    Raises :class:`InputError` for a non-positive step, ``stop < start`` or more than 1000 points.
    """
    vals = [start, stop, step]
    if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in vals):
        raise InputError("--start, --stop and --step must be finite numbers")
    if step <= 0:
        raise InputError(f"--step must be positive, got {step}")
    if stop < start:
        raise InputError(f"--stop ({stop}) must not be smaller than --start ({start})")
    n = int(math.floor((stop - start) / step + 1e-9)) + 1
    if n > 1000:
        raise InputError(f"{n} points is too many for one sweep (at most 1000)")
    return np.round(start + step * np.arange(n, dtype=np.float64), 9)


# ---------------------------------------------------------------------- points
def make_points(settings: SweepSettings, values) -> list[dict]:
    """One JSON-ready payload per value: the design (or why there is none) and the settings.

    The design gets the swept value and ``views`` widened to the first ``n_views`` views
    (:func:`kaleidospec.instrument.design_for_views`).
    """
    from kaleidospec.instrument import design_for_views

    base = settings.base_design()
    out = []
    for x in values:
        x = float(x)
        p: dict[str, Any] = {"kind": settings.kind, "field": settings.field, "value": x,
                             "settings": settings.to_dict(), "settings_key": settings.key(),
                             "design": None, "design_hash": None, "status": "pending",
                             "reason": ""}
        try:
            d = design_for_views(base.replace(**{settings.field: x}), int(settings.n_views))
        except InputError as err:
            p["status"], p["reason"] = "invalid", str(err)
            # Invalid points have no design hash: key them by the base design and the value.
            p["design_hash"] = "invalid-" + hashlib.sha256(
                f"{base.hash}:{settings.field}={x!r}".encode()).hexdigest()[:16]
        else:
            p["design"], p["design_hash"] = d.to_dict(), d.hash
        out.append(p)
    return out


def point_key(payload: dict) -> str:
    """File stem of a point's stored result: ``<design hash>-<settings key>``."""
    return f"{payload['design_hash']}-{payload['settings_key']}"


def evaluate_point(payload: dict) -> dict:
    """Measure (and reconstruct at) one design point; never raises.

    Returns the payload with ``status`` (``ok``, ``invalid``, ``views-do-not-fit`` or ``error``),
    ``reason``, ``measure`` (:func:`sim.measure.measure_all`), ``recon`` (PSNR/SAM, seconds) and
    ``seconds``. JSON-ready (non-finite numbers become None).
    """
    from kaleidospec import instrument
    from kaleidospec.report import finite

    t0 = time.perf_counter()
    out = dict(payload)
    if payload.get("threads"):
        instrument.limit_threads(payload["threads"])
    if payload["design"] is None:
        out["seconds"] = 0.0
        return finite(out)
    try:
        d = instrument.Design.from_dict(payload["design"])
        s = payload["settings"]
        fits = d.views_fit
        out["measure"] = instrument.measure_design(d, spp=int(s["spp"]), seed=int(s["seed"]))
        if not fits:
            out["status"] = "views-do-not-fit"
            out["reason"] = ("the views' light leaves the sensor or its own rectangle "
                             "(Design.views_fit is false)")
        else:
            out["status"] = "ok"
            if s["reconstruct"]:
                out["recon"] = _reconstruct(d, s)
    except Exception as err:  # noqa: BLE001 - a failed point is reported, the sweep goes on
        out["status"] = "error"
        out["reason"] = f"{type(err).__name__}: {err}"
    finally:
        try:
            # Each point has its own design hash: drop its in-memory transports.
            instrument.release_transports()
        except Exception:  # noqa: BLE001
            pass
    out["seconds"] = time.perf_counter() - t0
    return finite(out)


def _reconstruct(design, s: dict) -> dict:
    """Calibrate, render ``s['scene']`` and reconstruct from the first ``n_views`` views."""
    from kaleidospec.calibrate import calibrate
    from kaleidospec.instrument import render_scene
    from kaleidospec.reconstruct import reconstruct_views
    from recon.metrics import psnr, sam

    t0 = time.perf_counter()
    cal = calibrate(design, progress=False)
    t_cal = time.perf_counter() - t0
    # The scene itself (not its mean on the design's grid) goes onto the reconstruction grid.
    frame, meta, scene, _ = render_scene(s["scene"], design, seed=int(s["seed"]), native=True)
    cube, info = reconstruct_views(frame, meta, cal, int(s["n_views"]), solver=s["solver"],
                                   iters=int(s["iters"]), tol=s["tol"], tau=s["tau"],
                                   truth=scene, design=design)
    tg = info["truth_grid"]
    return {"psnr_db": float(psnr(cube, tg)), "sam_deg": float(sam(cube, tg)),
            "calibrate_seconds": t_cal, "seconds": time.perf_counter() - t0,
            "cube_shape": list(cube.shape)}


# ---------------------------------------------------------------------- store
def _load_point(path: Path) -> dict | None:
    """A stored point, or None (none yet, or a damaged or foreign entry: removed with one
    warning line by :func:`recon.io.cache.read_json`, so the point is computed again)."""
    from recon.io.cache import read_json

    # The file name is the point's key: its entry must say the same, and this code's version.
    r = read_json(path, kind="sweep-point", version=MEASURE_VERSION, key=path.stem)
    return r if r is not None and r.get("status") in _STORED else None


_STORED = ("ok", "invalid", "views-do-not-fit")


def _store_point(folder: Path, result: dict) -> Path:
    from kaleidospec.report import finite
    from recon.io.cache import write_json

    k = point_key(result)
    return write_json(folder / f"{k}.json", finite(result), kind="sweep-point",
                      design_hash=result.get("design_hash"), version=MEASURE_VERSION, key=k)


# ---------------------------------------------------------------------- execution
@dataclass
class SweepResult:
    """What :func:`run_sweep` produced."""

    settings: SweepSettings
    results: list[dict]
    rows: list[dict]
    csv_path: Path
    plot_path: Path | None
    computed: int
    reused: int
    seconds: float
    apex_60px_pred: float | None = None
    apex_60px_meas: float | None = None
    summary: list[str] = field(default_factory=list)


def _local_map(fn, payloads, workers: int, threads: int):
    """Yield results as they finish, from a spawn process pool (or in-process for 1 worker)."""
    from kaleidospec.instrument import limit_threads

    if workers <= 1:
        limit_threads(threads)
        for p in payloads:
            yield fn(p)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # spawn: drjit/LLVM state must not be forked.
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                             initializer=limit_threads, initargs=(threads,)) as ex:
        futs = [ex.submit(fn, p) for p in payloads]
        for f in as_completed(futs):
            yield f.result()


def _dask_map(fn, payloads, scheduler: str):
    """Yield results as they finish, from a Dask cluster (``dask.distributed``, lazily)."""
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise InputError("--scheduler needs dask.distributed (pip install 'distributed'); "
                         "without --scheduler the sweep runs in a local process pool") from None
    with Client(scheduler) as client:
        futs = client.map(fn, payloads, pure=False)
        for f in as_completed(futs):
            yield f.result()


def run_sweep(settings: SweepSettings, values, out_dir, *, workers: int | None = None,
              scheduler: str | None = None, plot: bool = True,
              log: Callable[[str], None] | None = print) -> SweepResult:
    """Run (or resume) a sweep and write ``<out_dir>/<kind>.csv`` and ``.png``.

    Parameters
    ----------
    settings : SweepSettings
    values : sequence of float
        Values of the swept field (:func:`sweep_values`).
    out_dir : path
        Result folder; ``points/`` holds one JSON per finished point.
    workers : int, optional
        Local worker processes (default: the number of cores, at most the number of points to
        compute). Ignored with ``scheduler``.
    scheduler : str, optional
        Dask scheduler address (``tcp://host:port``): run the points there.
    plot : bool
        Write the PNG (matplotlib, Agg).
    log : callable, optional
        Receives progress and summary lines.
    """
    from kaleidospec import report
    from kaleidospec.evaluate import apex_reaching

    t0 = time.perf_counter()
    say = log or (lambda s: None)
    out = Path(out_dir)
    store = out / "points"
    store.mkdir(parents=True, exist_ok=True)
    payloads = make_points(settings, values)
    results: dict[str, dict] = {}
    todo = []
    for p in payloads:
        k = point_key(p)
        r = _load_point(store / f"{k}.json")
        if r is not None:
            results[k] = r
        elif p["status"] == "invalid":
            # Nothing to render: recorded at once, with why.
            results[k] = report.finite({**p, "seconds": 0.0})
            _store_point(store, results[k])
        else:
            todo.append(p)
    reused = len(payloads) - len(todo)
    say(f"{settings.kind}: {len(payloads)} points, {reused} already done or invalid, "
        f"{len(todo)} to compute" + (f" on {scheduler}" if scheduler and todo else ""))
    if todo:
        if scheduler:
            it = _dask_map(evaluate_point, todo, scheduler)
        else:
            cores = kernels.cores()
            w = max(1, min(int(workers or cores), len(todo)))
            threads = max(1, cores // w)
            it = _local_map(evaluate_point, todo, w, threads)
        done = 0
        for r in it:
            done += 1
            results[point_key(r)] = r
            if r["status"] in _STORED:
                _store_point(store, r)
            say(f"  [{done}/{len(todo)}] {settings.field} = {r['value']:g}: {r['status']}"
                + (f" ({r['reason']})" if r["status"] != "ok" and r.get("reason") else "")
                + f", {r.get('seconds', 0.0):.1f} s")
    ordered = [results[point_key(p)] for p in payloads]
    rows = report.sweep_rows(ordered, settings)
    csv_path = report.write_sweep_csv(rows, out / f"{settings.kind}.csv", settings.field)
    res = SweepResult(settings, ordered, rows, csv_path, None, len(todo), reused,
                      time.perf_counter() - t0)
    if settings.kind == "prism-apex":
        res.apex_60px_pred, res.apex_60px_meas = apex_reaching(
            settings.base_design(), [r[settings.field] for r in rows],
            [r["dispersion_span_meas_px"] for r in rows])
    if plot:
        res.plot_path = report.plot_sweep(rows, out / f"{settings.kind}.png", settings)
    res.summary = report.sweep_summary_lines(res)
    for line in res.summary:
        say(line)
    return res
