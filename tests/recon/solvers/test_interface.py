"""The common solver interface: registry, solve(), SolverResult, callback, tol, warm start."""

import numpy as np
import pytest

from cases import piecewise_cube
from recon.errors import InputError
from recon.metrics import psnr
from recon.operators import MatrixOperator, kaleidoscope_cassi, standard_cassi
from recon.solvers import SOLVERS, SolverResult, solve
from recon.solvers.progress import ProgressCallback

NAMES = sorted(SOLVERS)


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(1)
    op = standard_cassi((rng.random((32, 32)) > 0.5).astype(np.float32), 1, 8)
    truth = piecewise_cube()
    return op, truth, op.forward(truth)


def test_registry():
    assert set(SOLVERS) == {"twist", "gap-tv", "fista-tv", "admm"}


@pytest.mark.parametrize("name", NAMES)
def test_result_and_callback_once_per_iteration(name, problem):
    op, truth, g = problem
    calls = []

    def cb(it, x, info):
        calls.append(it)
        assert x.shape == op.ishape and x.dtype == np.float32
        assert {"objective", "rel_change", "seconds"} <= set(info)

    res = solve(name, op, g, iters=7, tau=0.05, callback=cb)
    assert isinstance(res, SolverResult)
    assert calls == list(range(1, 8))
    assert res.iterations == 7 and not res.converged and res.seconds > 0
    assert res.x.shape == op.ishape and res.x.dtype == np.float32


@pytest.mark.parametrize("name", NAMES)
def test_callback_true_stops(name, problem):
    op, _, g = problem
    res = solve(name, op, g, iters=20, tau=0.05, callback=lambda it, x, info: it == 3)
    assert res.iterations == 3


@pytest.mark.parametrize("name", NAMES)
def test_tol_stops_early(name, problem):
    op, _, g = problem
    changes, held = [], []

    def cb(it, x, info):
        changes.append(info["rel_change"])
        held.append(info["held"])

    res = solve(name, op, g, iters=400, tau=0.05, tol=1e-3, callback=cb)
    assert res.converged and res.iterations < 400
    # The first change below tol stops the loop, unless the rule is held after a restart.
    assert changes[-1] < 1e-3 and not held[-1]
    assert all(c >= 1e-3 or h for c, h in zip(changes[:-1], held[:-1]))


def test_rule_held_after_restart():
    from recon.solvers.base import RESTART_HOLD, IterationLoop

    loop = IterationLoop(1e-3, None)
    for it in range(1, 51):
        assert not loop.step(it, None, 1e-2)
    loop.restarted()
    # After 50 iterations of momentum, changes below tol in the hold (the restart's own
    # iteration included) do not stop ...
    for it in range(51, 51 + RESTART_HOLD):
        assert not loop.step(it, None, 1e-4)
    assert not loop.converged
    # ... the first one after it does.
    assert loop.step(51 + RESTART_HOLD, None, 1e-4) and loop.converged


def test_rule_waits_for_the_priors_own_state():
    from recon.solvers.base import IterationLoop

    # The iterate's change is below tol, the prior's basis still moves: go on ...
    loop = IterationLoop(1e-3, None)
    for it, moved in enumerate([5e-3, 2e-3, 1.1e-3, 1e-3], start=1):
        assert not loop.step(it, None, 1e-4, prior_change=moved)
    # ... until it has settled too; a prior with no such state (None) never holds the rule.
    assert loop.step(5, None, 1e-4, prior_change=9e-4) and loop.converged
    assert IterationLoop(1e-3, None).step(1, None, 1e-4, prior_change=None)
    assert not IterationLoop(None, None).step(1, None, 1e-4, prior_change=0.0)


