"""Design sweeps: one design parameter varied over a range, each point rendered and measured.

For every value of the swept field (``mirror_length_mm`` or ``prism_apex_deg``) the engine builds
the design, then, in a worker process (or on a Dask cluster):

1. measures the design in monochromatic renders of the physical simulator
   (:func:`sim.measure.measure_all`): view size (the pitch between copies, predicted
   :math:`p_v = m\\, w\\, f_{\\text{img}}/(f_{\\text{col}}\\Delta)` with :math:`m = b/a`,
   :math:`1/a + 1/b = 1/f_r`), minification, gaps/overlap between neighbouring copies,
   clipping by the sensor, vignetting, and the dispersion span (predicted by Sellmeier +
   prism geometry);
2. reconstructs a scene from the first ``n_views`` views with the calibrated pipeline
   (:mod:`kaleidospec.pipeline`: calibrate from rendered captures, render, solve) and scores
   it (PSNR, peak 1 on the cube scaled to [0, 1]; SAM in degrees).

Points that make no physical sense are recorded, not crashed on: a design that cannot be built
(the relay forms no real image because ``mirror_length_mm + relay_gap_mm ≤ relay_focal_mm`` —
with ``relay_gap_mm = 0`` that is a mirror shorter than the relay's focal length — or total
internal reflection in the prism) is ``invalid``; a design whose views do not fit the sensor is
``views-do-not-fit`` (measured, so the clipping shows, but not reconstructed).

Result store
------------
``<out>/points/<key>.json``, one file per point, written atomically; ``key`` is the design hash
(:attr:`sim.design.Design.hash`, which covers the swept value and every override) plus a hash of
the settings that change the result (scene, views, solver, iterations, τ, seed, samples, what
was computed). A point whose file exists is never recomputed: rerunning a sweep, or extending
its range or refining its step, computes only the new points. Failures (status ``error``) are
reported but not stored, so a rerun retries them. ``<out>/<kind>.csv`` and ``<out>/<kind>.png``
collect every point of the current range.

Parallelism
-----------
Points are independent. Locally they run in a ``spawn`` process pool (default: one worker per
core, each drjit limited to ``cores // workers`` threads); with ``scheduler="tcp://host:port"``
they run on a Dask cluster (``dask.distributed``, an optional dependency imported only then;
the workers need this package installed and see their own ``KALEIDOSPEC_CACHE``). Workers
receive and return JSON-ready dicts only, and only the driver writes files.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from kaleidospec.pipeline import DEFAULTS
from recon.errors import InputError

__all__ = [
    "SWEEPS",
    "MEASURE_VERSION",
    "SweepSettings",
    "SweepResult",
    "sweep_values",
    "make_points",
    "point_key",
    "evaluate_point",
    "run_sweep",
    "rows_from_results",
    "write_csv",
    "plot_sweep",
    "smallest_reaching",
    "CSV_COLUMNS",
]

#: Sweep kind → (design field, unit, label).
SWEEPS: dict[str, tuple[str, str, str]] = {
    "mirror-length": ("mirror_length_mm", "mm", "mirror length"),
    "prism-apex": ("prism_apex_deg", "°", "prism apex angle"),
}
#: Bumped when what a point computes changes, so old stored results are not reused.
MEASURE_VERSION = 2
#: The dispersion span the paper asks for over the pass band (px).
TARGET_SPAN_PX = 60.0


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
    solver, iters, tau, seed
        Reconstruction settings and the noise seed.
    spp : int
        Samples per pixel of the measurement renders.
    reconstruct : bool
        Run the calibrate/render/reconstruct pipeline (PSNR/SAM) or only measure.
    """

    kind: str
    design: str = "small"
    overrides: dict = field(default_factory=dict)
    scene: str = "colorchecker"
    n_views: int = 5
    solver: str = DEFAULTS["solver"]
    iters: int = DEFAULTS["iters"]
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

    def key(self) -> str:
        """Hash of the settings that change a point's result (not the design: it has its own)."""
        blob = json.dumps({
            "v": MEASURE_VERSION, "scene": str(self.scene), "n_views": int(self.n_views),
            "solver": self.solver, "iters": int(self.iters),
            "tau": None if self.tau is None else float(self.tau), "seed": int(self.seed),
            "spp": int(self.spp), "reconstruct": bool(self.reconstruct),
        }, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]

    def to_dict(self) -> dict:
        return {"kind": self.kind, "design": self.design, "overrides": dict(self.overrides),
                "scene": str(self.scene), "n_views": int(self.n_views), "solver": self.solver,
                "iters": int(self.iters), "tau": self.tau, "seed": int(self.seed),
                "spp": int(self.spp), "reconstruct": bool(self.reconstruct)}


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
def _base_design(settings: SweepSettings):
    from sim.design import get_design

    return get_design(settings.design, settings.overrides)


