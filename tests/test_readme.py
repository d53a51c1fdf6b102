"""The README's commands, run as written.

The commands come from README.md itself (its ```python and ```bash blocks), so an edit of the
README changes what runs here and a renamed option fails here:

- the Python example runs and reconstructs its scene;
- the quick start is two commands, set-up then the main job and set-up then the tests, and its
  test command is the one CI runs;
- its main job, ``kaleidospec demo --out out/demo``, runs from an empty folder (a fresh clone has
  no ``out/``) and writes every file "What the demo wrote" describes; with its output sent to a
  file (``> log 2>&1``) it writes at most 40 lines, one per finished step and no redraws;
- the ``render``, ``video``, ``design show`` and ``reconstruct`` (real-capture layout) examples
  run to the end; every other ``kaleidospec`` line of the README parses (options and values) and
  is not run (a whole ``run`` of another design is what ``demo`` already checks).

The command-line runs share the transports and calibrations of the other tests through
``$KALEIDOSPEC_CACHE`` (the ``shared_cache`` fixture): the demo traces the ``small`` design once,
the render and the video reuse it.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


# ------------------------------------------------------------------------ reading the README
def _section(title: str) -> str:
    """The README's text from the line starting with ``title`` to the next heading or the next
    bold paragraph title (``**…**``), whichever comes first."""
    text = README.read_text()
    start = text.index(title)
    rest = text[start + len(title):]
    end = re.search(r"^(#+ |\*\*)", rest, flags=re.M)
    return title + (rest[:end.start()] if end else rest)


def _bash_lines(text: str) -> list[str]:
    """The command lines of the ```bash blocks in ``text``, comments stripped."""
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line and not line.startswith("#"):
                lines.append(line)
    return lines


def readme_commands() -> list[list[str]]:
    """Every ``kaleidospec …`` command of the README, as its arguments (program name left out);
    ``a && kaleidospec …`` counts too."""
    out = []
    for line in _bash_lines(README.read_text()):
        for part in line.split("&&"):
            words = shlex.split(part)
            if words and words[0] == "kaleidospec":
                out.append(words[1:])
    return out


def readme_command(*start: str) -> list[str]:
    """The one README command whose arguments begin with ``start``."""
    hits = [c for c in readme_commands() if c[:len(start)] == list(start)]
    assert len(hits) == 1, f"the README should have one `kaleidospec {' '.join(start)}` line: {hits}"
    return hits[0]


def option(args: list[str], name: str, default=None):
    """The value after ``name`` in ``args`` (the last one if repeated)."""
    values = [args[i + 1] for i, a in enumerate(args[:-1]) if a == name]
    return values[-1] if values else default


def options(args: list[str], name: str) -> list[str]:
    return [args[i + 1] for i, a in enumerate(args[:-1]) if a == name]


def quick_start() -> list[tuple[str, str]]:
    """The quick start's commands, each split at its ``&&`` into (set-up, then)."""
    lines = _bash_lines(_section("## Quick start"))
    out = []
    for line in lines:
        first, _, then = line.partition("&&")
        out.append((first.strip(), then.strip()))
    return out


# ------------------------------------------------------------------------ running a command
def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.fixture(scope="module")
def cli_env(shared_cache):
    """The environment of a user's shell: this checkout importable (as the editable install
    makes it), the tests' shared cache."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return dict(os.environ, KALEIDOSPEC_CACHE=str(shared_cache), PYTHONPATH=path)


def kaleidospec(args, cwd, env):
    """``kaleidospec ARGS`` in ``cwd``, the console script's own entry point."""
    r = subprocess.run([sys.executable, "-m", "kaleidospec.cli", *args], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"kaleidospec {shlex.join(args)}\n{r.stdout}\n{r.stderr}"
    assert "Traceback" not in r.stderr and "error" not in r.stderr.lower(), r.stderr
    return r


# ------------------------------------------------------------------------ the Python example
def test_readme_python_example_runs(capsys):
    page = ROOT / "docs" / "reconstruction.md"
    assert "docs/reconstruction.md#from-python" in README.read_text()
    blocks = re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S)
    assert blocks, "docs/reconstruction.md has no Python example"
    namespace: dict = {}
    exec(compile(blocks[0], str(page), "exec"), namespace)  # noqa: S102 - our own docs
    assert namespace["cube"].shape == namespace["truth"].shape
    assert namespace["info"]["metrics"]["psnr"] > 25.0
    assert "dB" in capsys.readouterr().out


# ------------------------------------------------------------------------ the quick start
def test_quick_start_is_set_up_then_the_main_job_then_the_tests():
    steps = quick_start()
    assert len(steps) == 2, steps
    assert steps[0][0] == steps[1][0] == "bash tools/setup.sh"
    assert (ROOT / "tools" / "setup.sh").is_file()
    assert shlex.split(steps[0][1])[:2] == ["kaleidospec", "demo"]
    # The README's test command is the one CI runs.
    ci = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines()
          if ln.strip() and not ln.lstrip().startswith("#")]
    assert steps[1][1] == ci[-1]


@pytest.fixture(scope="module")
def demo(tmp_path_factory, cli_env):
    """The quick start's main command, as written, in an empty folder (a fresh clone has no
    ``out/``: it is git-ignored), its output and errors sent to one file as ``> log 2>&1``
    does (a file is no terminal); returns the folders and the log's text."""
    args = shlex.split(quick_start()[0][1])[1:]
    cwd = tmp_path_factory.mktemp("fresh-clone")
    log = tmp_path_factory.mktemp("log") / "demo.log"
    with open(log, "w") as f:
        r = subprocess.run([sys.executable, "-m", "kaleidospec.cli", *args], cwd=cwd,
                           env=cli_env, stdout=f, stderr=subprocess.STDOUT, timeout=600)
    text = log.read_text()
    assert r.returncode == 0, f"kaleidospec {shlex.join(args)}\n{text}"
    assert "Traceback" not in text and "error" not in text.lower(), text
    return cwd, cwd / option(args, "--out"), text


def _promised_files(views) -> set[str]:
    """The files the README's "What the demo wrote" names, ``<n>`` expanded per view count."""
    text = _section("**What the demo wrote.**")
    names = set(re.findall(r"`([\w<>]+\.(?:png|json|exr))`", text))
    out = set()
    for name in names:
        out |= {name.replace("<n>", str(n)) for n in views} if "<n>" in name else {name}
    # "srgb_1views.png … srgb_5views.png": every view count between the two named.
    ranged = re.search(r"`srgb_(\d+)views\.png` … `srgb_(\d+)views\.png`", text)
    assert ranged, "the README lists the sRGB pictures as `srgb_1views.png` … `srgb_Nviews.png`"
    out |= {f"srgb_{n}views.png" for n in views}
    return out


def test_demo_writes_what_the_readme_describes(demo):
    import imageio.v3 as iio

    from kaleidospec.commands.demo import DEFAULT_VIEWS
    from kaleidospec.run import parse_views

    cwd, out, log = demo
    m = json.loads((out / "metrics.json").read_text())
    views = parse_views(DEFAULT_VIEWS)
    assert sorted(int(n) for n in m["views"]) == sorted(views)
    assert {p.name for p in out.iterdir()} == _promised_files(views)
    assert log.strip().splitlines()[-1] == f"wrote {os.path.relpath(out, cwd)}/"
    # Readable pictures: the sRGB renderings on the cube's grid, the plots not blank.
    h, w = m["cube_shape"][:2]
    for n in ["truth", *views]:
        img = iio.imread(out / f"srgb_{n}views.png" if n != "truth" else out / "srgb_truth.png")
        assert img.shape == (h, w, 3) and img.dtype == np.uint8 and img.std() > 10
    for name in ("bands.png", "spectra.png"):
        img = iio.imread(out / name)
        assert img.shape[0] > 200 and img[..., :3].std() > 10, name


def test_demo_log_is_one_line_per_finished_step(demo):
    """``kaleidospec demo > log 2>&1``: a handful of lines, no progress-bar redraws."""
    from kaleidospec.commands.demo import DEFAULT_VIEWS
    from kaleidospec.reconstruct import DEFAULTS
    from kaleidospec.run import parse_views

    _, _, log = demo
    # splitlines() also splits at "\r": every redraw of a bar would count as a line.
    lines = log.splitlines()
    assert len(lines) <= 40, log
    assert "\r" not in log and "\x1b[" not in log, "a bar redrew itself in the log"
    # Each solve is a finished step: one line, with its iterations and its time.
    solves = [ln for ln in lines if ln.startswith("fista-tv: ")]
    assert len(solves) == len(parse_views(DEFAULT_VIEWS)), log
    cap = DEFAULTS["iters"]
    assert all(re.fullmatch(rf"fista-tv: \d+/{cap} it in \d+\.\d s \(psnr [\d.]+\)", ln)
               for ln in solves), solves
    # The README says how many lines the log holds.
    said = re.search(r"one\s+line per finished step \((\d+) lines in all\)", README.read_text())
    assert said, "the README says how many lines the demo's log holds"
    assert len(lines) <= int(said.group(1))


def test_demo_reaches_the_targets_the_readme_names(demo):
    from recon.io.cubes import read_cube
    from recon.metrics import psnr
    from sim.optics.design import Design

    _, out, _ = demo
    m = json.loads((out / "metrics.json").read_text())
    t = m["targets"]
    assert t["psnr_rises_with_views"] and t["gain_5_vs_1_ge_3db"]
    # The README's figure for 5 views with the default prior, subspace-tv (measured 29.20 dB;
    # TV reads 23.60): natural has spectral rank 3, which flatters that prior; a leak of the
    # truth would show as far more still.
    said = re.search(r"`psnr` \(dB[^)]*; ([\d.]+)\s+with 5 views\)", README.read_text())
    assert said, "the README gives the demo's PSNR with 5 views"
    assert m["views"]["5"]["psnr"] == pytest.approx(float(said.group(1)), abs=0.3)
    assert m["prior"] == "subspace-tv"
    assert abs(m["views"]["5"]["psnr"] - 29.20) < 1.5
    # A scene no calibration capture shows, and a frame from its own trace at twice the grid.
    raw = json.loads((out / "raw.json").read_text())
    assert m["scene"] == "natural" and raw["trace_seed"] == 1
    assert raw["scene_shape"] == [2 * Design.from_dict(m["design"]).view_size_px] * 2
    # The footprint model reconstructs on the view's grid: the truth is the scene's area mean.
    truth, wl = read_cube(out / "truth.exr")
    assert m["model"] == "footprint"
    assert tuple(m["cube_shape"]) == truth.shape
    assert m["cube_shape"][:2] == [Design.from_dict(m["design"]).view_size_px] * 2
    np.testing.assert_allclose(wl, m["wavelengths_nm"])
    # The metrics are those of the files written.
    for n, entry in m["views"].items():
        cube, _ = read_cube(out / f"cube_{n}views.exr")
        assert psnr(cube, truth) == pytest.approx(entry["psnr"], abs=0.01), n


def test_demo_output_is_readable_by_others_and_leaves_nothing_else(demo):
    cwd, out, _ = demo
    # The folders it made and the files in them get the umask's permissions (a temporary
    # folder is private, 0700, until made otherwise).
    for d in (out.parent, out):
        assert d.stat().st_mode & 0o777 == 0o777 & ~_umask(), d
    for f in out.iterdir():
        assert f.stat().st_mode & 0o777 == 0o666 & ~_umask(), f
    assert [p.name for p in cwd.iterdir()] == [out.relative_to(cwd).parts[0]]
    assert [p.name for p in out.parent.iterdir()] == [out.name]  # no temporaries


# ------------------------------------------------------------------------ the other examples
def test_every_readme_command_parses():
    import click
    import typer

    from kaleidospec.cli import app

    root = typer.main.get_command(app)
    commands = readme_commands()
    assert len(commands) >= 6
    for args in commands:
        cmd, rest, name = root, list(args), "kaleidospec"
        while isinstance(cmd, click.Group):
            name, *rest = rest
            cmd = cmd.get_command(click.Context(root), name)
            assert cmd is not None, f"unknown command in the README: {shlex.join(args)}"
        # Parses every option and value (click raises on unknown options, bad numbers, a
        # missing required option); nothing runs.
        cmd.make_context(name, rest)


def test_design_show_example(capsys):
    from kaleidospec.cli import main

    args = readme_command("design", "show")
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code in (0, None)
    d = json.loads(capsys.readouterr().out)
    assert d["preset"] == option(args, "--design", "paper")
    for item in options(args, "--set"):
        k, v = item.split("=", 1)
        assert d[k] == pytest.approx(float(v)), k


def test_render_example(demo, tmp_path, cli_env):
    from recon.io.raw import read_raw
    from sim.optics.design import get_design, parse_overrides

    args = readme_command("render")
    kaleidospec(args, tmp_path, cli_env)
    out = tmp_path / option(args, "--out")
    d = get_design(option(args, "--design", "small"), parse_overrides(options(args, "--set")))
    frame, meta = read_raw(out)
    assert meta["design_hash"] == d.hash and meta["scene"] == option(args, "--scene")
    assert frame.shape == (d.sensor_height_px, d.sensor_width_px)
    assert np.all(np.isfinite(frame)) and frame.std() > 0
    assert sorted(p.name for p in out.parent.iterdir()) == sorted(
        [out.name, out.with_suffix(".json").name, out.stem + "_gt.npz"])


def test_video_example(demo, tmp_path, cli_env):
    import imageio.v3 as iio

    args = readme_command("video")
    r = kaleidospec(args, tmp_path, cli_env)
    out = tmp_path / option(args, "--out")
    n = int(option(args, "--frames"))
    frames = iio.imread(out / "video.gif", index=None)
    assert frames.shape[0] == n and frames.std() > 10
    m = json.loads((out / "metrics.json").read_text())
    assert len(m["frames"]) == n and all(np.isfinite(f["psnr"]) for f in m["frames"])
    assert len(list((out / "cubes").glob("*.exr"))) == n
    assert f"mean over {n} frames" in r.stdout


def test_real_capture_example(tmp_path, capsys, monkeypatch):
    """The README's ``reconstruct`` line on files laid out like TSA-Net's real captures
    (``meas_real``; the shifted mask cube ``mask_3d_shift``), small, built here."""
    import imageio.v3 as iio
    import scipy.io

    from kaleidospec.cli import main
    from recon.io.cubes import read_cube
    from recon.operators import standard_cassi

    args = readme_command("reconstruct")
    step, n_bands, h, w = int(option(args, "--step")), 28, 24, 20
    rng = np.random.default_rng(1)
    mask = (rng.random((h, w)) < 0.5).astype(np.float32)
    truth = np.empty((h, w, n_bands), np.float32)
    truth[:] = np.linspace(0.2, 0.8, n_bands)
    truth[6:18, 4:12] = np.linspace(0.9, 0.3, n_bands)
    g = standard_cassi(mask, step, n_bands).forward(np.moveaxis(truth, 2, 0).copy())[0]
    shifted = np.zeros((h, g.shape[1], n_bands), np.float32)
    for l in range(n_bands):
        shifted[:, step * l:step * l + w, l] = mask
    scipy.io.savemat(tmp_path / option(args, "--measurement"), {"meas_real": g})
    scipy.io.savemat(tmp_path / option(args, "--mask"), {"mask_3d_shift": shifted})
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(args)
    text = capsys.readouterr().out
    assert exc.value.code in (0, None), text
    assert "['meas_real']" in text and "['mask_3d_shift']" in text
    out = Path(option(args, "--out"))
    cube, _ = read_cube(out)
    assert cube.shape == truth.shape
    for suffix in ("_srgb.png", "_bands.png"):
        assert iio.imread(out.with_name(out.stem + suffix)).std() > 5, suffix
    assert "28 CASSI bands" in text
