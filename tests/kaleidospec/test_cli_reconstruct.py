"""``kaleidospec reconstruct`` end to end on a tiny 24×24×6 problem, and every bad input."""

import re
import subprocess
import sys

import numpy as np
import pytest
import scipy.io

from kaleidospec.cli import main
from recon.io.arrays import write_array2d
from recon.io.cubes import read_cube, write_cube
from recon.metrics import psnr

H = W = 24
L = 6
STEP = 2
WL = np.linspace(450.0, 650.0, L)


def _truth():
    y, x = np.mgrid[0:H, 0:W] / (H - 1)
    cube = np.empty((H, W, L), np.float32)
    for l in range(L):
        cube[:, :, l] = 0.2 + 0.1 * l / L
        cube[:, :, l] += 0.6 * ((x - 0.4) ** 2 + (y - 0.5) ** 2 < 0.08) * (l + 1) / L
        cube[:, :, l] += 0.4 * ((x > 0.65) & (y < 0.35)) * (L - l) / L
    return cube


@pytest.fixture
def problem(tmp_path):
    from recon.operators import standard_cassi

    rng = np.random.default_rng(0)
    mask = (rng.random((H, W)) < 0.5).astype(np.float32)
    truth = _truth()
    g = standard_cassi(mask, STEP, L).forward(np.ascontiguousarray(np.moveaxis(truth, 2, 0)))[0]
    paths = {
        "meas": write_array2d(tmp_path / "meas.npy", g),
        "mask": write_array2d(tmp_path / "mask.mat", mask, key="mask"),
        "truth": write_cube(tmp_path / "truth.npz", truth, WL),
    }
    return tmp_path, paths, truth


