"""Fault injection, end to end: each test is a row of docs/faults.md.

Damaged cache entries of every kind (calibrations, traced maps, sampled transports, sweep points,
a video's frames) are removed with one warning line and rebuilt to what an undamaged run gives;
a process killed with SIGKILL during a calibration, a video segment or a sweep point, run again,
finishes with the results of an uninterrupted run; two processes calibrating one design at once
share one cache; an unwritable cache folder and a full output disk fail with one line, leaving
no partial output and the inputs untouched.

Everything runs on the reduced ``small`` design of the stages' tests (:data:`TINY`: a
300 × 240 sensor of 40 µm pixels, 6 bands) in caches of this module's own: its optics are traced
and it is calibrated once (:func:`base`); every test copies that cache, so a rebuilt
calibration costs seconds, not a trace.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from recon.io import cache

ROOT = Path(__file__).resolve().parents[2]
#: The reduced design (tests/kaleidospec/conftest.py's TINY), as ``--set`` overrides.
TINY = {"sensor_pixel_um": 40, "sensor_width_px": 300, "sensor_height_px": 240,
        "mask_pitch_um": 80, "band_step_nm": 50}
SETS = [a for k, v in TINY.items() for a in ("--set", f"{k}={v}")]
RUN = ["run", "--scene", "colorchecker", "--views", "1", "--iters", "5", "--no-oracle",
       "--no-progress", *SETS]
#: The sweep of tests/kaleidospec/test_sweep.py (views of 78 px, 6 bands).
REDUCED = dict(sensor_width_px="300", sensor_height_px="240", sensor_pixel_um="40",
               mask_pitch_um="80", band_step_nm="50", relay_gap_mm="190")

pytestmark = pytest.mark.mitsuba


# ------------------------------------------------------------------------------ helpers
def _use_cache(monkeypatch, folder: Path) -> Path:
    """``$KALEIDOSPEC_CACHE`` = ``folder``, and no transport kept in memory from before."""
    from sim.transport import sampled, exact as transport

    monkeypatch.setenv("KALEIDOSPEC_CACHE", str(folder))
    monkeypatch.setattr(transport, "_MEMO", {})
    monkeypatch.setattr(sampled, "_MEMO", {})
    return folder


def _copy_cache(src: Path, dst: Path, *, calibration: bool = True) -> Path:
    dst.mkdir(parents=True)
    for f in src.iterdir():
        if calibration or not f.name.startswith("calibration-"):
            shutil.copy2(f, dst / f.name)
    return dst


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 3])


def _garble(p: Path) -> None:
    b = bytearray(p.read_bytes())
    mid = len(b) // 2
    b[mid:mid + 64] = bytes(x ^ 0xA5 for x in b[mid:mid + 64])
    p.write_bytes(bytes(b))


def _empty(p: Path) -> None:
    p.write_bytes(b"")


def _foreign_npz(p: Path, **header) -> None:
    """Rewrite an entry as a sound one of another design, code version, ...: what a file copied
    in from another cache, or left by other code under this name, looks like."""
    with np.load(p, allow_pickle=False) as z:
        head = json.loads(bytes(z[cache.ENTRY]).decode())
        arrays = {n: z[n] for n in z.files if n != cache.ENTRY}
    kw = {k: head[k] for k in ("kind", "design_hash", "version", "key")}
    cache.write_npz(p, arrays, meta=head.get("meta"), **{**kw, **header})


NPZ_FAULTS = {"truncated": _truncate, "garbled": _garble, "empty": _empty,
              "another design's": lambda p: _foreign_npz(p, design_hash="0000000000000000"),
              "another code version's": lambda p: _foreign_npz(p, version="0-other")}


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if "warning" in line]


def _one_warning(err: str, name: str) -> None:
    w = _warnings(err)
    assert len(w) == 1, err
    assert name in w[0], w
    assert "Traceback" not in err


def _env(cache_dir: Path) -> dict:
    env = dict(os.environ, KALEIDOSPEC_CACHE=str(cache_dir))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


def _script(tmp_path: Path, name: str, body: str) -> Path:
    """A Python script that installs the fault named by ``$FAULT`` (a SIGKILL of itself at a
    chosen point) and then runs ``body``: the same command, with and without the fault."""
    head = textwrap.dedent("""\
        import os, signal, sys
        FAULT = os.environ.get("FAULT", "")

        def die(*a, **k):
            os.kill(os.getpid(), signal.SIGKILL)

        def kill_at(module, name, when=lambda n, *a, **k: True):
            import importlib
            m = importlib.import_module(module)
            real, calls = getattr(m, name), []

            def hooked(*a, **k):
                calls.append(1)
                if when(len(calls), *a, **k):
                    die()
                return real(*a, **k)
            setattr(m, name, hooked)
        """)
    p = tmp_path / name
    p.write_text(head + textwrap.dedent(body))
    return p


def _run(script: Path, cache_dir: Path, fault: str = "", *args, timeout=600):
    env = _env(cache_dir)
    env["FAULT"] = fault
    return subprocess.run([sys.executable, str(script), *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=timeout)


def _assert_same_calibration(a, b) -> None:
    from recon.calibration.store import ARRAY_FIELDS, OPTIONAL_ARRAY_FIELDS

    assert a.view_ids == b.view_ids and a.cube_shape == b.cube_shape
    for n in ARRAY_FIELDS + OPTIONAL_ARRAY_FIELDS:
        x, y = getattr(a, n), getattr(b, n)
        assert (x is None) == (y is None), n
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=n)


def _cli(argv, capsys):
    from kaleidospec.cli import main

    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


# ------------------------------------------------------------------------------ the base run
@pytest.fixture(scope="module")
def base(tmp_path_factory, spectral_variant):
    """``kaleidospec run`` of the reduced design on the ColorChecker in a fresh cache of this
    module's own: its traced maps (captures, scene), its calibration and its outputs."""
    from kaleidospec.cli import main
    from kaleidospec.instrument import get_design
    from recon.calibration import calibration_path, load_cached

    root = tmp_path_factory.mktemp("faults")
    folder = root / "cache"
    with pytest.MonkeyPatch.context() as mp:
        _use_cache(mp, folder)
        with pytest.raises(SystemExit) as exc:
            main(RUN + ["--out", str(root / "out")])
        assert exc.value.code in (0, None)
        d = get_design("small", TINY)
        cal = load_cached(folder, d.hash)
    assert cal is not None
    return {"cache": folder, "out": root / "out", "design": d, "cal": cal,
            "cal_file": calibration_path(folder, d.hash)}


