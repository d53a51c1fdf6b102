"""An operator's constants kept between solves (recon.solvers.constants)."""

import json

import numpy as np
import pytest

from recon.errors import InputError
from recon.solvers.band_metric import DEFAULT_EXPONENT
from recon.solvers.constants import OperatorConstants, band_metric_name, lipschitz_name


@pytest.fixture(scope="module")
def problem(ops):
    """The shared three-view kaleidoscope (conftest) measuring a box of a sloped spectrum."""
    op = ops["kaleido3"]
    x = np.zeros(op.ishape, np.float32)
    x[:, 8:24, 5:20] = np.linspace(0.2, 1.0, op.ishape[0])[:, None, None]
    return op, op.forward(x)


def test_a_constant_is_estimated_once_and_read_back_exactly():
    calls = []
    memo = OperatorConstants()
    d = memo.get("d", lambda: calls.append(1) or np.array([0.1, 1 / 3, 2.0]))
    again = memo.get("d", lambda: calls.append(1) or np.array([9.0, 9.0, 9.0]))
    assert calls == [1] and memo.estimated == ["d"]
    np.testing.assert_array_equal(d, again)
    again[0] = 5.0                                       # a copy: the memo keeps its own
    assert memo.get("d", lambda: None)[0] == 0.1
    # Through JSON, as the application's cache keeps it: the same doubles.
    back = OperatorConstants(json.loads(json.dumps(memo.as_dict())))
    np.testing.assert_array_equal(back.get("d", lambda: None), d)
    assert back.estimated == []


def test_values_that_are_not_constants():
    memo = OperatorConstants()
    assert memo.get("norm", lambda: 0.0) == 0.0          # returned for the caller to refuse,
    assert "norm" not in memo                            # not kept
    assert memo.get("norm", lambda: 2.5) == 2.5 and "norm" in memo
    # A kept value the caller's check refuses (another band count) is estimated again.
    memo = OperatorConstants({"d": [1.0, 2.0]})
    out = memo.get("d", lambda: np.ones(3), check=lambda v: np.shape(v) == (3,))
    assert out.shape == (3,) and memo.estimated == ["d"]
    for bad in ({"a": -1.0}, {"a": float("nan")}, {"a": [1.0, 0.0]}, {"a": [[1.0]]},
                {"a": "x"}, {"a": True}):
        with pytest.raises(InputError, match="'a'"):
            OperatorConstants(bad)


def test_fista_with_a_memo_gives_the_same_bits_and_estimates_nothing_twice(problem,
                                                                            monkeypatch):
    import sys

    from recon.solvers import band_metric as bmod
    from recon.solvers.fista_tv import fista_tv

    fmod = sys.modules["recon.solvers.fista_tv"]

    op, g = problem
    plain = fista_tv(op, g, iters=15, tau=0.01, metric="bands")
    memo = OperatorConstants()
    first = fista_tv(op, g, iters=15, tau=0.01, metric="bands", constants=memo)
    assert memo.estimated == [band_metric_name(DEFAULT_EXPONENT, np.float32)]

    def no_estimate(*a, **k):
        raise AssertionError("estimated again")
    monkeypatch.setattr(bmod, "band_metric", no_estimate)
    monkeypatch.setattr(fmod, "operator_norm_sq", no_estimate)
    second = fista_tv(op, g, iters=15, tau=0.01, metric="bands", constants=memo)
    for r in (first, second):
        np.testing.assert_array_equal(r.x, plain.x)
        assert r.info["band_metric"] == plain.info["band_metric"]
    # The scalar step's ||H||^2: estimated by the first solve that needs it, then kept.
    monkeypatch.undo()
    scalar = fista_tv(op, g, iters=15, tau=0.01, constants=memo)
    assert memo.estimated[-1] == lipschitz_name(np.float32)
    monkeypatch.setattr(fmod, "operator_norm_sq", no_estimate)
    np.testing.assert_array_equal(fista_tv(op, g, iters=15, tau=0.01, constants=memo).x,
                                  scalar.x)
    # Another exponent is another constant.
    monkeypatch.undo()
    fista_tv(op, g, iters=3, tau=0.01, metric="bands", metric_exponent=1.0, constants=memo)
    assert memo.estimated[-1] == band_metric_name(1.0, np.float32)


def test_a_zero_operator_is_still_refused_with_a_memo(problem):
    from recon.operators.base import LinearOperator
    from recon.solvers.fista_tv import fista_tv

    op, g = problem

    class Zero(LinearOperator):
        def _forward(self, x):
            return np.zeros(self.oshape, x.dtype)

        def _adjoint(self, y):
            return np.zeros(self.ishape, y.dtype)

    memo = OperatorConstants()
    with pytest.raises(InputError, match="zero"):
        fista_tv(Zero(op.ishape, op.oshape), g, iters=2, tau=0.01, constants=memo)
    assert memo.as_dict() == {}
