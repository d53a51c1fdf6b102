"""tools/exp_tsa_real.py: each capture through ``kaleidospec reconstruct`` with each prior."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tool_scripts import load_tool


def _tool():
    return load_tool("exp_tsa_real")


def _captures(root: Path, size=24, bands=28, step=2) -> None:
    """A TSA-Net-like folder: ``tsa/mask.mat`` (size²) and ``tsa/scene1.mat`` (meas_real)."""
    from scipy.io import savemat

    rng = np.random.default_rng(0)
    mask = (rng.random((size, size)) < 0.5).astype(np.float32)
    cube = rng.random((size, size, bands)).astype(np.float32)
    meas = np.zeros((size, size + step * (bands - 1)), np.float32)
    for l in range(bands):
        meas[:, step * l:step * l + size] += mask * cube[..., l]
    (root / "tsa").mkdir()
    savemat(root / "tsa" / "mask.mat", {"mask": mask})
    savemat(root / "tsa" / "scene1.mat", {"meas_real": meas})


def test_each_prior_reconstructs_each_capture_and_the_figure_is_written(tmp_path, monkeypatch):
    _captures(tmp_path)
    monkeypatch.setenv("KALEIDOSPEC_DATA", str(tmp_path))
    out, fig = tmp_path / "out", tmp_path / "fig.png"
    assert _tool().main(["--priors", "tv,subspace-tv", "--scenes", "scene1", "--out", str(out),
                         "--figure", str(fig)]) == 0
    rows = json.loads((out / "exp_tsa_real.json").read_text())["rows"]
    assert [(r["scene"], r["prior"]) for r in rows] == [("scene1", "tv"),
                                                        ("scene1", "subspace-tv")]
    cubes = []
    for r in rows:
        assert r["iterations"] == 50 and r["solve_s"] > 0 and r["wall_s"] >= r["solve_s"]
        cubes.append(np.load(r["cube"])["cube"])
    assert cubes[0].shape == (24, 24, 28)
    assert not np.allclose(cubes[0], cubes[1])  # the prior reached the solver
    assert fig.stat().st_size > 0


def test_without_the_captures_it_says_where_they_go(tmp_path, monkeypatch):
    monkeypatch.setenv("KALEIDOSPEC_DATA", str(tmp_path))
    with pytest.raises(SystemExit, match="tsa/"):
        _tool().main(["--out", str(tmp_path / "out")])