def run(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def base_args(paths, out):
    return ["reconstruct", "--measurement", str(paths["meas"]), "--mask", str(paths["mask"]),
            "--step", str(STEP), "--out", str(out), "--iters", "15"]


def test_success_writes_cube_and_prints_metrics(problem, capsys):
    tmp, paths, truth = problem
    out = tmp / "rec.npz"
    code, stdout, err = run(base_args(paths, out) + ["--truth", str(paths["truth"])], capsys)
    assert code in (0, None), err
    cube, wl = read_cube(out)
    assert cube.shape == (H, W, L)
    np.testing.assert_allclose(wl, WL)  # inferred from the truth file
    m = re.search(r"PSNR ([\d.]+) dB", stdout)
    assert m, stdout
    assert float(m.group(1)) == pytest.approx(psnr(cube, truth), abs=0.006)
    assert psnr(cube, truth) > psnr(np.zeros_like(truth) + truth.mean(), truth)
    assert "SSIM" in stdout and "SAM" in stdout and re.search(r"in [\d.]+ s", stdout)
    assert err == ""


def _other_solvers():
    from recon.app import solver_names

    return [s for s in solver_names() if s != "gap-tv"]


@pytest.mark.parametrize("solver", _other_solvers())
def test_other_solvers_and_exr_output(problem, capsys, solver):
    tmp, paths, _ = problem
    out = tmp / "rec.exr"
    code, stdout, err = run(base_args(paths, out) + ["--solver", solver, "--bands", str(L),
                                                     "--wavelengths", "450:650:6"], capsys)
    assert code in (0, None), err
    cube, wl = read_cube(out)
    assert cube.shape == (H, W, L) and np.all(np.isfinite(cube))
    np.testing.assert_allclose(wl, WL)
    assert "PSNR" not in stdout


def _bad_cases(tmp, paths):
    g = np.load(paths["meas"])
    nan = g.copy()
    nan[2, 3] = np.nan
    write_array2d(tmp / "nan.npy", nan)
    write_array2d(tmp / "short.npy", g[:-1])
    write_array2d(tmp / "narrow.npy", g[:, :-1])  # W + 9: step 2 does not divide 9
    (tmp / "empty.npy").write_bytes(b"")
    (tmp / "garbage.exr").write_bytes(b"not an exr file at all")
    scipy.io.savemat(tmp / "two.mat", {"a": g, "b": g})
    write_cube(tmp / "small_truth.npz", _truth()[:, :, :4], WL[:4])
    return {
        "mismatched heights": ["--measurement", str(tmp / "short.npy")],
        "NaN in measurement": ["--measurement", str(tmp / "nan.npy")],
        "empty file": ["--measurement", str(tmp / "empty.npy")],
        "unreadable file": ["--mask", str(tmp / "garbage.exr")],
        "missing file": ["--mask", str(tmp / "nothere.npy")],
        "missing mat key": ["--mask-key", "Phi"],
        "ambiguous mat": ["--measurement", str(tmp / "two.mat")],
        "step does not fit": ["--measurement", str(tmp / "narrow.npy")],
        "bad step": ["--step", "0"],
        "bands disagree": ["--bands", "5"],
        "truth shape": ["--truth", str(tmp / "small_truth.npz")],
        "bad solver": ["--solver", "magic"],
        "bad wavelengths": ["--wavelengths", "450:650:7"],
        "exr without wavelengths": ["--out", str(tmp / "rec.exr")],
        "bad out suffix": ["--out", str(tmp / "rec.txt")],
        "out folder missing": ["--out", str(tmp / "nope" / "rec.npz")],
    }


def test_bad_inputs_exit_2_with_one_line(problem, capsys):
    tmp, paths, _ = problem
    out = tmp / "rec.npz"
    before = sorted(p.name for p in tmp.iterdir())
    for name, extra in _bad_cases(tmp, paths).items():
        listing = sorted(p.name for p in tmp.iterdir())
        code, stdout, err = run(base_args(paths, out) + extra, capsys)
        assert code == 2, (name, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("kaleidospec: error:"), (name, err)
        assert "Traceback" not in err
        assert sorted(p.name for p in tmp.iterdir()) == listing, name  # nothing written
    assert not out.exists()
    assert set(before) <= {p.name for p in tmp.iterdir()}


@pytest.mark.parametrize("which", ["meas", "mask", "truth"])
def test_output_equal_to_an_input_is_refused(problem, capsys, which):
    tmp, paths, _ = problem
    target = paths[which]
    before = target.read_bytes()
    args = base_args(paths, tmp / "." / target.name) + ["--truth", str(paths["truth"])]
    code, _, err = run(args, capsys)
    assert code == 2 and "input" in err and len(err.strip().splitlines()) == 1
    assert target.read_bytes() == before


def test_subprocess_bad_input_no_traceback(problem):
    tmp, paths, _ = problem
    (tmp / "empty.npy").write_bytes(b"")
    args = base_args(paths, tmp / "rec.npz")
    args[2] = str(tmp / "empty.npy")
    r = subprocess.run([sys.executable, "-m", "kaleidospec.cli", *args], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "empty" in r.stderr
    assert not (tmp / "rec.npz").exists()


def test_help_imports_nothing_heavy():
    code = ("import sys, kaleidospec.cli; "
            "print(sorted(m for m in ('numpy', 'scipy', 'recon', 'OpenEXR', 'colour', 'skimage') "
            "if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.stdout.strip() == "[]"


def test_demo_is_the_run_of_the_default_scene(capsys):
    # The demo renders and calibrates (about a minute): here only its wiring is checked;
    # tests/kaleidospec/test_cli_run.py runs the same pipeline on a reduced design.
    from kaleidospec.commands import demo

    # A scene no calibration capture shows (the ColorChecker fits the gains).
    assert demo.DEFAULT_SCENE == "natural" and demo.DEFAULT_MODEL == "footprint"
    code, stdout, err = run(["demo", "--help"], capsys)
    assert code in (0, None) and "--out" in stdout and "--model" in stdout
    code, _, err = run(["demo", "--model", "exact"], capsys)
    assert code == 2 and "--model" in err
