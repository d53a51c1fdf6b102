"""``kaleidospec run`` end to end on a reduced small design, and every bad input."""

import json

import numpy as np
import pytest

from kaleidospec.cli import main

SET = ["--set", "band_step_nm=50"]


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


def cli(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out, err = capsys.readouterr()
    return exc.value.code, out, err


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    import contextlib
    import io

    out = tmp_path_factory.mktemp("run") / "res"
    err = io.StringIO()
    with pytest.raises(SystemExit) as exc, contextlib.redirect_stderr(err):
        main(["run", "--scene", "colorchecker", "--out", str(out), "--views", "1,2", "--iters",
              "10", "--no-progress", *SET])
    assert exc.value.code in (0, None)
    # --no-progress: not a line of progress (a log would get one per finished step).
    assert err.getvalue() == ""
    return out


def test_run_writes_everything(done):
    names = {p.name for p in done.iterdir()}
    want = {"raw.exr", "raw.json", "truth.exr", "srgb_truth.png", "cube_1views.exr",
            "cube_2views.exr", "srgb_1views.png", "srgb_2views.png", "bands.png", "spectra.png",
            "metrics.json"}
    assert want == names
    m = json.loads((done / "metrics.json").read_text())
    assert set(m["views"]) == {"1", "2"} and set(m["oracle"]) == {"1", "2"}
    assert m["prior"] == "subspace-tv"  # the default prior of run, recorded
    for e in m["views"].values():
        for k in ("psnr", "psnr_bandwise", "ssim", "sam_deg", "delta_e2000", "seconds"):
            assert isinstance(e[k], float), k
    from recon.io.cubes import read_cube

    cube, wl = read_cube(done / "cube_2views.exr")
    assert list(cube.shape) == m["cube_shape"] and np.all(np.isfinite(cube))
    assert not [p for p in done.parent.iterdir() if p.name.startswith(".")]  # no temporaries


def test_bad_cube_leaves_the_folder_alone(done, tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    cube = np.ones((8, 8, 3), np.float32)
    cube[2, 2, 1] = np.nan
    np.savez(bad, cube=cube, wavelengths=np.array([450.0, 575.0, 700.0]))
    before = {p.name: p.stat().st_mtime_ns for p in done.iterdir()}
    code, out, err = cli(["run", "--scene", str(bad), "--out", str(done), "--views", "1",
                          "--no-progress", *SET], capsys)
    assert code == 2
    assert err.startswith("kaleidospec: error:") and len(err.strip().splitlines()) == 1
    assert "non-finite" in err or "NaN" in err
    assert {p.name: p.stat().st_mtime_ns for p in done.iterdir()} == before


def test_raw_with_another_design_is_refused(done, tmp_path, capsys):
    raw = done / "raw.exr"          # taken with band_step_nm=50
    out = tmp_path / "o"
    code, _, err = cli(["run", "--scene", "colorchecker", "--raw", str(raw), "--out", str(out),
                        "--views", "1", "--no-progress", "--set", "band_step_nm=25"], capsys)
    assert code == 2 and "design" in err and not out.exists()


def test_raw_missing_view_is_refused(done, tmp_path, capsys):
    out = tmp_path / "o"
    code, _, err = cli(["run", "--scene", "colorchecker", "--raw", str(done / "raw.exr"),
                        "--out", str(out), "--views", "9", "--no-progress", *SET], capsys)
    assert code == 2 and "missing" in err and not out.exists()


def test_bad_options(tmp_path, capsys):
    for args in (["--views", "0"], ["--views", "1,a"], ["--iters", "0"], ["--solver", "nope"],
                 ["--tol", "-1"], ["--tol", "nan"],
                 ["--model", "exact"],
                 # GAP-TV diverges on the exact operator: refused unless the oracle is off.
                 ["--solver", "gap-tv"]):
        code, _, err = cli(["run", "--scene", "colorchecker", "--out", str(tmp_path / "x"),
                            "--no-progress", *SET, *args], capsys)
        assert code == 2, args
    assert not (tmp_path / "x").exists()


def test_cli_defaults_are_the_reconstruction_defaults():
    # The CLI states its defaults as literals (its help imports no NumPy); they must be these.
    import inspect

    from kaleidospec.commands.run import run
    from kaleidospec.reconstruct import DEFAULTS

    params = inspect.signature(run).parameters
    assert params["iters"].default.default == DEFAULTS["iters"]
    assert params["tol"].default.default == DEFAULTS["tol"]
    assert params["solver"].default.default == DEFAULTS["solver"]


def test_summary_states_the_stopping_rule_and_the_iterations_done(done):
    from kaleidospec.report import summary_lines

    m = json.loads((done / "metrics.json").read_text())
    assert m["tol"] == 1e-3 and m["iters"] == 10
    lines = summary_lines(m)
    assert "until a relative change < 0.001 (at most 10 iterations)" in lines[0]
    head = lines[2].split()
    for n, e in m["views"].items():
        row = next(r.split() for r in lines[4:] if r.split()[:1] == [n])
        assert row[head.index("it")] == str(e["iters"]) and e["iters"] <= 10