def make_points(settings: SweepSettings, values) -> list[dict]:
    """One JSON-ready payload per value: the design (or why there is none) and the settings.

    The design gets the swept value and, like :func:`kaleidospec.pipeline.design_for_views`,
    ``views`` widened to the first ``n_views`` views.
    """
    base = _base_design(settings)
    out = []
    for x in values:
        x = float(x)
        p: dict[str, Any] = {"kind": settings.kind, "field": settings.field, "value": x,
                             "settings": settings.to_dict(), "settings_key": settings.key(),
                             "design": None, "design_hash": None, "status": "pending",
                             "reason": ""}
        try:
            d = base.replace(**{settings.field: x})
            need = set(range(int(settings.n_views)))
            if not need <= set(d.views):
                d = d.replace(views=tuple(sorted(set(d.views) | need)))
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


def _init_worker(threads: int | None) -> None:
    """Worker start-up: limit drjit's threads so parallel workers do not oversubscribe."""
    if threads:
        import drjit as dr

        from sim.variant import ensure_variant

        ensure_variant()
        dr.set_thread_count(int(threads))


def _finite(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return _finite(x.item())
    return x


def evaluate_point(payload: dict) -> dict:
    """Measure (and reconstruct at) one design point; never raises.

    Returns the payload with ``status`` (``ok``, ``invalid``, ``views-do-not-fit`` or ``error``),
    ``reason``, ``measure`` (:func:`sim.measure.measure_all`), ``recon`` (PSNR/SAM, seconds) and
    ``seconds``. JSON-ready (non-finite numbers become None).
    """
    t0 = time.perf_counter()
    out = dict(payload)
    if payload.get("threads"):
        _init_worker(payload["threads"])
    if payload["design"] is None:
        out["seconds"] = 0.0
        return _finite(out)
    try:
        from sim import measure, transport
        from sim.design import Design

        d = Design.from_dict(payload["design"])
        s = payload["settings"]
        fits = d.views_fit
        out["measure"] = measure.measure_all(d, spp=int(s["spp"]), seed=int(s["seed"]))
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
            transport._MEMO.clear()
        except Exception:  # noqa: BLE001
            pass
    out["seconds"] = time.perf_counter() - t0
    return _finite(out)


def _reconstruct(design, s: dict) -> dict:
    """Calibrate, render ``s['scene']`` and reconstruct from the first ``n_views`` views."""
    from kaleidospec import pipeline
    from recon.metrics import psnr, sam

    t0 = time.perf_counter()
    cal = pipeline.calibrate(design, progress=False)
    t_cal = time.perf_counter() - t0
    frame, meta, truth, _ = pipeline.render_scene(s["scene"], design, seed=int(s["seed"]))
    cube, info = pipeline.reconstruct_views(frame, meta, cal, int(s["n_views"]),
                                            solver=s["solver"], iters=int(s["iters"]),
                                            tau=s["tau"], truth=truth, design=design)
    tg = info["truth_grid"]
    return {"psnr_db": float(psnr(cube, tg)), "sam_deg": float(sam(cube, tg)),
            "calibrate_seconds": t_cal, "seconds": time.perf_counter() - t0,
            "cube_shape": list(cube.shape)}


# ---------------------------------------------------------------------- store
def _load_point(path: Path) -> dict | None:
    try:
        with open(path, encoding="utf-8") as fh:
            r = json.load(fh)
    except (OSError, ValueError):
        return None  # a damaged file is recomputed
    return r if isinstance(r, dict) and r.get("status") in _STORED else None


_STORED = ("ok", "invalid", "views-do-not-fit")


def _store_point(folder: Path, result: dict) -> Path:
    from recon.io.atomic import write_text

    path = folder / f"{point_key(result)}.json"
    write_text(path, json.dumps(result, indent=1, sort_keys=True, allow_nan=False) + "\n")
    return path


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
    if workers <= 1:
        _init_worker(threads)
        for p in payloads:
            yield fn(p)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # spawn: drjit/LLVM state must not be forked.
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                             initializer=_init_worker, initargs=(threads,)) as ex:
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
            results[k] = _finite({**p, "seconds": 0.0})
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
            cores = os.cpu_count() or 1
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
    rows = rows_from_results(ordered, settings)
    csv_path = write_csv(rows, out / f"{settings.kind}.csv", settings.field)
    res = SweepResult(settings, ordered, rows, csv_path, None, len(todo), reused,
                      time.perf_counter() - t0)
    res.apex_60px_pred, res.apex_60px_meas = _apex_60(settings, rows)
    if plot:
        res.plot_path = plot_sweep(rows, out / f"{settings.kind}.png", settings)
    res.summary = summary_lines(res)
    for line in res.summary:
        say(line)
    return res