@pytest.fixture
def cache_copy(base, tmp_path, monkeypatch):
    """A copy of the base cache (maps and calibration), in use."""
    return _use_cache(monkeypatch, _copy_cache(base["cache"], tmp_path / "cache"))


# ------------------------------------------------------------------------------ calibrations
def test_run_with_a_truncated_calibration_warns_once_and_finishes(base, cache_copy, tmp_path,
                                                                  capsys):
    """The issue's case: ``run`` (what ``demo`` does) with the cached calibration cut to a third
    prints one warning naming it, calibrates again and writes its usual outputs."""
    from recon.calibration import load_cached
    from recon.io.cubes import read_cube

    npz = cache_copy / base["cal_file"].name
    _truncate(npz)
    code, out, err = _cli(RUN + ["--out", tmp_path / "out"], capsys)
    assert code in (0, None), err
    _one_warning(err, npz.name)
    assert "calibration: rendered" in out      # the report says it was calibrated again
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == \
        sorted(p.name for p in base["out"].iterdir())
    _assert_same_calibration(load_cached(cache_copy, base["design"].hash), base["cal"])
    np.testing.assert_array_equal(read_cube(tmp_path / "out" / "cube_1views.exr")[0],
                                  read_cube(base["out"] / "cube_1views.exr")[0])
    # The rebuilt entry is sound: the next run loads it silently.
    code, out, err = _cli(RUN + ["--out", tmp_path / "out2"], capsys)
    assert code in (0, None) and _warnings(err) == [] and "calibration: cached" in out


CAL_FAULTS = {**{k: v for k, v in NPZ_FAULTS.items() if k != "truncated"},
              "sidecar missing": lambda p: p.with_suffix(".json").unlink(),
              "sidecar garbled": lambda p: p.with_suffix(".json").write_text("{\"design_")}


@pytest.mark.parametrize("fault", CAL_FAULTS)
def test_damaged_calibration_is_rebuilt(base, cache_copy, capsys, fault):
    from kaleidospec.calibrate import calibrate

    npz = cache_copy / base["cal_file"].name
    CAL_FAULTS[fault](npz)
    cal = calibrate(base["design"], progress=False)
    _one_warning(capsys.readouterr().err, npz.name)
    _assert_same_calibration(cal, base["cal"])
    assert npz.exists() and npz.with_suffix(".json").exists()
    calibrate(base["design"], progress=False)
    assert _warnings(capsys.readouterr().err) == []


