"""tools/bench_tradeoff.py --priors: one Pareto front per solver and prior."""

from __future__ import annotations

import json

import pytest

from tool_scripts import load_tool


def _tool():
    return load_tool("bench_tradeoff")


def test_every_solver_runs_with_every_prior_and_the_prior_changes_the_result(tmp_path):
    """--quick with two priors: rows for each (solver, prior, views, noise, checkpoint), the
    priors' reconstructions differ, and the plots are written."""
    tool = _tool()
    assert tool.main(["--quick", "--priors", "tv,subspace-tv", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "tradeoff.json").read_text())
    assert doc["priors"] == ["tv", "subspace-tv"]
    table = doc["table"]
    keys = {(r["solver"], r["prior"], r["views"], r["snr_db"]) for r in table}
    assert len(keys) == len(tool.SOLVERS) * 2 * len(doc["views"]) * len(doc["snr_db"])
    for solver in tool.SOLVERS:
        last = {r["prior"]: r["psnr"] for r in table if r["solver"] == solver
                and r["views"] == 3 and r["snr_db"] is None and r["iters"] == 50}
        assert set(last) == {"tv", "subspace-tv"}
        assert abs(last["tv"] - last["subspace-tv"]) > 1e-3
    assert all("prior" in r for r in doc["recommended"])
    assert (tmp_path / "tradeoff_psnr.png").stat().st_size > 0


def test_an_unknown_prior_is_refused_before_any_work(tmp_path):
    with pytest.raises(Exception, match="no-such-prior"):
        _tool().main(["--quick", "--priors", "tv,no-such-prior", "--out", str(tmp_path)])
    assert not (tmp_path / "tradeoff.json").exists()
