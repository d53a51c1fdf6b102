r"""The contract between priors and solvers.

A prior is a regulariser :math:`\varphi` (its weight included) known through its proximal map

.. math::

    \mathrm{prox}_{s\varphi}(v) = \arg\min_x \tfrac12\|x - v\|_2^2 + s\,\varphi(x),

or, for a plug-and-play prior, through a denoiser used in its place (the step :math:`s` then
sets the denoising strength).  Solvers see only this contract, so any prior works with any
solver that can take it (proximal gradient / FISTA, GAP, ADMM / half-quadratic splitting).

:class:`Prior` is the contract itself (a protocol: any object with these three methods is a
prior).  :class:`PriorBase` is a convenience base class that adds the optional operations the
solvers use when a prior offers them, each with a generic default written with the three
methods only, so that a prior overrides one only to make it faster or to keep its own state:

- :meth:`PriorBase.gradient_prox` -- a gradient step and the prox in one,
  :math:`\mathrm{prox}_{s\varphi}(b + c\,H^\top y)` (GAP's step; the TV prior fuses it into one
  pass over the cube where the operator allows);
- :meth:`PriorBase.combine_value` -- a three-term combination and its :math:`\varphi` (TwIST's
  two-step update);
- :meth:`PriorBase.describe` -- what a solver's ``info`` records of the prior;
- :meth:`PriorBase.refine` -- continue an inexact (iterative) prox on the same input;
- :meth:`PriorBase.state` / :meth:`PriorBase.load_state` -- warm-start state carried from one
  problem to the next (a video's frames);
- :meth:`PriorBase.state_change` -- how far what the prior re-estimates from the iterate (a
  spectral basis) moved at its last call: the solvers' stopping rule waits for it too;
- :meth:`PriorBase.scaled_prox` -- :math:`q \odot \mathrm{prox}_{s\varphi}(q \odot v)`
  for a factor per band (FISTA's band metric on a ``band_weighted`` prior), which a prior may
  make without weighing the cube twice;
- :meth:`PriorBase.rescaled_prox` -- :math:`r \odot \mathrm{prox}_{s\varphi}(v)` for a
  factor per band (FISTA's band metric on a ``band_scalable`` prior), which a prior may scale
  as it writes its result instead of in a pass of its own;
- :meth:`PriorBase.prox_value` -- :math:`\varphi` of the last prox's result, where the prox
  has it at hand (FISTA's restart test then evaluates no :meth:`value` of its own);
- :meth:`PriorBase.stages` -- a plug-and-play prior that starts from another prior's solve
  (:func:`recon.solvers.solve` runs the two stages).

A prior may also declare ``band_scalable = True`` (default False): it separates over the
bands and is positively homogeneous of degree one, :math:`\varphi(x) = \sum_l \varphi_l(x_l)`
with :math:`\varphi_l(\lambda x_l) = \lambda\varphi_l(x_l)`, so that solvers may take a step
per band (:mod:`recon.solvers.band_metric`).  A prior that couples the bands may declare
``band_weighted = True`` instead: in that metric it is then taken on the band-weighted cube
:math:`\varphi(w \odot x)`.

Solvers look these up with :func:`gradient_prox`, :func:`combine_value`, :func:`refine` and
:func:`describe`, so a bare :class:`Prior` that does not derive from :class:`PriorBase` works
too.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from recon import kernels
from recon.errors import InputError

__all__ = ["Prior", "PriorBase", "check_prior", "gradient_prox", "combine_value", "refine",
           "describe", "state_change", "prox_value", "previous_value", "scaled_prox",
           "rescaled_prox", "stages",
           "linear_combination", "solver_algorithm"]


@runtime_checkable
class Prior(Protocol):
    """A regulariser on band-major ``(L, H, W)`` cubes.

    Methods
    -------
    prox(v, step, out=None)
        :math:`\\mathrm{prox}_{s\\varphi}(v)` with :math:`s` = ``step`` > 0, into ``out`` when
        given (``out`` may be ``v``).  May keep warm-start state between calls.
    value(x)
        :math:`\\varphi(x)`, or ``None`` where the prior defines no value (a denoiser).
    reset()
        Forget any warm-start state (a new problem begins).
    """

    def prox(self, v: np.ndarray, step: float, out: np.ndarray | None = None) -> np.ndarray: ...

    def value(self, x: np.ndarray) -> float | None: ...

    def reset(self) -> None: ...


def check_prior(prior) -> Prior:
    """``prior`` if it fulfils :class:`Prior`, else an :class:`~recon.errors.InputError`."""
    if not isinstance(prior, Prior):
        raise InputError(f"prior must be a recon prior (prox, value, reset), got "
                         f"{type(prior).__name__}; recon.priors.make_prior builds one by name")
    return prior


class PriorBase:
    """Generic versions of the optional operations (see the module notes).

    Subclasses implement :meth:`prox`, :meth:`value` and :meth:`reset`.
    """

    #: Whether the prior separates over the bands and is 1-homogeneous (see the module notes).
    band_scalable = False
    band_weighted = False

    def prox(self, v: np.ndarray, step: float, out: np.ndarray | None = None) -> np.ndarray:
        raise NotImplementedError

    def value(self, x: np.ndarray) -> float | None:
        return None

    def reset(self) -> None:
        return None

    def gradient_prox(self, op, y: np.ndarray, base: np.ndarray, step: float,
                      scale: float = 1.0, out: np.ndarray | None = None) -> np.ndarray:
        r""":math:`\mathrm{prox}_{s\varphi}(b + c\,H^\top y)` with :math:`s` = ``step``,
        :math:`b` = ``base``, :math:`c` = ``scale``; ``out`` may be ``base``.

        Generic: ``op.adjoint_add`` then :meth:`prox`.
        """
        out = op.adjoint_add(y, base, scale, out=out)
        return self.prox(out, step, out=out)

    def combine_value(self, a: float, u: np.ndarray, b: float, v: np.ndarray, c: float,
                      w: np.ndarray, out: np.ndarray) -> float | None:
        r"""``out`` :math:`= a u + b v + c w` (``out`` aliases no input) and
        :math:`\varphi(\mathrm{out})`.

        Generic: the combination (:func:`recon.kernels.vector.combine3` or NumPy), then
        :meth:`value`.
        """
        linear_combination(a, u, b, v, c, w, out, getattr(self, "threads", None))
        return self.value(out)

    def refine(self, v: np.ndarray, step: float, out: np.ndarray) -> int:
        """Continue the prox of ``v`` (the input of the last call) into ``out``, when the
        prox is iterative and was stopped early; return the inner iterations done (0: the
        prox is exact or cannot be continued, ``out`` is unchanged)."""
        return 0

    def describe(self) -> dict:
        """What a solver's ``info`` records of this prior: at least ``{"prior": name}``."""
        return {"prior": getattr(self, "name", type(self).__name__)}

    def state(self) -> dict:
        """Warm-start state to carry to the next problem (copies); empty by default."""
        return {}

    def load_state(self, state: dict) -> None:
        """Start from a :meth:`state` of an earlier problem of the same shape."""
        return None

    def state_change(self) -> float | None:
        """The relative change, at the last prox, of what the prior re-estimates from the
        iterate (its own fixed point, besides the solver's); None where it keeps nothing of
        the kind or has no earlier call to compare with.

        A prior whose prox depends on the iterate through such a state (a basis) has
        converged only when that state has settled too; the solvers' stopping rule
        (:class:`recon.solvers.base.IterationLoop`) waits for this to fall below its
        tolerance as well as the iterate's relative change."""
        return None

    def scaled_prox(self, v: np.ndarray, step: float, weights, out: np.ndarray | None = None
                    ) -> np.ndarray:
        r""":math:`q \odot \mathrm{prox}_{s\varphi}(q \odot v)` for a factor :math:`q_l > 0`
        per band (``weights``, shape ``(L,)``; None: the plain prox), into ``out`` if given.
        ``v`` may be overwritten.  The default weighs ``v`` in place, calls :meth:`prox` and
        weighs its result."""
        return _scaled_prox_default(self, v, step, weights, out)

    def rescaled_prox(self, v: np.ndarray, step: float, factors, out: np.ndarray | None = None
                      ) -> np.ndarray:
        r""":math:`r \odot \mathrm{prox}_{s\varphi}(v)` for a factor :math:`r_l` per band
        (``factors``, shape ``(L,)``), into ``out`` if given.  The default calls :meth:`prox`
        and scales its result in place."""
        return _rescaled_prox_default(self, v, step, factors, out)

    def prox_value(self) -> float | None:
        """:math:`\varphi` of the result of the last :meth:`prox` call, where the prox has it at
        hand for less than a :meth:`value` call would cost (the subspace prior: TV of its
        coefficient images, without projecting the cube again); None (the default) where it
        does not, or before any call.  Equal to ``value`` of that result up to rounding."""
        return None

    def previous_value(self) -> float | None:
        r""":math:`\varphi` of the result of the prox call before the last one, scored with the
        state the last call re-estimated (:meth:`state_change`), where the prior has it at hand
        for less than a :meth:`value` call would cost; None (the default) where it does not, or
        before two calls.  Equal to ``value`` of that result, called now, up to rounding.

        A solver that compares its last two iterates under one objective (FISTA's restart
        test) asks for it, when the earlier iterate is the earlier prox's result."""
        return None

    def stages(self) -> tuple[Prior, int] | None:
        """A prior solved in two stages: ``(first, n)``, the prior of the first stage, which
        the solver runs to its stopping rule (or its iterations), and ``n`` iterations of this
        prior after it, from the first stage's result (:func:`recon.solvers.solve`).  None
        (the default): the prior is solved in one stage."""
        return None


