"""kaleidospec.sweep: design points, invalid points, resumable store, CSV, CLI."""

from __future__ import annotations

import csv
import json
import math

import pytest

from recon.errors import InputError

#: The reduced ``small`` design of tests/sim/test_measure.py (views of 78 px, 6 bands).
REDUCED = dict(sensor_width_px="300", sensor_height_px="240", sensor_pixel_um="40",
               mask_pitch_um="80", band_step_nm="50", relay_gap_mm="190")


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    from sim.transport import exact as transport

    monkeypatch.setenv("KALEIDOSPEC_CACHE", str(tmp_path / "cache"))
    transport.release()
    yield tmp_path / "cache"
    transport.release()


def _settings(kind="prism-apex", **kw):
    from kaleidospec.sweep import SweepSettings

    kw.setdefault("reconstruct", False)
    kw.setdefault("spp", 4)
    return SweepSettings(kind=kind, design="small", overrides=dict(REDUCED), **kw)


# ---------------------------------------------------------------------- values and points
def test_sweep_values_include_the_stop_and_reject_bad_ranges():
    from kaleidospec.sweep import sweep_values

    assert sweep_values(10, 40, 10).tolist() == [10, 20, 30, 40]
    assert sweep_values(17, 17, 1).tolist() == [17]
    assert sweep_values(0.1, 0.3, 0.1).size == 3
    for bad in [(10, 40, 0), (10, 40, -1), (40, 10, 5), (0, 1e6, 1), (0, math.inf, 1)]:
        with pytest.raises(InputError):
            sweep_values(*bad)


def test_settings_reject_bad_input():
    from kaleidospec.sweep import SweepSettings

    with pytest.raises(InputError):
        SweepSettings(kind="focal-length")
    with pytest.raises(InputError):
        SweepSettings(kind="prism-apex", n_views=10)
    with pytest.raises(InputError):
        SweepSettings(kind="prism-apex", overrides={"prism_apex_deg": "20"})


def test_invalid_points_are_reported_not_raised():
    from kaleidospec.sweep import evaluate_point, make_points, point_key

    # Total internal reflection in BK-7 past ~80°.
    pts = make_points(_settings(), [30.0, 86.0])
    assert pts[0]["status"] == "pending" and pts[0]["design"] is not None
    assert pts[1]["status"] == "invalid" and "internal reflection" in pts[1]["reason"]
    # A mirror shorter than the relay's focal length with no gap: no real image.
    s = _settings("mirror-length")
    s.overrides["relay_gap_mm"] = "0"
    ml = make_points(s, [40.0, 240.0])
    assert ml[0]["status"] == "invalid" and "relay" in ml[0]["reason"]
    assert ml[1]["status"] == "pending"
    r = evaluate_point(ml[0])
    assert r["status"] == "invalid" and "measure" not in r
    keys = {point_key(p) for p in pts + ml}
    assert len(keys) == 4
    # The design hash covers the swept value and the widened views.
    d = pts[0]["design"]
    assert d["prism_apex_deg"] == 30.0 and set(range(5)) <= set(d["views"])


def test_views_are_widened_for_the_view_count():
    from kaleidospec.sweep import make_points

    p9 = make_points(_settings(n_views=9), [30.0])[0]
    p5 = make_points(_settings(n_views=5), [30.0])[0]
    assert p9["design"]["views"] == list(range(9))
    assert p9["design_hash"] != p5["design_hash"]


def test_local_process_pool_returns_every_point():
    from kaleidospec.parallel import map_unordered
    from kaleidospec.sweep import evaluate_point, make_points

    pts = make_points(_settings(), [85.0, 86.0, 87.0])  # all invalid: no rendering needed
    got = sorted(r["value"] for r in map_unordered(evaluate_point, [(p,) for p in pts],
                                                    workers=2))
    assert got == [85.0, 86.0, 87.0]