def test_rule_with_a_prior_state_waits_for_the_momentum_to_break():
    from recon.solvers.base import COAST, RESTART_HOLD, IterationLoop

    # The momentum has run since the start: past COAST iterations the iterate is coasting,
    # and a small change does not stop a solve whose prior reports a (settled) state ...
    loop = IterationLoop(1e-3, None, restarts=True)
    for it in range(1, COAST + 1):
        assert not loop.step(it, None, 1e-2, prior_change=1e-5)
    for it in range(COAST + 1, COAST + 40):
        assert not loop.step(it, None, 1e-4, prior_change=1e-5)
    # ... until a restart, once its hold is over.
    loop.restarted()
    first = COAST + 40
    for it in range(first, first + RESTART_HOLD):
        assert not loop.step(it, None, 1e-4, prior_change=1e-5)
    assert loop.step(first + RESTART_HOLD, None, 1e-4, prior_change=1e-5) and loop.converged
    # A prior without a state (TV), or a solver without restarts, is not held.
    tv = IterationLoop(1e-3, None, restarts=True)
    assert not any(tv.step(it, None, 1e-2) for it in range(1, COAST + 5))
    assert tv.step(COAST + 5, None, 1e-4)
    plain = IterationLoop(1e-3, None)
    assert not any(plain.step(it, None, 1e-2, prior_change=1e-5) for it in range(1, COAST + 5))
    assert plain.step(COAST + 5, None, 1e-4, prior_change=1e-5)


# GAP is left out: with a rank-2 subspace on this 8-band cube its iterate keeps a relative
# change near 0.1 for 400 iterations, so its rule never fires either way.
@pytest.mark.parametrize("name", ["fista-tv", "admm", "twist"])
def test_solvers_stop_only_once_the_subspace_has_settled(name, problem):
    op, _, g = problem
    from recon.priors.subspace import SubspaceTV

    log = []

    def cb(it, x, info):
        log.append((info["rel_change"], info["prior_change"], info["held"]))

    res = solve(name, op, g, iters=400, prior=SubspaceTV(0.05, rank=2), tol=1e-3, callback=cb)
    assert res.converged and res.iterations == len(log) < 400

    def passes(c, m, h):
        return c is not None and c < 1e-3 and (m is None or m < 1e-3) and not h

    assert passes(*log[-1]) and log[-1][1] is not None
    assert not any(passes(*entry) for entry in log[:-1])
    if name == "admm":
        # Here the basis still moved when the iterate's change first fell below tol.
        assert any(c is not None and c < 1e-3 and m >= 1e-3 for c, m, _ in log)


class _TwoStage:
    """A prior of two stages (recon.priors.base.stages), or of one without ``first``: its own
    prox is the projection onto the non-negative cube, easy to tell from the first stage's."""

    name = "two-stage"

    def __init__(self, first, n):
        self.first, self.n, self.calls = first, n, 0

    def prox(self, v, step, out=None):
        self.calls += 1
        return np.maximum(v, 0, out=out)

    def value(self, x):
        return None

    def reset(self):
        self.calls = 0

    def stages(self):
        return None if self.first is None else (self.first, self.n)


@pytest.mark.parametrize("name", ["fista-tv", "admm", "gap-tv"])
def test_a_two_stage_prior_runs_its_stages_in_turn(name, problem):
    """solve() runs the first stage's prior to the rule, then the prior itself for its own
    iterations from there, without the rule: the same arrays as the two solves by hand, one
    count of iterations for the callback, both stages' seconds."""
    from recon.priors.tv import TVPrior

    op, _, g = problem
    first = TVPrior(0.05, op.ishape, np.float32)
    log = []
    res = solve(name, op, g, iters=300, tol=1e-3, prior=_TwoStage(first, 6),
                callback=lambda it, x, info: log.append((it, info["seconds"])) and None)
    ref1 = solve(name, op, g, iters=300, tol=1e-3, prior=TVPrior(0.05, op.ishape, np.float32))
    ref2 = solve(name, op, g, iters=6, x0=ref1.x, prior=_TwoStage(None, 0))
    assert ref1.converged and ref1.iterations < 300
    np.testing.assert_array_equal(res.x, ref2.x)
    assert res.iterations == ref1.iterations + 6 and res.converged
    assert [it for it, _ in log] == list(range(1, res.iterations + 1))
    seconds = [t for _, t in log]
    assert seconds == sorted(seconds) and res.seconds >= seconds[-1]
    assert res.info["first_stage"]["iterations"] == ref1.iterations
    assert res.info["first_stage"]["converged"] and res.info["first_stage"]["prior"] == "tv"