def solver_algorithm(solver) -> str:
    """A solver's name without the ``-tv`` of its default prior (``"fista-tv"`` →
    ``"fista"``): the key of the priors' per-solver settings."""
    name = str(solver)
    return name[:-3] if name.endswith("-tv") else name


def gradient_prox(prior, op, y, base, step, scale=1.0, out=None) -> np.ndarray:
    """:meth:`PriorBase.gradient_prox` of ``prior``, or its generic form for a bare prior."""
    fn = getattr(prior, "gradient_prox", None)
    if fn is not None:
        return fn(op, y, base, step, scale, out=out)
    return PriorBase.gradient_prox(prior, op, y, base, step, scale, out=out)


def combine_value(prior, a, u, b, v, c, w, out) -> float | None:
    """:meth:`PriorBase.combine_value` of ``prior``, or its generic form for a bare prior."""
    fn = getattr(prior, "combine_value", None)
    if fn is not None:
        return fn(a, u, b, v, c, w, out)
    return PriorBase.combine_value(prior, a, u, b, v, c, w, out)


def describe(prior) -> dict:
    """:meth:`PriorBase.describe` of ``prior``; ``{"prior": its class name}`` for a bare one."""
    fn = getattr(prior, "describe", None)
    return {"prior": type(prior).__name__} if fn is None else dict(fn())