# ---------------------------------------------------------------------- a real sweep
@pytest.mark.mitsuba
def test_sweep_measures_resumes_and_extends(cache, tmp_path, monkeypatch):
    pytest.importorskip("mitsuba")
    import kaleidospec.sweep as sw

    calls = []
    real = sw.evaluate_point

    def counting(p):
        calls.append(p["value"])
        return real(p)

    monkeypatch.setattr(sw, "evaluate_point", counting)
    out = tmp_path / "sweep"
    s = _settings()
    res = sw.run_sweep(s, [30.0, 45.0, 86.0], out, workers=1, log=None)
    assert sorted(calls) == [30.0, 45.0]  # the invalid point is never rendered
    assert [r["status"] for r in res.results] == ["ok", "ok", "invalid"]
    rows = list(csv.DictReader(open(res.csv_path)))
    assert [float(r["prism_apex_deg"]) for r in rows] == [30.0, 45.0, 86.0]
    assert rows[2]["status"] == "invalid" and rows[2]["dispersion_span_meas_px"] == ""
    for r in rows[:2]:
        # The targets: dispersion within 0.5 px, view size within 1 %.
        assert abs(float(r["dispersion_span_meas_px"]) - float(r["dispersion_span_pred_px"])) < 0.5
        assert abs(float(r["view_size_err_pct"])) < 1.0
    spans = [float(r["dispersion_span_meas_px"]) for r in rows[:2]]
    assert spans[1] > spans[0]  # a larger apex disperses more
    assert res.plot_path.exists() and res.plot_path.stat().st_size > 10_000
    stored = sorted((out / "points").glob("*.json"))
    assert len(stored) == 3
    for f in stored:
        json.loads(f.read_text())  # valid JSON (no NaN tokens)
    mtimes = {f: f.stat().st_mtime_ns for f in stored}

    # Resume: nothing recomputed, nothing rewritten.
    calls.clear()
    res2 = sw.run_sweep(s, [30.0, 45.0, 86.0], out, workers=1, log=None)
    assert calls == [] and res2.computed == 0 and res2.reused == 3
    assert {f: f.stat().st_mtime_ns for f in stored} == mtimes
    assert list(csv.DictReader(open(res2.csv_path))) == rows

    # Extend: only the new point is computed.
    res3 = sw.run_sweep(s, [30.0, 37.5, 45.0, 86.0], out, workers=1, log=None, plot=False)
    assert calls == [37.5] and res3.computed == 1
    assert len(list((out / "points").glob("*.json"))) == 4

    # Different settings (another view count) are different points.
    calls.clear()
    sw.run_sweep(_settings(n_views=3), [30.0], out, workers=1, log=None, plot=False)
    assert calls == [30.0]


@pytest.mark.mitsuba
def test_views_that_do_not_fit_are_measured_but_not_reconstructed(cache, tmp_path):
    pytest.importorskip("mitsuba")
    from kaleidospec.sweep import make_points, evaluate_point

    s = _settings("mirror-length", reconstruct=True)
    p = make_points(s, [150.0])[0]
    r = evaluate_point(p)
    assert r["status"] == "views-do-not-fit" and "recon" not in r
    # The grid is larger than the sensor: the outer copies are cut by its border.
    assert r["measure"]["predicted"]["views_fit"] is False
    assert set(r["measure"]["white"]["clipped_views"]) >= {5, 6, 7, 8}


# ---------------------------------------------------------------------- command line
def test_cli_prism_apex_reports_tir_points(tmp_path, cache):
    from typer.testing import CliRunner

    from kaleidospec.cli import app

    out = tmp_path / "cli"
    args = ["sweep", "prism-apex", "--start", "85", "--stop", "87", "--step", "1",
            "--out", str(out), "--no-recon"] + sum((["--set", f"{k}={v}"] for k, v in
                                                    REDUCED.items()), [])
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "3 points" in r.output and "smallest apex" in r.output
    rows = list(csv.DictReader(open(out / "prism-apex.csv")))
    assert [row["status"] for row in rows] == ["invalid"] * 3


def test_cli_bad_input_exits_2(tmp_path, capsys):
    from kaleidospec.cli import main

    for args in (["--step", "0"], ["--set", "no_such_field=1"], ["--views", "12"]):
        with pytest.raises(SystemExit) as e:
            main(["sweep", "mirror-length", "--out", str(tmp_path / "x"), "--no-recon", *args])
        assert e.value.code == 2
        assert "error" in capsys.readouterr().err


def test_sweep_runs_on_a_dask_cluster(cache, tmp_path):
    """`--scheduler` sends the points to a Dask scheduler: here a local cluster on loopback."""
    pytest.importorskip("mitsuba")
    distributed = pytest.importorskip("distributed")
    import kaleidospec.sweep as sw
    from kaleidospec.report import sweep_rows

    local = sw.run_sweep(_settings(), [30.0], tmp_path / "local", workers=1, log=None,
                         plot=False)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        res = sw.run_sweep(_settings(), [30.0, 86.0], tmp_path / "dask", log=None, plot=False,
                           scheduler=cluster.scheduler_address)
    assert [r["status"] for r in res.results] == ["ok", "invalid"]
    # The same point computed on the cluster and locally measures the same.
    a, b = (sweep_rows(r.results, _settings())[0] for r in (local, res))
    for key in ("dispersion_span_meas_px", "view_size_meas_px"):
        assert float(b[key]) == pytest.approx(float(a[key]), rel=1e-6), key