# ------------------------------------------------------------------------------ traced maps
@pytest.mark.parametrize("fault", NPZ_FAULTS)
def test_damaged_maps_entry_is_removed(base, cache_copy, capsys, fault):
    """Every fault of a traced-maps entry is found on load (the rebuild itself: the next
    test)."""
    from sim.transport import exact as transport

    d = base["design"]
    for path in sorted(cache_copy.glob(f"maps-{d.hash}-*.npz")):
        key = path.stem.rsplit("-", 1)[1]
        assert transport._load(d, path, key) is not None
        NPZ_FAULTS[fault](path)
        assert transport._load(d, path, key) is None
        _one_warning(capsys.readouterr().err, path.name)
        assert not path.exists()


def test_truncated_maps_are_traced_again(base, cache_copy, capsys):
    """A cut maps entry under a recalibration: one warning, traced again, the same
    calibration."""
    from kaleidospec.calibrate import calibrate
    from sim.transport import exact as transport

    d = base["design"]
    files = sorted(cache_copy.glob(f"maps-{d.hash}-*.npz"))
    for f in files:
        _truncate(f)
    built = transport.STATS["built"]
    cal = calibrate(d, progress=False, force=True)
    err = capsys.readouterr().err
    assert transport.STATS["built"] > built
    assert len(_warnings(err)) >= 1 and all("maps-" in w for w in _warnings(err))
    _assert_same_calibration(cal, base["cal"])


# ------------------------------------------------------------------------------ sampled
@pytest.mark.parametrize("fault", NPZ_FAULTS)
def test_damaged_sampled_transport_is_removed(tmp_path, capsys, fault):
    from sim.transport import sampled

    rng = np.random.default_rng(1)
    L = 3
    pix = [np.sort(rng.choice(1000, 50, replace=False)).astype(np.int32) for _ in range(L)]
    tr = sampled.Transport("d1", (20, 30), (40, 50), np.array([450.0, 500.0, 550.0]),
                           np.array([[440.0, 460], [490, 510], [540, 560]]), 4, pix,
                           [rng.integers(0, 600, 50).astype(np.int32) for _ in range(L)],
                           [rng.random(50).astype(np.float32) for _ in range(L)])
    p = tmp_path / "sampled-d1-k.npz"
    sampled._save(tr, p, "k")
    back = sampled._load(p, "d1", "k")
    for l in range(L):
        np.testing.assert_array_equal(back.pix[l], tr.pix[l])
        np.testing.assert_array_equal(back.w[l], tr.w[l])
    NPZ_FAULTS[fault](p)
    assert sampled._load(p, "d1", "k") is None
    _one_warning(capsys.readouterr().err, p.name)


# ------------------------------------------------------------------------------ sweep points
JSON_FAULTS = {"truncated": _truncate, "garbled": _garble, "empty": _empty}


def _sweep_settings():
    from kaleidospec.sweep import SweepSettings

    return SweepSettings(kind="prism-apex", design="small", overrides=dict(REDUCED),
                         reconstruct=False, spp=4)


@pytest.mark.parametrize("fault", [*JSON_FAULTS, "another code version's", "another point's"])
def test_damaged_sweep_point_is_computed_again(tmp_path, capsys, fault):
    """Points of total internal reflection are recorded without a render: a cheap stored
    point whose every fault must be found."""
    import kaleidospec.sweep as sw

    out = tmp_path / "sweep"
    s = _sweep_settings()
    first = sw.run_sweep(s, [86.0, 87.0], out, workers=1, plot=False, log=None)
    table = first.csv_path.read_text()
    files = {sw.point_key(r): out / "points" / f"{sw.point_key(r)}.json" for r in first.results}
    k0, k1 = list(files)
    good = files[k0].read_bytes()
    if fault in JSON_FAULTS:
        JSON_FAULTS[fault](files[k0])
    elif fault == "another point's":
        shutil.copy(files[k1], files[k0])
    else:
        obj = json.loads(good)
        head = obj.pop(cache.ENTRY)
        cache.write_json(files[k0], obj, kind=head["kind"], design_hash=head["design_hash"],
                         version=sw.MEASURE_VERSION - 1, key=head["key"])
    capsys.readouterr()
    again = sw.run_sweep(s, [86.0, 87.0], out, workers=1, plot=False, log=None)
    _one_warning(capsys.readouterr().err, files[k0].name)
    assert [r["status"] for r in again.results] == ["invalid", "invalid"]
    assert again.csv_path.read_text() == table
    assert json.loads(files[k0].read_bytes())["value"] == json.loads(good)["value"]