def state_change(prior) -> float | None:
    """:meth:`PriorBase.state_change` of ``prior``; None for a bare prior."""
    fn = getattr(prior, "state_change", None)
    change = None if fn is None else fn()
    return None if change is None else float(change)


def scaled_prox(prior, v, step, weights, out=None):
    """:meth:`PriorBase.scaled_prox` of ``prior``; its default for a bare prior."""
    fn = getattr(prior, "scaled_prox", None)
    return _scaled_prox_default(prior, v, step, weights, out) if fn is None else \
        fn(v, step, weights, out)


def rescaled_prox(prior, v, step, factors, out=None):
    """:meth:`PriorBase.rescaled_prox` of ``prior``; its default for a bare prior."""
    fn = getattr(prior, "rescaled_prox", None)
    return _rescaled_prox_default(prior, v, step, factors, out) if fn is None else \
        fn(v, step, factors, out)


def _rescaled_prox_default(prior, v, step, factors, out):
    out = prior.prox(v, step, out=out)
    out *= np.asarray(factors, dtype=out.dtype).reshape(-1, *([1] * (out.ndim - 1)))
    return out


def _scaled_prox_default(prior, v, step, weights, out):
    if weights is None:
        return prior.prox(v, step, out=out)
    q = np.asarray(weights, dtype=v.dtype).reshape(-1, *([1] * (v.ndim - 1)))
    np.multiply(v, q, out=v)
    out = prior.prox(v, step, out=out)
    out *= q
    return out


def prox_value(prior) -> float | None:
    """:meth:`PriorBase.prox_value` of ``prior``; None for a bare prior."""
    fn = getattr(prior, "prox_value", None)
    value = None if fn is None else fn()
    return None if value is None else float(value)


def previous_value(prior) -> float | None:
    """:meth:`PriorBase.previous_value` of ``prior``; None for a bare prior."""
    fn = getattr(prior, "previous_value", None)
    value = None if fn is None else fn()
    return None if value is None else float(value)


def stages(prior) -> tuple[Prior, int] | None:
    """:meth:`PriorBase.stages` of ``prior``; None for a bare prior."""
    fn = getattr(prior, "stages", None)
    return None if fn is None else fn()


def refine(prior, v, step, out) -> int:
    """:meth:`PriorBase.refine` of ``prior``; 0 for a bare prior."""
    fn = getattr(prior, "refine", None)
    return 0 if fn is None else int(fn(v, step, out))


#: Elements per block of :func:`linear_combination`'s NumPy path (a block and its scratch stay
#: in L2 cache).
_BLOCK = 1 << 16


def linear_combination(a: float, u: np.ndarray, b: float, v: np.ndarray, c: float,
                       w: np.ndarray, out: np.ndarray, threads: int | None = None) -> np.ndarray:
    """``out = a*u + b*v + c*w`` in one pass (:func:`recon.kernels.vector.combine3`), or with
    NumPy block by block: no array-sized temporaries, and each block is read once from memory
    (``out`` must alias none of the inputs); threaded over spans."""
    from recon.prox.tv import parallel_spans

    uf, vf, wf, of = u.reshape(-1), v.reshape(-1), w.reshape(-1), out.reshape(-1)
    if kernels.usable(u, v, w, out):
        from recon.kernels import vector as kvec

        t = out.dtype.type
        with kernels.threads(threads):
            kvec.combine3(t(a), uf, t(b), vf, t(c), wf, of)
        return out

    def run(lo, hi):
        tmp = np.empty(min(_BLOCK, hi - lo), dtype=out.dtype)
        for i in range(lo, hi, _BLOCK):
            j = min(hi, i + _BLOCK)
            o, t = of[i:j], tmp[:j - i]
            np.multiply(uf[i:j], a, out=o)
            np.multiply(vf[i:j], b, out=t)
            o += t
            np.multiply(wf[i:j], c, out=t)
            o += t

    parallel_spans(run, of.size, threads, min_span=4 * _BLOCK)
    return out