# ---------------------------------------------------------------------- tables and plots
CSV_COLUMNS = [
    "status", "reason", "design_hash", "view_rect_px",
    "minification_pred", "minification_meas",
    "view_size_pred_px", "view_size_meas_px", "view_size_err_pct", "view_centre_err_px",
    "gap_x_pred_px", "gap_x_meas_px", "gap_y_pred_px", "gap_y_meas_px",
    "views_fit_pred", "clipped_views", "throughput_min", "edge_falloff_max",
    "dispersion_span_pred_px", "dispersion_span_meas_px", "dispersion_span_err_px",
    "dispersion_max_err_px", "psnr_db", "sam_deg", "recon_seconds", "seconds",
]


def _num(x) -> float:
    return float("nan") if x is None else float(x)


def rows_from_results(results: list[dict], settings: SweepSettings) -> list[dict]:
    """Flat CSV rows (one per point, in sweep order) from stored/computed point results."""
    used = [str(v) for v in range(int(settings.n_views))]
    rows = []
    for r in results:
        row: dict[str, Any] = {settings.field: r["value"], "status": r["status"],
                               "reason": r.get("reason", ""),
                               "design_hash": r.get("design_hash") or ""}
        m = r.get("measure") or {}
        pr, ge = m.get("predicted") or {}, m.get("geometry") or {}
        di, wh = m.get("dispersion") or {}, m.get("white") or {}
        vs_p, vs_m = _num(pr.get("view_size_px")), _num(ge.get("view_size_px"))
        sp_p, sp_m = _num(di.get("span_pred_px")), _num(di.get("span_meas_px"))
        thr = [_num(v) for k, v in (wh.get("throughput_rel") or {}).items() if k in used]
        fal = [_num(v) for k, v in (wh.get("edge_falloff") or {}).items() if k in used]
        cerr = [abs(_num(x)) for x in (ge.get("view_centre_err_px") or [])]
        rec = r.get("recon") or {}
        row.update({
            "view_rect_px": pr.get("view_rect_px", ""),
            "minification_pred": _num(pr.get("minification")),
            "minification_meas": _num(ge.get("minification")),
            "view_size_pred_px": vs_p, "view_size_meas_px": vs_m,
            "view_size_err_pct": 100.0 * (vs_m - vs_p) / vs_p if vs_p else float("nan"),
            "view_centre_err_px": max(cerr) if cerr else float("nan"),
            "gap_x_pred_px": _num(pr.get("gap_x_px")), "gap_x_meas_px": _num(wh.get("gap_x_px")),
            "gap_y_pred_px": _num(pr.get("gap_y_px")), "gap_y_meas_px": _num(wh.get("gap_y_px")),
            "views_fit_pred": pr.get("views_fit", ""),
            "clipped_views": " ".join(str(v) for v in wh.get("clipped_views", [])),
            "throughput_min": min(thr) if thr else float("nan"),
            "edge_falloff_max": max(fal) if fal else float("nan"),
            "dispersion_span_pred_px": sp_p, "dispersion_span_meas_px": sp_m,
            "dispersion_span_err_px": sp_m - sp_p,
            "dispersion_max_err_px": _num(di.get("max_phi_err_px")),
            "psnr_db": _num(rec.get("psnr_db")), "sam_deg": _num(rec.get("sam_deg")),
            "recon_seconds": _num(rec.get("seconds")), "seconds": _num(r.get("seconds")),
        })
        rows.append(row)
    return rows


