"""Precision and threading: float32 vs float64 runs, 1 vs 2 TV threads, BLAS/OpenMP threads.

Stated tolerance: after 50 iterations on the 24×24×6 kaleidoscope problem (40 dB noise), the
float32 and float64 reconstructions agree to a relative L2 difference of 1e-5 (measured:
1e-7 to 5e-7; float32 rounding is 6e-8).  Threads split the TV prox over bands, which are
independent, so the results must be bit-identical; NumPy's BLAS (dot products of the
objective and the step sizes) must not change them either.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from recon.solvers import SOLVERS, solve

NAMES = sorted(SOLVERS)
F32_F64_RTOL = 1e-5


@pytest.fixture(scope="module", params=[1, 3], ids=["1view", "3views"])
def problem(request, stress):
    truth = stress.piecewise_cube()
    op = stress.kaleido_op(request.param)
    return op, stress.add_noise(op.forward(truth), 40.0, seed=1), truth


@pytest.mark.parametrize("name", NAMES)
def test_float32_and_float64_agree(problem, stress, name):
    op, g, truth = problem
    r32 = solve(name, op, g.astype(np.float32), iters=50, tau=stress.TAU[name])
    r64 = solve(name, op, g.astype(np.float64), iters=50, tau=stress.TAU[name])
    assert r32.x.dtype == np.float32 and r64.x.dtype == np.float64
    d = stress.rel_err(r32.x, r64.x)
    assert d < F32_F64_RTOL, d
    # and the agreement is not that of two useless answers
    assert stress.rel_err(r64.x, truth) < 0.35


@pytest.mark.parametrize("name", NAMES)
def test_result_does_not_depend_on_tv_threads(problem, stress, name):
    op, g, _ = problem
    a = solve(name, op, g, iters=30, tau=stress.TAU[name], threads=1).x
    b = solve(name, op, g, iters=30, tau=stress.TAU[name], threads=2).x
    c = solve(name, op, g, iters=30, tau=stress.TAU[name], threads=4).x
    assert np.array_equal(a, b) and np.array_equal(a, c)


_CHILD = r"""
import hashlib, json, sys
import numpy as np
from recon.operators import kaleidoscope_cassi
from recon.solvers import solve
rng = np.random.default_rng(0)
op = kaleidoscope_cassi((rng.random((3, 24, 24)) < 0.5).astype(np.float32), 0.9 * np.arange(6), 3)
x = rng.random(op.ishape).astype(np.float32)
g = op.forward(x)
out = {}
for name in ("twist", "gap-tv", "fista-tv"):
    r = solve(name, op, g, iters=20, tau=0.1, threads=int(sys.argv[1]))
    out[name] = hashlib.sha256(np.ascontiguousarray(r.x).tobytes()).hexdigest()
print(json.dumps(out))
"""


def _child(env_threads: str, tv_threads: int) -> dict:
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = env_threads
    r = subprocess.run([sys.executable, "-c", _CHILD, str(tv_threads)], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_result_does_not_depend_on_blas_threads():
    one = _child("1", 1)
    assert _child("2", 2) == one
