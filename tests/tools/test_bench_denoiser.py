"""tools/bench_denoiser.py: its two eigensolvers solve the same problems, and it runs."""

from __future__ import annotations

import numpy as np

from tool_scripts import load_tool


def _tool():
    return load_tool("bench_denoiser")


def test_the_two_eigensolvers_agree():
    """Jacobi and LAPACK give the same largest eigenvalue and leading eigenvector (up to sign)
    of the same Gram matrices, so the benchmark compares like with like."""
    tool = _tool()
    rng = np.random.default_rng(0)
    y = rng.standard_normal((5, 16, 24))
    y[:, :, :2] *= 10.0
    grams = np.einsum("gdm,gdn->gmn", y, y)
    a, b = np.empty(5), np.empty(5)
    tool._jacobi_all(grams, a)
    tool._lapack_all(grams, b)
    np.testing.assert_allclose(a, b, rtol=1e-10)
    np.testing.assert_allclose(a, [np.linalg.eigh(g)[0][-1] + abs(np.linalg.eigh(g)[1][0, -1])
                                   for g in grams], rtol=1e-10)


def test_it_prints_a_line_per_size(monkeypatch, capsys):
    tool = _tool()
    monkeypatch.setattr(tool, "SIZES", ((2, 20, 24),))
    assert tool.main(["--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "2x20x24:" in out and "Jacobi" in out