def _fmt(x) -> str:
    if isinstance(x, float):
        return "" if not math.isfinite(x) else f"{x:.6g}"
    return str(x)


def write_csv(rows: list[dict], path, field_name: str) -> Path:
    """Write the rows (swept field first, then :data:`CSV_COLUMNS`) atomically; empty cells
    for quantities that could not be measured."""
    from recon.io.atomic import write_text

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    cols = [field_name] + CSV_COLUMNS
    w.writerow(cols)
    for r in rows:
        w.writerow([_fmt(r.get(c, "")) for c in cols])
    return write_text(path, buf.getvalue())


def smallest_reaching(values, spans, target: float = TARGET_SPAN_PX) -> float | None:
    """The smallest swept value at which ``spans`` reaches ``target``, interpolated linearly
    between the last point below and the first at or above; None if never reached (NaN spans
    are skipped). The first point already reaching it gives its own value."""
    pts = [(float(v), float(s)) for v, s in zip(values, spans) if s is not None and math.isfinite(s)]
    pts.sort()
    for i, (v, s) in enumerate(pts):
        if s >= target:
            if i == 0:
                return v
            v0, s0 = pts[i - 1]
            return v0 + (target - s0) * (v - v0) / (s - s0)
    return None


def _apex_60(settings: SweepSettings, rows) -> tuple[float | None, float | None]:
    """Predicted (Sellmeier, bisection) and measured (sweep, interpolated) apex for 60 px."""
    if settings.kind != "prism-apex":
        return None, None
    from sim.glass import apex_for_span

    d = _base_design(settings)
    try:
        pred = apex_for_span(d.prism_glass, TARGET_SPAN_PX, d.filter_min_nm, d.filter_max_nm,
                             d.prism_center_nm, d.imaging_focal_mm, d.sensor_pixel_um)
    except InputError:
        pred = None
    meas = smallest_reaching([r[settings.field] for r in rows],
                             [r["dispersion_span_meas_px"] for r in rows])
    return pred, meas


def summary_lines(res: SweepResult) -> list[str]:
    """Human-readable summary: agreement figures, timing, and the 60 px apex for apex sweeps."""
    s, rows = res.settings, res.rows
    unit = SWEEPS[s.kind][1]
    lines = [f"{s.kind} ({s.design}): {len(rows)} points, {res.computed} computed, "
             f"{res.reused} reused, {res.seconds:.1f} s"]
    ok = [r for r in rows if r["status"] in ("ok", "views-do-not-fit")]
    if ok:
        dv = np.nanmax(np.abs([r["view_size_err_pct"] for r in ok]))
        dd = np.nanmax(np.abs([r["dispersion_span_err_px"] for r in ok]))
        lines.append(f"  max |view size meas − pred| = {dv:.3f} % (target ≤ 1 %); "
                     f"max |dispersion span meas − pred| = {dd:.3f} px (target ≤ 0.5 px)")
    for r in rows:
        if r["status"] not in ("ok",):
            lines.append(f"  {s.field} = {r[s.field]:g}: {r['status']}: {r['reason']}")
    lines.append(f"  CSV: {res.csv_path}" + (f"; plot: {res.plot_path}" if res.plot_path else ""))
    if s.kind == "prism-apex":
        d = _base_design(s)
        pred = (f"{res.apex_60px_pred:.2f}{unit}" if res.apex_60px_pred is not None
                else "not reachable before total internal reflection")
        meas = (f"{res.apex_60px_meas:.2f}{unit}" if res.apex_60px_meas is not None
                else "not reached in the swept range")
        lines.append(f"smallest apex for a {TARGET_SPAN_PX:g} px span over "
                     f"{d.filter_min_nm:g}–{d.filter_max_nm:g} nm ({d.prism_glass}, "
                     f"{d.imaging_focal_mm:g} mm lens, {d.sensor_pixel_um:g} µm pixels): "
                     f"predicted {pred}, measured {meas}")
    return lines