def test_a_two_stage_prior_ends_with_a_first_stage_the_rule_did_not_stop(problem):
    op, _, g = problem
    from recon.priors.tv import TVPrior

    prior = _TwoStage(TVPrior(0.05, op.ishape, np.float32), 6)
    res = solve("fista-tv", op, g, iters=50, prior=prior,
                callback=lambda it, x, info: it == 4)
    assert res.iterations == 4 and prior.calls == 0
    # A first stage that runs out of iterations (no rule) is the result too.
    res = solve("fista-tv", op, g, iters=5, prior=prior)
    assert res.iterations == 5 and not res.converged and prior.calls == 0
    first = res.info["first_stage"]
    assert (first["iterations"], first["converged"], first["prior"]) == (5, False, "tv")


def test_a_two_stage_priors_second_stage_takes_fistas_scalar_step(problem):
    """The band metric given for the solve is the first stage's; the second (a prior that
    does not declare the metric) takes the scalar step instead of failing."""
    from recon.priors.subspace import SubspaceTV

    op, _, g = problem
    res = solve("fista-tv", op, g, iters=400, tol=1e-3, metric="bands", metric_exponent=0.5,
                prior=_TwoStage(SubspaceTV(0.05, rank=2), 3))
    first = res.info["first_stage"]
    assert first["converged"] and res.iterations == first["iterations"] + 3
    assert res.info["metric"] == "scalar"
    with pytest.raises(InputError, match="band metric"):
        solve("fista-tv", op, g, iters=3, metric="bands", prior=_TwoStage(None, 0))


def test_close_restarts_hold_briefly():
    from recon.solvers.base import RESTART_HOLD, IterationLoop

    # Restarts every third iteration (the momentum no longer accelerates) hold the rule for
    # two iterations each, so it is tested, and stops, between them.
    loop = IterationLoop(1e-3, None)
    for it in range(1, 31):
        assert not loop.step(it, None, 1e-2)
    stopped = None
    for it in range(31, 31 + 4 * RESTART_HOLD):
        if (it - 31) % 3 == 0:
            loop.restarted()
        if loop.step(it, None, 1e-4):
            stopped = it
            break
    # The first restart (after 30 iterations of momentum) holds RESTART_HOLD iterations, 31-40,
    # which the restarts at 34 and 37 do not shorten; the one at 40 holds 40-41: 42 is tested
    # and stops.
    assert stopped == 42 and loop.converged


@pytest.mark.parametrize("name", NAMES)
def test_warm_start_from_truth_stays_near(name, problem):
    op, truth, g = problem
    # A small TV weight: the truth is then close to a minimiser, so iterations stay near it.
    cold = solve(name, op, g, iters=5, tau=0.002)
    warm = solve(name, op, g, iters=5, tau=0.002, x0=truth)
    assert psnr(warm.x, truth) > 30
    assert psnr(warm.x, truth) > psnr(cold.x, truth) + 5


@pytest.mark.parametrize("name", NAMES)
def test_float64_stays_float64(name, problem):
    op, truth, g = problem
    res = solve(name, op, g.astype(np.float64), iters=3, tau=0.05)
    assert res.x.dtype == np.float64


@pytest.mark.parametrize("name", NAMES)
def test_generic_operator_with_several_output_blocks(name):
    # Not CASSI: a random non-negative matrix, oshape with K = 3 blocks; 75 % as many rows as
    # unknowns, so the TV prior is what recovers the cube.
    rng = np.random.default_rng(2)
    ishape, oshape = (2, 12, 12), (3, 6, 16)
    a = rng.random((int(np.prod(oshape)), int(np.prod(ishape)))) < 0.1
    op = MatrixOperator(a.astype(np.float32), ishape, oshape)
    truth = piecewise_cube(2, 12, 12, seed=3)
    truth[:, :, :] = truth[:, :, :].round(1)
    g = op.forward(truth)
    start = op.adjoint(g)
    res = solve(name, op, g, iters=150, tau=0.01)
    assert psnr(res.x, truth) > psnr(start, truth) + 10


