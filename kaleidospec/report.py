"""What the runs leave for people to read: summary lines, metrics files, tables, plots and
videos; every file written atomically (:mod:`recon.io.atomic`).

The pictures of one cube (sRGB, band montages, spectra) are :mod:`recon.report`'s; this module
assembles them and everything else a run, a video or a sweep reports:

- common: :func:`finite` (JSON has no NaN), :func:`write_json`, :func:`progress_bar`;
- a still run (``kaleidospec run``): :func:`summary_lines` (the table the command prints) and
  :func:`probe_boxes` (where ``spectra.png`` samples the spectra);
- a video: :func:`write_frame_table` (``metrics.csv``) and :func:`write_animation` (the sRGB
  GIF/WebP);
- a design sweep: :func:`sweep_rows`, :func:`write_sweep_csv`, :func:`sweep_summary_lines`
  and :func:`plot_sweep`.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

__all__ = ["finite", "write_json", "progress_bar", "summary_lines", "probe_boxes",
           "FRAME_COLUMNS", "write_frame_table", "write_animation", "CSV_COLUMNS",
           "sweep_rows", "write_sweep_csv", "sweep_summary_lines", "plot_sweep"]


# ------------------------------------------------------------------------------- common
def finite(obj):
    """``obj`` with every non-finite float replaced by None (JSON has no NaN or infinity) and
    NumPy scalars made plain; dicts and sequences recursively (sequences become lists)."""
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def write_json(path, obj, *, indent: int = 2, sort_keys: bool = False) -> Path:
    """Write ``obj`` as JSON (no NaN allowed: see :func:`finite`), atomically."""
    from recon.io.atomic import write_text

    return write_text(path, json.dumps(obj, indent=indent, sort_keys=sort_keys,
                                       allow_nan=False) + "\n")


def progress_bar(total: int, desc: str, show: bool = True):
    """A progress report of ``total`` steps on stderr: a bar on a terminal (cleared when
    done), one line when the work ends elsewhere, nothing unless ``show``
    (:func:`recon.progress.progress_bar`)."""
    from recon.progress import progress_bar as bar

    return bar(total=total, desc=desc, unit="step", show=show)


# ------------------------------------------------------------------------------- still runs
def summary_lines(result) -> list[str]:
    """The human summary ``kaleidospec run`` prints."""
    lines = [f"scene {result['scene']}, design {result['design_hash']}, cube "
             f"{'x'.join(str(x) for x in result['cube_shape'])}, {result.get('model', 'shifted')}"
             f" model, {result['solver']} "
             + (f"until a relative change < {result['tol']:g} (at most {result['iters']} "
                f"iterations)" if result.get("tol") else f"x{result['iters']}")
             + ", tau " + " / ".join(
                 f"{e['tau']:g}" for e in result["views"].values() if e.get("tau") is not None),
             f"calibration: {'cached' if result['calibration']['cached'] else 'rendered'} "
             f"({result['calibration']['seconds']:.1f} s)"]
    # dE00: per pixel of the sRGB rendering; dE00p: per ColorChecker patch (mean spectra).
    head = (f"{'views':>5} {'PSNR':>7} {'PSNRb':>7} {'SSIM':>6} {'SAM':>6} {'dE00':>6} "
            f"{'dE00p':>6} {'it':>4} {'s':>6} {'oracle':>7}")
    lines += [head, "-" * len(head)]
    for n, e in result["views"].items():
        o = result["oracle"].get(n, {}).get("psnr")

        def f(x, fmt):
            return format(x, fmt) if x is not None else "n/a".rjust(len(format(0.0, fmt)))
        lines.append(f"{n:>5} {f(e['psnr'], '7.2f')} {f(e['psnr_bandwise'], '7.2f')} "
                     f"{f(e['ssim'], '6.3f')} {f(e['sam_deg'], '6.2f')} "
                     f"{f(e['delta_e2000'], '6.2f')} {f(e.get('delta_e2000_patches'), '6.2f')} "
                     f"{e.get('iters') or 0:>4d} {f(e['seconds'], '6.1f')} {f(o, '7.2f')}")
    t = result.get("targets", {})
    bits = []
    if t.get("psnr_rises_with_views") is not None:
        bits.append(f"PSNR rises with views: {'yes' if t['psnr_rises_with_views'] else 'NO'}")
    if "gain_5_vs_1_db" in t:
        bits.append(f"5 vs 1 view: {t['gain_5_vs_1_db']:+.2f} dB "
                    f"({'>=' if t['gain_5_vs_1_ge_3db'] else 'NOT >='} 3)")
    if "oracle_minus_calibrated_db" in t:
        worst = max(t["oracle_minus_calibrated_db"].values())
        bits.append(f"oracle - calibrated: at most {worst:+.2f} dB "
                    f"({'within' if t['within_1db_of_oracle'] else 'NOT within'} 1 dB)")
    if "delta_e2000_5views" in t:
        bits.append(f"CIEDE2000 (5 views): {t['delta_e2000_5views']:.2f} per pixel")
    if "delta_e2000_patches_5views" in t:
        bits.append(f"{t['delta_e2000_patches_5views']:.2f} per patch")
    if bits:
        lines.append("targets: " + "; ".join(bits))
    return lines


def probe_boxes(scene, design, cal, model=None):
    """A few regions (y0, x0, h, w) on the reconstruction grid for the spectral plots: six
    ColorChecker patches, or four small squares elsewhere."""
    from kaleidospec.evaluate import colorchecker_patches
    from kaleidospec.models import cube_grid
    from recon.report import grid_regions

    h, w = cube_grid(cal, model)
    if str(scene) == "colorchecker":
        patches = colorchecker_patches(design, cal, model)
        # light skin, blue sky, bluish green, red, green, blue
        out = [(f"patch {k + 1}", patches[k]) for k in (1, 2, 5, 13, 14, 15) if k in patches]
        if out:
            return out
    return grid_regions((h, w))


# ------------------------------------------------------------------------------- videos
#: The columns of a video's ``metrics.csv`` (then one per colour-wheel sector).
FRAME_COLUMNS = ("frame", "time_s", "warm", "iters", "solve_seconds", "psnr", "psnr_bandwise",
                 "ssim", "sam_deg", "delta_e2000", "sector_delta_e2000_mean")


def write_frame_table(path, frames: list[dict]) -> Path:
    """The frames' metrics as CSV (:data:`FRAME_COLUMNS`, then each sector's CIEDE2000; empty
    cells where a frame lacks a value), atomically."""
    from recon.io.atomic import write_text

    n_sec = max((len(f.get("sector_delta_e2000") or []) for f in frames), default=0)
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(list(FRAME_COLUMNS) + [f"sector_{k}_delta_e2000" for k in range(n_sec)])
    for f in frames:
        sec = list(f.get("sector_delta_e2000") or [])
        sec += [None] * (n_sec - len(sec))
        wr.writerow(["" if f.get(k) is None else f.get(k) for k in FRAME_COLUMNS]
                    + ["" if v is None else v for v in sec])
    return write_text(path, buf.getvalue())


def write_animation(path, images, fps: float, fmt: str = "gif") -> Path:
    """An animated GIF or (lossless) WebP (``fmt``) of ``images`` (each (H, W, 3) in [0, 1])
    at ``fps``, looping, through imageio/Pillow, atomically."""
    import imageio.v3 as iio

    from recon.io.atomic import atomic_path

    frames = np.stack([np.round(np.clip(im, 0, 1) * 255).astype(np.uint8) for im in images])
    kw = {"duration": 1000.0 / float(fps), "loop": 0}
    if fmt == "webp":
        kw["lossless"] = True
    path = Path(path)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, frames, extension=f".{fmt}", plugin="pillow", **kw)
    return path


# ------------------------------------------------------------------------------- design sweeps
#: The columns of a sweep's CSV after the swept field.
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


def sweep_rows(results: list[dict], settings) -> list[dict]:
    """Flat CSV rows (one per point, in sweep order) from stored/computed point results
    (:func:`kaleidospec.sweep.evaluate_point`) of a sweep with ``settings``
    (:class:`kaleidospec.sweep.SweepSettings`)."""
    used = [str(v) for v in range(int(settings.n_views))]
    rows = []
    for r in results:
        row: dict = {settings.field: r["value"], "status": r["status"],
                     "reason": r.get("reason", ""), "design_hash": r.get("design_hash") or ""}
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


def write_sweep_csv(rows: list[dict], path, field_name: str) -> Path:
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


def sweep_summary_lines(res) -> list[str]:
    """Human-readable summary of a :class:`kaleidospec.sweep.SweepResult`: agreement figures,
    timing, and the 60 px apex for apex sweeps."""
    from kaleidospec.evaluate import TARGET_SPAN_PX

    s, rows = res.settings, res.rows
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
        d = s.base_design()
        pred = (f"{res.apex_60px_pred:.2f}{s.unit}" if res.apex_60px_pred is not None
                else "not reachable before total internal reflection")
        meas = (f"{res.apex_60px_meas:.2f}{s.unit}" if res.apex_60px_meas is not None
                else "not reached in the swept range")
        lines.append(f"smallest apex for a {TARGET_SPAN_PX:g} px span over "
                     f"{d.filter_min_nm:g}–{d.filter_max_nm:g} nm ({d.prism_glass}, "
                     f"{d.imaging_focal_mm:g} mm lens, {d.sensor_pixel_um:g} µm pixels): "
                     f"predicted {pred}, measured {meas}")
    return lines


def plot_sweep(rows: list[dict], path, settings) -> Path:
    """Every quantity against the swept value (predicted dashed, measured solid), the paper's
    design marked by a vertical line and invalid points by grey bands; PNG written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kaleidospec.evaluate import TARGET_SPAN_PX
    from kaleidospec.instrument import get_design
    from recon.io.atomic import atomic_path

    f = settings.field
    unit = settings.unit
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
    paper = getattr(get_design("paper"), f)
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
        ax.set_xlabel(f"{settings.label} ({unit})")
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