# ------------------------------------------------------------------------------ video
H = W = 24
L = 4
WL = [450.0, 525.0, 600.0, 675.0]
N_FRAMES = 4


def _sequence(root: Path) -> dict:
    """A rendered sequence of a synthetic two-view instrument (no Mitsuba; the video tests'
    kind) and its segment settings."""
    from kaleidospec.reconstruct import calibrated_operator
    from kaleidospec.video import VideoLayout
    from recon.calibration import save_calibration
    from recon.calibration.store import Calibration
    from recon.io.cubes import write_cube
    from recon.io.raw import write_raw

    rng = np.random.default_rng(3)
    wm = W + 3
    cal = Calibration(view_ids=(0, 1), view_boxes=[[0, 0, H, wm], [H + 4, 0, H, wm]],
                      homographies=np.stack([np.eye(3)] * 2),
                      mask_images=(rng.random((2, L, H, wm)) < 0.5).astype(np.float32),
                      offsets=np.array([[0, 1, 2, 3], [3, 2, 1, 0]], np.float64),
                      gains=np.ones(L), wavelengths=WL, cube_shape=(H, W, L))
    save_calibration(root / "cal.npz", cal)
    op = calibrated_operator(cal, (0, 1))
    lay = VideoLayout(root / "video")
    lay.make()
    for i in range(N_FRAMES):
        t = np.full((H, W, L), 0.2, np.float32)
        t[5:14, 4 + i:12 + i] += np.linspace(0.6, 0.2, L, dtype=np.float32)
        g = op.forward(np.ascontiguousarray(np.moveaxis(t, 2, 0)))
        g += rng.normal(0, 0.003, g.shape).astype(np.float32)
        frame = np.zeros((2 * H + 4, wm), np.float32)
        frame[:H], frame[H + 4:] = g[0], g[1]
        write_cube(lay.truth(i), t, WL)
        write_raw(lay.raw(i), frame, {"radiance_scale": 1.0, "time_s": i / 10})
    return {"calibration": str(root / "cal.npz"), "views": 2, "solver": "gap-tv", "iters": 8,
            "cold_iters": 20, "tau": 0.02, "mu": 0.0, "animation": None, "wavelengths": WL,
            "threads": 1}


@pytest.fixture(scope="module")
def video_reference(tmp_path_factory):
    """An uninterrupted reconstruction of the synthetic sequence: its cubes."""
    from kaleidospec.video import VideoLayout, reconstruct_sequence
    from recon.io.cubes import read_cube

    root = tmp_path_factory.mktemp("video-ref")
    settings = _sequence(root)
    reconstruct_sequence(root / "video", N_FRAMES, [[0, 2], [2, N_FRAMES]], settings,
                         workers=1, progress=False)
    lay = VideoLayout(root / "video")
    return root, settings, [read_cube(lay.cube(i))[0] for i in range(N_FRAMES)]


def _check_video(folder: Path, reference) -> None:
    from kaleidospec.video import VideoLayout
    from recon.io.cubes import read_cube

    lay = VideoLayout(folder)
    for i in range(N_FRAMES):
        assert lay.verified("cube", i)
        np.testing.assert_array_equal(read_cube(lay.cube(i))[0], reference[i])
    assert not [p for p in folder.rglob(".*")]          # no temporary left


VIDEO_FAULTS = {
    "cube truncated": lambda lay: _truncate(lay.cube(2)),
    "cube garbled": lambda lay: _garble(lay.cube(2)),
    "cube empty": lambda lay: _empty(lay.cube(2)),
    "metrics garbled": lambda lay: _garble(lay.metrics(2)),
    "seal garbled": lambda lay: _garble(lay.check("cube", 2)),
    "another frame's seal": lambda lay: shutil.copy(lay.check("cube", 3), lay.check("cube", 2)),
}


@pytest.mark.parametrize("fault", VIDEO_FAULTS)
def test_damaged_video_frame_is_reconstructed_again(video_reference, tmp_path, capsys, fault):
    from kaleidospec.video import VideoLayout, reconstruct_sequence

    root, settings, ref = video_reference
    shutil.copytree(root / "video", tmp_path / "video")
    lay = VideoLayout(tmp_path / "video")
    VIDEO_FAULTS[fault](lay)
    r = reconstruct_sequence(lay.root, N_FRAMES, [[0, 2], [2, N_FRAMES]], settings, workers=1,
                             progress=False)
    assert r["done"] == 1 and r["skipped"] == N_FRAMES - 1
    _one_warning(capsys.readouterr().err, lay.check("cube", 2).name)
    _check_video(lay.root, ref)