def test_bad_inputs(problem):
    op, truth, g = problem
    with pytest.raises(InputError, match="unknown solver"):
        solve("nope", op, g, iters=2, tau=0.1)
    with pytest.raises(InputError, match="no option"):
        solve("twist", op, g, iters=2, tau=0.1, bogus=1)
    with pytest.raises(InputError):
        solve("gap-tv", op, g[:, :, :-1], iters=2, tau=0.1)
    with pytest.raises(InputError):
        solve("gap-tv", op, g, iters=0, tau=0.1)
    with pytest.raises(InputError):
        solve("gap-tv", op, g, iters=2, tau=-1)
    with pytest.raises(InputError):
        solve("gap-tv", op, g, iters=2, tau=0.1, tol=0)
    with pytest.raises(InputError):
        solve("fista-tv", op, g, iters=2, tau=0.1, x0=truth[:-1])
    bad = g.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError):
        solve("twist", op, bad, iters=2, tau=0.1)


def test_progress_callback_records_psnr(problem):
    import io

    op, truth, g = problem
    buf = io.StringIO()
    with ProgressCallback(5, truth=truth, file=buf) as cb:
        res = solve("twist", op, g, iters=5, tau=0.05, callback=cb)
    assert [h["iteration"] for h in cb.history] == [1, 2, 3, 4, 5]
    assert cb.history[-1]["psnr"] == pytest.approx(psnr(res.x, truth), abs=1e-3)
    assert all(h["objective"] is not None for h in cb.history)
    assert "dB" in buf.getvalue()
    with pytest.raises(InputError):
        ProgressCallback(3, truth=np.zeros((2, 2)))


def test_kaleidoscope_three_views_beats_one_view():
    # The multi-view operator carries more information about the same cube.
    rng = np.random.default_rng(4)
    masks = (rng.random((3, 32, 32)) > 0.5).astype(np.float32)
    truth = piecewise_cube(seed=5)
    offsets = np.arange(8, dtype=float)
    one = kaleidoscope_cassi(masks, offsets, 1)
    three = kaleidoscope_cassi(masks, offsets, 3)
    p1 = psnr(solve("gap-tv", one, one.forward(truth), iters=60, tau=0.05).x, truth)
    p3 = psnr(solve("gap-tv", three, three.forward(truth), iters=60, tau=0.05).x, truth)
    assert p3 > p1 + 3


def _power_reference(op, n_iter, dtype, seed, weights=None):
    # The loop power_iteration replaced: new cubes every iteration.
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(op.ishape).astype(dtype)
    x /= np.linalg.norm(x)
    w = 1 if weights is None else np.asarray(weights).astype(dtype)[:, None, None]
    lam = 0.0
    for _ in range(n_iter):
        y = op.adjoint(op.forward(x * w)) * w
        lam = float(np.linalg.norm(y))
        x = (y / lam).astype(dtype, copy=False)
    return lam


@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("key", ["standard", "kaleido3"])
def test_power_iteration_matches_its_reference_and_the_top_eigenvalue(small_ops, key, weighted):
    from recon.solvers.base import operator_norm_sq, power_iteration

    op = small_ops[key]
    w = np.linspace(0.3, 1.0, op.ishape[0]) if weighted else None
    for dtype in (np.float32, np.float64):
        assert power_iteration(op, 15, dtype, 3, w) == _power_reference(op, 15, dtype, 3, w)
    if not weighted:
        assert operator_norm_sq(op) == 1.02 * _power_reference(op, 15, np.float32, 0)
    # The eigenvalue itself, from the dense matrix W H^T H W.
    n = int(np.prod(op.ishape))
    cols = np.stack([op.adjoint(op.forward(e.reshape(op.ishape))).ravel()
                     for e in np.eye(n)], axis=1)
    ww = np.ones(n) if w is None else np.repeat(w, n // op.ishape[0])
    top = np.linalg.eigvalsh(ww[:, None] * cols * ww[None, :]).max()
    assert power_iteration(op, 400, np.float64, 0, w) == pytest.approx(top, rel=1e-6)
    assert power_iteration(MatrixOperator(np.zeros((4, 6))), 5) == 0.0