def plot_sweep(rows: list[dict], path, settings: SweepSettings) -> Path:
    """Every quantity against the swept value (predicted dashed, measured solid), the paper's
    design marked by a vertical line and invalid points by grey bands; PNG written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from recon.io.atomic import atomic_path
    from sim.design import PRESETS

    f = settings.field
    unit = SWEEPS[settings.kind][1]
    x = np.array([r[f] for r in rows], dtype=np.float64)

    def col(name):
        return np.array([_num(r.get(name)) if r.get(name) != "" else np.nan for r in rows],
                        dtype=np.float64)

    panels = [
        ("minification m = b/a", [("minification_pred", "predicted", "--"),
                                  ("minification_meas", "measured", "-o")]),
        ("view size (pitch), px", [("view_size_pred_px", "predicted", "--"),
                                   ("view_size_meas_px", "measured", "-o")]),
        ("gap between views, px (<0: overlap)", [("gap_x_pred_px", "x predicted", "--"),
                                                 ("gap_x_meas_px", "x measured", "-o"),
                                                 ("gap_y_pred_px", "y predicted", ":"),
                                                 ("gap_y_meas_px", "y measured", "-s")]),
        ("vignetting (used views)", [("throughput_min", "min throughput / centre", "-o"),
                                     ("edge_falloff_max", "max edge fall-off", "-s")]),
        ("dispersion span 450–700 nm, px", [("dispersion_span_pred_px", "predicted", "--"),
                                            ("dispersion_span_meas_px", "measured", "-o")]),
        ("measured − predicted", [("view_size_err_pct", "view size, %", "-o"),
                                  ("dispersion_span_err_px", "dispersion span, px", "-s")]),
        (f"PSNR, dB ({settings.n_views} views)", [("psnr_db", "PSNR", "-o")]),
        (f"SAM, ° ({settings.n_views} views)", [("sam_deg", "SAM", "-o")]),
    ]
    fig, axes = plt.subplots(2, 4, figsize=(17, 7.5), constrained_layout=True)
    paper = getattr(PRESETS["paper"], f)
    bad = x[[r["status"] not in ("ok",) for r in rows]]
    step = float(np.min(np.diff(np.unique(x)))) if np.unique(x).size > 1 else 1.0
    for ax, (title, series) in zip(axes.ravel(), panels):
        for name, label, style in series:
            y = col(name)
            if np.isfinite(y).any():
                ax.plot(x, y, style, label=label, ms=4)
        if title.startswith("dispersion"):
            ax.axhline(TARGET_SPAN_PX, color="tab:red", lw=0.8, ls=":", label="60 px")
        for b in bad:
            ax.axvspan(b - 0.4 * step, b + 0.4 * step, color="0.85", lw=0)
        # The paper's design is always marked, the axis widened to show it if need be.
        ax.axvline(paper, color="k", lw=0.8, ls="-.", label=f"paper ({paper:g}{unit})")
        ax.set_xlim(min(x.min() - step, paper - step), max(x.max() + step, paper + step))
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(f"{SWEEPS[settings.kind][2]} ({unit})")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.suptitle(f"{settings.kind} sweep, design {settings.design}"
                 + (f" ({', '.join(f'{k}={v}' for k, v in settings.overrides.items())})"
                    if settings.overrides else "")
                 + "; grey: invalid / views do not fit", fontsize=11)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return path