def test_damaged_raw_frame_is_rendered_again(base, cache_copy, tmp_path, capsys):
    """The rendering stage's seals: a cut raw frame is rendered again, the same frame."""
    from kaleidospec.instrument import FrameRenderer
    from kaleidospec.video import VideoLayout, render_sequence
    from recon.io.raw import read_raw
    from scenes.animated import RotatingColorwheel

    d = base["design"]
    v = d.view_size_px
    anim = RotatingColorwheel((v, v), d.wavelengths, n_frames=2, speed_deg_s=45)
    r = FrameRenderer(d, (v, v), d.wavelengths)
    s = r.exposure_for(anim.frame(0))
    out = tmp_path / "v"
    render_sequence(anim, d, out, radiance_scale=s, renderer=r, progress=False)
    lay = VideoLayout(out)
    frame1, _ = read_raw(lay.raw(1))
    _truncate(lay.raw(1))
    capsys.readouterr()
    st = render_sequence(anim, d, out, radiance_scale=s, renderer=r, progress=False)
    assert st["rendered"] == 1 and st["skipped"] == 1
    _one_warning(capsys.readouterr().err, lay.check("raw", 1).name)
    np.testing.assert_array_equal(read_raw(lay.raw(1))[0], frame1)


# ------------------------------------------------------------------------------ SIGKILL
CALIBRATE = """
    if FAULT == "steps":          # in the middle of the calibration's steps
        kill_at("kaleidospec.calibrate", "floor_chrome")
    elif FAULT == "write":        # the image written, its sidecar not yet
        kill_at("recon.io.atomic", "write_text")
    from kaleidospec.calibrate import calibrate
    from kaleidospec.instrument import get_design
    calibrate(get_design("small", %r), progress=False)
""" % (TINY,)


@pytest.mark.parametrize("fault", ["steps", "write"])
def test_calibration_killed_then_run_again(base, tmp_path, fault):
    from recon.calibration import load_cached

    folder = _copy_cache(base["cache"], tmp_path / "cache", calibration=False)
    script = _script(tmp_path, "calibrate.py", CALIBRATE)
    killed = _run(script, folder, fault)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    # Killed in the steps: nothing; between the two files: the image without its sidecar.
    left = sorted(p.name for p in folder.glob("calibration-*"))
    assert left == ([] if fault == "steps" else [base["cal_file"].name])
    again = _run(script, folder)
    assert again.returncode == 0, again.stderr
    w = _warnings(again.stderr)
    assert len(w) == (1 if fault == "write" else 0), again.stderr
    _assert_same_calibration(load_cached(folder, base["design"].hash), base["cal"])


def test_two_processes_calibrate_one_design_at_once(base, tmp_path, capsys):
    from recon.calibration import load_cached

    folder = _copy_cache(base["cache"], tmp_path / "cache", calibration=False)
    script = _script(tmp_path, "calibrate.py", CALIBRATE)
    env = _env(folder)
    procs = [subprocess.Popen([sys.executable, str(script)], env=env, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    errs = [p.communicate(timeout=600)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    assert all(_warnings(e) == [] for e in errs), errs
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]   # no temporaries
    _assert_same_calibration(load_cached(folder, base["design"].hash), base["cal"])
    assert _warnings(capsys.readouterr().err) == []


VIDEO = """
    if FAULT == "segment":        # frame 2's cube written, its metrics not yet
        kill_at("kaleidospec.report", "write_json",
                lambda n, path, *a, **k: "frame_00002" in str(path))
    import json
    from kaleidospec.video import reconstruct_sequence
    settings = json.loads(open(sys.argv[2]).read())
    reconstruct_sequence(sys.argv[1], %d, [[0, 2], [2, %d]], settings, workers=1,
                         progress=False)
""" % (N_FRAMES, N_FRAMES)


def test_video_segment_killed_then_run_again(video_reference, tmp_path):
    from kaleidospec.video import VideoLayout

    root, settings, ref = video_reference
    folder = tmp_path / "seq"
    folder.mkdir()
    s = _sequence(folder)
    (tmp_path / "settings.json").write_text(json.dumps(s))
    script = _script(tmp_path, "video.py", VIDEO)
    killed = _run(script, tmp_path, "segment", folder / "video", tmp_path / "settings.json")
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    lay = VideoLayout(folder / "video")
    assert lay.cube(2).exists() and not lay.reconstructed(2) and lay.reconstructed(1)
    again = _run(script, tmp_path, "", folder / "video", tmp_path / "settings.json")
    assert again.returncode == 0, again.stderr
    _check_video(folder / "video", ref)


SWEEP = """
    import time
    import kaleidospec.instrument as instrument

    def measure(d, spp, seed):
        # A stand-in for the point's Monte Carlo measurement (minutes a point on 2 cores): a
        # function of the design alone, so an uninterrupted run and a resumed one must agree.
        time.sleep(0.5)
        return {"predicted": {"view_size_px": 3.0 * d.prism_apex_deg},
                "dispersion": {"span_pred_px": d.prism_apex_deg / 7.0,
                               "span_meas_px": d.prism_apex_deg / 7.1}}
    instrument.measure_design = measure
    if FAULT == "point":          # in the middle of the second point's measurement
        kill_at("kaleidospec.instrument", "measure_design", lambda n, *a, **k: n == 2)
    from kaleidospec.sweep import SweepSettings, run_sweep
    s = SweepSettings(kind="prism-apex", design="small", overrides=%r, reconstruct=False,
                      spp=4)
    run_sweep(s, [30.0, 37.5, 45.0], sys.argv[1], workers=1, plot=False, log=None)
""" % (REDUCED,)


def test_sweep_killed_during_a_point_then_run_again(tmp_path):
    import csv

    script = _script(tmp_path, "sweep.py", SWEEP)
    folder = tmp_path / "cache"
    ref = _run(script, folder, "", tmp_path / "ref")
    assert ref.returncode == 0, ref.stderr
    killed = _run(script, folder, "point", tmp_path / "sweep")
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert len(list((tmp_path / "sweep" / "points").glob("*.json"))) == 1
    assert not (tmp_path / "sweep" / "prism-apex.csv").exists()
    again = _run(script, folder, "", tmp_path / "sweep")
    assert again.returncode == 0, again.stderr
    assert _warnings(again.stderr) == []

    def rows(d):
        with open(d / "prism-apex.csv") as fh:
            return [{k: v for k, v in r.items() if "seconds" not in k}
                    for r in csv.DictReader(fh)]
    got, want = rows(tmp_path / "sweep"), rows(tmp_path / "ref")
    assert len(want) == 3 and all(r["status"] == "ok" for r in want)
    assert got == want


# ------------------------------------------------------------------------------ folders
def test_unwritable_cache_folder_stops_with_one_line(base, tmp_path, monkeypatch, capsys):
    """Tests run as root, where permission bits stop nothing: the cache folder's write probe
    is made to fail with EACCES, as a read-only folder's would."""
    folder = _use_cache(monkeypatch, tmp_path / "ro-cache")
    real = cache._probe

    def refuse(f):
        if Path(f) == folder:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))
        return real(f)

    monkeypatch.setattr(cache, "_probe", refuse)
    code, out, err = _cli(RUN + ["--out", tmp_path / "out"], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(folder) in lines[0] and "cannot be written" in lines[0]
    assert not (tmp_path / "out").exists()


def test_full_output_disk_leaves_no_partial_output(base, cache_copy, tmp_path, monkeypatch,
                                                   capsys):
    """The output folder's file system fills up while the outputs are written (a PNG's write
    raises ENOSPC): one line, no output folder, no temporaries, the input cube and the cache
    untouched."""
    from recon.io.cubes import write_cube
    import recon.report

    cube = tmp_path / "in" / "scene.exr"
    cube.parent.mkdir()
    v = base["design"].view_size_px
    rng = np.random.default_rng(0)
    write_cube(cube, rng.uniform(0.1, 0.9, (v, v, len(base["design"].wavelengths)))
               .astype(np.float32), base["design"].wavelengths)
    before = {p: cache.file_digest(p) for p in [cube, *cache_copy.iterdir()]}

    calls = []

    def full(path, *a, **k):
        calls.append(path)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(recon.report, "write_png", full)
    argv = [a if a != "colorchecker" else str(cube) for a in RUN]
    code, out, err = _cli(argv + ["--out", tmp_path / "out" / "run"], capsys)
    assert code == 2, err
    assert len(calls) == 1      # the outputs were being written when the disk filled up
    lines = err.strip().splitlines()
    assert len(lines) == 1 and os.strerror(errno.ENOSPC) in lines[0]
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "in"]
    assert {p: cache.file_digest(p) for p in before} == before
