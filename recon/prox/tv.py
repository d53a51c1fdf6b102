r"""Spatial total variation of band-major cubes and its proximal map.

A cube :math:`f` has the working layout ``(L, H, W)``: every band is a contiguous image.  The
total variation is spatial only and summed over bands (paper Eq. 7; no spectral smoothing).  With
forward differences and a Neumann boundary (the difference past the last row or column is zero),

.. math::

    (\nabla f)_{l,i,j} = \bigl(f_{l,i+1,j}-f_{l,i,j},\; f_{l,i,j+1}-f_{l,i,j}\bigr),

the isotropic and the anisotropic variants are

.. math::

    \mathrm{TV}_\mathrm{iso}(f) = \sum_{l,i,j} \|(\nabla f)_{l,i,j}\|_2, \qquad
    \mathrm{TV}_\mathrm{aniso}(f) = \sum_{l,i,j} \|(\nabla f)_{l,i,j}\|_1 .

The proximal map :math:`\mathrm{prox}_{\lambda\mathrm{TV}}(v)=\arg\min_x \tfrac12\|x-v\|^2+
\lambda\,\mathrm{TV}(x)` is computed on the dual (Chambolle 2004): with a dual field
:math:`p` of shape ``(2, L, H, W)`` in the unit ball (pointwise :math:`\|p\|_2\le 1` for the
isotropic norm, :math:`\|p\|_\infty\le 1` for the anisotropic one),

.. math::

    x = v - \lambda\,\mathrm{div}\,p, \qquad \mathrm{div} = -\nabla^\top,

and the dual iterates with step :math:`\theta = 1/4`:

- isotropic (Chambolle's semi-implicit step)
  :math:`p \leftarrow \dfrac{p - (\theta/\lambda)\nabla x}{1 + (\theta/\lambda)\|\nabla x\|_2}`,
- anisotropic (Chambolle 2005 projected gradient)
  :math:`p \leftarrow \Pi_{[-1,1]}\bigl(p - (\theta/\lambda)\nabla x\bigr)`.

Every band is independent.  With Numba, all dual iterations and the result are one fused pass
over memory (:func:`recon.kernels.tv.chambolle`, bands in parallel); the NumPy path below
processes all bands at once by whole-array operations and is the reference the kernel is
tested against.  The dual can be kept between calls (:class:`TVProx`, or the ``dual=``
argument of :func:`prox_tv`): inside an outer solver the argument :math:`v` changes little
from one iteration to the next, so a warm-started dual needs only one or two inner
iterations.

With the step 1/4, a warm-started dual is best used with an even number of iterations per
call: an odd number leaves a period-2 oscillation of the dual when the input keeps changing
(measured in GAP-TV and FISTA: the outer iterations then stall at a relative change of ~1e-2).

The isotropic iteration is the one of :func:`skimage.restoration.denoise_tv_chambolle`
(``weight`` = :math:`\lambda`), so both give the same result; the tests check this.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from recon import kernels
from recon.errors import InputError

__all__ = ["gradient", "divergence", "tv_norm", "tv_norm_per_band", "prox_tv", "TVProx",
           "parallel_spans"]

# Dual step.  1/4 is the largest step for which the projected-gradient form is proven to
# converge in 2-D (||div||^2 <= 8, step < 2/8); Chambolle's semi-implicit form is used at the
# same step by skimage and converges in practice.
_STEP = 0.25


def _check_cube(x: np.ndarray, name: str = "x") -> np.ndarray:
    x = np.asarray(x)
    if x.ndim != 3:
        raise InputError(f"{name} must be a band-major (L, H, W) cube, got shape {x.shape}")
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float32)
    return x


def gradient(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    r"""Spatial forward differences of every band, Neumann boundary.

    Parameters
    ----------
    x : ndarray, shape (L, H, W)
    out : ndarray, shape (2, L, H, W), optional
        Written in place; its last row (component 0) and last column (component 1) are set to 0.

    Returns
    -------
    ndarray, shape (2, L, H, W)
        ``out[0]`` = :math:`f_{i+1,j}-f_{i,j}` (vertical), ``out[1]`` = :math:`f_{i,j+1}-f_{i,j}`.
    """
    x = _check_cube(x)
    if out is None:
        out = np.empty((2,) + x.shape, dtype=x.dtype)
    np.subtract(x[:, 1:, :], x[:, :-1, :], out=out[0, :, :-1, :])
    out[0, :, -1, :] = 0
    np.subtract(x[:, :, 1:], x[:, :, :-1], out=out[1, :, :, :-1])
    out[1, :, :, -1] = 0
    return out


def divergence(p: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    r"""Discrete divergence, the negative adjoint of :func:`gradient`: :math:`\mathrm{div}=-\nabla^\top`.

    Parameters
    ----------
    p : ndarray, shape (2, L, H, W)
    out : ndarray, shape (L, H, W), optional

    Returns
    -------
    ndarray, shape (L, H, W)
        :math:`(\mathrm{div}\,p)_{i,j} = p^0_{i,j}-p^0_{i-1,j} + p^1_{i,j}-p^1_{i,j-1}`, with
        :math:`p^0_{-1,j}=p^0_{H-1,j}=0` and :math:`p^1_{i,-1}=p^1_{i,W-1}=0`.
    """
    p = np.asarray(p)
    if p.ndim != 4 or p.shape[0] != 2:
        raise InputError(f"dual field must have shape (2, L, H, W), got {p.shape}")
    if out is None:
        out = np.empty(p.shape[1:], dtype=p.dtype)
    py, px = p[0], p[1]
    # Components past the Neumann boundary are zero by definition of the gradient, whatever the
    # array holds there, so they are left out explicitly.
    out[:, :-1, :] = py[:, :-1, :]
    out[:, -1, :] = 0
    out[:, 1:, :] -= py[:, :-1, :]
    out[:, :, :-1] += px[:, :, :-1]
    out[:, :, 1:] -= px[:, :, :-1]
    return out


def tv_norm_per_band(x: np.ndarray, isotropic: bool = True,
                     threads: int | None = None) -> np.ndarray:
    r"""Total variation of every band (paper Eq. 7 for ``isotropic=False``).

    Computed in row strips of a few tens of KiB (the cube seen as ``(L*H, W)`` rows; the
    vertical difference of the last row of a band is zero), spread over the thread pool: no
    cube-sized temporaries, and each strip stays in cache across its half-dozen passes.

    Parameters
    ----------
    x : ndarray, shape (L, H, W)
    isotropic : bool
        :math:`\sum\|\nabla x\|_2` if True, :math:`\sum\|\nabla x\|_1` if False.
    threads : int, optional
        Worker threads (default as :class:`TVProx`).

    Returns
    -------
    ndarray, shape (L,), float64
    """
    x = np.ascontiguousarray(_check_cube(x))
    n_bands, h, w = x.shape
    if kernels.usable(x):
        from recon.kernels import tv as ktv

        row_tv = np.empty((n_bands, h), dtype=np.float64)
        with kernels.threads(threads):
            ktv.tv_rows(x, bool(isotropic), row_tv)
        return row_tv.sum(axis=1)
    rows = x.reshape(n_bands * h, w)
    row_tv = np.empty(n_bands * h, dtype=np.float64)
    strip = max(1, _TV_STRIP_BYTES // max(1, w * x.itemsize))
    n_threads = _default_threads() if threads is None else max(1, int(threads))
    n_jobs = min(n_threads, -(-rows.shape[0] // strip))
    edges = np.linspace(0, rows.shape[0], n_jobs + 1).round().astype(int)
    spans = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]
    args = (rows, h, strip, bool(isotropic), row_tv)
    if len(spans) == 1:
        _tv_rows(*spans[0], *args)
    else:
        for job in [_pool(n_threads).submit(_tv_rows, a, b, *args) for a, b in spans]:
            job.result()
    return row_tv.reshape(n_bands, h).sum(axis=1)


# Bytes of one strip of rows in tv_norm: with its two scratch strips it stays in L2; measured
# at 645x501x25 (one thread): 15 ms against 67 ms for the former whole-cube passes (which
# allocated three cube-sized temporaries), 32 ms at 16 KiB strips.
_TV_STRIP_BYTES = 1 << 18


def _tv_rows(j0: int, j1: int, rows: np.ndarray, h: int, strip: int, isotropic: bool,
             row_tv: np.ndarray) -> None:
    r"""Per-row TV of the flat rows ``j0:j1`` of a band-major cube seen as ``(L*H, W)``."""
    n_rows, w = rows.shape
    dy = np.empty((strip, w), dtype=rows.dtype)
    dx = np.empty((strip, w), dtype=rows.dtype)
    dx[:, -1] = 0  # Neumann boundary: no difference past the last column
    for a in range(j0, j1, strip):
        b = min(j1, a + strip)
        n = b - a
        d, e = dy[:n], dx[:n]
        # Vertical differences reach one row past the strip; the flat row after the last row
        # of a band belongs to the next band, so those differences are zeroed.
        m = min(b, n_rows - 1) - a
        np.subtract(rows[a + 1:a + 1 + m], rows[a:a + m], out=d[:m])
        d[m:] = 0
        last = np.arange(a, b)
        d[(last + 1) % h == 0] = 0
        np.subtract(rows[a:b, 1:], rows[a:b, :-1], out=e[:, :-1])
        if isotropic:
            np.multiply(d, d, out=d)
            np.multiply(e, e, out=e)
            d += e
            np.sqrt(d, out=d)
        else:
            np.abs(d, out=d)
            np.abs(e, out=e)
            d += e
        row_tv[a:b] = d.sum(axis=1, dtype=np.float64)


def tv_norm(x: np.ndarray, isotropic: bool = True, threads: int | None = None) -> float:
    r"""Total variation of a band-major cube, summed over bands: :math:`\sum_l \mathrm{TV}(x_l)`.

    See :func:`tv_norm_per_band`.
    """
    return float(tv_norm_per_band(x, isotropic, threads).sum())


def _default_threads() -> int:
    return min(4, kernels.cores())


_POOL: ThreadPoolExecutor | None = None
_POOL_SIZE = 0
_POOL_LOCK = threading.Lock()


def _pool(n: int) -> ThreadPoolExecutor:
    """A process-wide thread pool (NumPy releases the GIL inside large ufuncs)."""
    global _POOL, _POOL_SIZE
    with _POOL_LOCK:
        if _POOL is None or _POOL_SIZE < n:
            if _POOL is not None:
                _POOL.shutdown(wait=False)
            _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="recon-tv")
            _POOL_SIZE = n
        return _POOL


def parallel_spans(fn, n: int, threads: int | None = None, min_span: int = 1 << 16) -> None:
    """Call ``fn(a, b)`` over contiguous spans covering ``range(n)``, on the thread pool.

    For elementwise NumPy work on large flat arrays (the GIL is released inside ufuncs).
    Spans are at least ``min_span`` long; with one span ``fn`` runs in the caller's thread.
    """
    n_threads = _default_threads() if threads is None else max(1, int(threads))
    k = max(1, min(n_threads, n // max(1, min_span)))
    edges = [n * i // k for i in range(k + 1)]
    if k == 1:
        fn(0, n)
        return
    for job in [_pool(n_threads).submit(fn, a, b) for a, b in zip(edges[:-1], edges[1:])]:
        job.result()


# Bands are processed in chunks of about this many bytes per array, so that the ~7 arrays a
# chunk touches stay in a core's cache across the dozen passes of one dual iteration (measured:
# 30 % faster than whole-cube passes at 256x256x28, before threading).
_CHUNK_BYTES = 1 << 19


# The fused gradient step (TVProx.gradient_prox) reads the masks and the measurement once per
# band: it pays while they stay in a core's L2 cache (2 MiB here) beside the band's rows, and
# loses where they do not.  Measured (two threads, 2 Chambolle iterations, in place): one
# view 256x256x28 (0.6 MB) 0.11 s against 0.12 s for 50 GAP-TV iterations; one view
# 645x501x25 (2.7 MB) 22.7 ms against 23.1 ms per step, even; 3 and 5 views 256x256x28
# (1.7, 2.9 MB) 7.2 ms against 6.7 and 6.3 ms; 5 views 645x501x25 (13 MB) 24 ms against 18.
_GATHER_BYTES = 1 << 20


class TVProx:
    r"""Proximal map of :math:`\lambda\,\mathrm{TV}` with a persistent (warm-startable) dual.

    Holds the dual field and all work arrays, so repeated calls allocate nothing.  Bands are
    independent, so they are processed in cache-sized chunks, spread over a thread pool.

    Parameters
    ----------
    shape : tuple of int
        ``(L, H, W)``.
    dtype : numpy dtype
        float32 (default) or float64.
    isotropic : bool
        Isotropic (default) or anisotropic TV.
    threads : int, optional
        Worker threads over band chunks (default: the number of CPUs, at most 4; 1 = serial).

    Attributes
    ----------
    dual : ndarray, shape (2, L, H, W)
        The current dual field :math:`p` (in the unit ball).  Zero after construction or
        :meth:`reset`.

    Examples
    --------
    >>> prox = TVProx(v.shape)
    >>> x = prox(v, 0.1, n_iter=10)             # cold start
    >>> x = prox(v2, 0.1, n_iter=2, warm=True)   # reuses the dual of the previous call
    """

    def __init__(self, shape, dtype=np.float32, isotropic: bool = True,
                 threads: int | None = None):
        shape = tuple(int(s) for s in shape)
        if len(shape) != 3 or min(shape) < 1:
            raise InputError(f"TVProx shape must be (L, H, W), got {shape}")
        self.shape = shape
        self.dtype = np.dtype(dtype)
        if self.dtype.kind != "f":
            raise InputError(f"TVProx dtype must be floating, got {self.dtype}")
        self.isotropic = bool(isotropic)
        self.threads = _default_threads() if threads is None else max(1, int(threads))
        self.dual = np.zeros((2,) + shape, dtype=self.dtype)
        # Work arrays of the NumPy path (five cubes), made on its first use: the kernel
        # needs none.
        self._work = None
        n_bands, band_bytes = shape[0], shape[1] * shape[2] * self.dtype.itemsize
        per_chunk = max(1, _CHUNK_BYTES // band_bytes)
        n_chunks = max(-(-n_bands // per_chunk), min(self.threads, n_bands))
        edges = np.linspace(0, n_bands, n_chunks + 1).round().astype(int)
        self._chunks = [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]

    def reset(self) -> None:
        """Set the dual to zero (the next call is a cold start)."""
        self.dual.fill(0)

    def __call__(self, v: np.ndarray, weight: float, n_iter: int = 10, warm: bool = True,
                 out: np.ndarray | None = None, out_scale=None) -> np.ndarray:
        r"""Return :math:`\mathrm{prox}_{\lambda\mathrm{TV}}(v)` after ``n_iter`` dual iterations.

        Parameters
        ----------
        v : ndarray, shape (L, H, W)
        weight : float
            :math:`\lambda \ge 0`.  ``0`` returns ``v`` unchanged (copied into ``out``).
        n_iter : int
            Dual iterations (``>= 0``; ``0`` just evaluates :math:`v-\lambda\,\mathrm{div}\,p`
            for the current dual).
        warm : bool
            Start from the stored dual (True) or from zero (False).
        out : ndarray, shape (L, H, W), optional
            Where to write the result; may be ``v`` itself.
        out_scale : array_like, shape (L,), optional
            A factor :math:`r_l` per band: the result is :math:`r_l x_l`, scaled as it is
            written (the same values as the prox followed by a pass that scales it).

        Returns
        -------
        ndarray, shape (L, H, W)
            :math:`x = v - \lambda\,\mathrm{div}\,p` for the final dual :math:`p`.
        """
        v = np.asarray(v)
        if v.shape != self.shape:
            raise InputError(f"TVProx: input shape {v.shape} != {self.shape}")
        weight, n_iter = self._check(weight, n_iter)
        if out is None:
            out = np.empty(self.shape, dtype=self.dtype)
        r = self._out_scale(out_scale)
        if weight == 0.0:
            np.copyto(out, v)
            if r.size:
                out *= r[:, None, None]
            return out
        if not warm:
            self.reset()
        if v.dtype != self.dtype:
            v = v.astype(self.dtype)
        if kernels.usable(v, out, self.dual) and out.flags.c_contiguous \
                and self.dual.flags.c_contiguous:
            from recon.kernels import tv as ktv

            self._kernel(np.ascontiguousarray(v), weight, n_iter, out,
                         ktv.no_gather(self.dtype), r)
            return out
        if self._work is None:
            shape = self.shape
            self._work = (np.zeros((2,) + shape, dtype=self.dtype),
                          *(np.empty(shape, dtype=self.dtype) for _ in range(3)))
        if len(self._chunks) == 1 or self.threads == 1:
            for sl in self._chunks:
                self._run(sl, v, weight, n_iter, out)
        else:
            jobs = [_pool(self.threads).submit(self._run, sl, v, weight, n_iter, out)
                    for sl in self._chunks]
            for job in jobs:
                job.result()
        if r.size:
            out *= r[:, None, None]
        return out

    def _out_scale(self, out_scale) -> np.ndarray:
        """``out_scale`` as a float array of one factor per band, or an empty one."""
        if out_scale is None:
            return np.zeros(0, self.dtype)
        r = np.ascontiguousarray(out_scale, dtype=self.dtype).reshape(-1)
        if r.shape != self.shape[:1] or not np.all(np.isfinite(r)):
            raise InputError(f"out_scale must hold one finite factor per band "
                             f"({self.shape[0]}), got shape {np.shape(out_scale)}")
        return r

    def gradient_prox(self, op, y: np.ndarray, base: np.ndarray, weight: float,
                      n_iter: int = 10, warm: bool = True, scale: float = 1.0,
                      out: np.ndarray | None = None) -> np.ndarray:
        r"""A solver's gradient step and this prox in one:
        :math:`\mathrm{prox}_{\lambda\mathrm{TV}}\bigl(b + s\,H^\top y\bigr)`.

        Parameters
        ----------
        op : LinearOperator
            :math:`H`, with ``ishape`` the shape of this prox.
        y : ndarray, shape ``op.oshape``
        base : ndarray, shape (L, H, W)
            :math:`b`; read only (unless it is ``out``).
        weight, n_iter, warm
            As for :meth:`__call__`.
        scale : float
            :math:`s`.
        out : ndarray, shape (L, H, W), optional
            Where to write the result; may be ``base`` itself.

        Returns
        -------
        ndarray, shape (L, H, W)

        Notes
        -----
        Where the operator offers the rows of its adjoint as a gather
        (:meth:`CassiOperator.adjoint_gather <recon.operators.cassi.CassiOperator.adjoint_gather>`:
        CASSI operators whose views are all permutations), small enough to stay in cache
        while every band reads it (``_GATHER_BYTES``), and the kernels run (float32), the
        step is made row by row inside the Chambolle pass (:func:`recon.kernels.tv.chambolle`):
        one read and one write of the cube fewer than the two calls.  Otherwise, and as the
        reference the fused pass is tested against, it is ``op.adjoint_add(y, base, scale,
        out)`` followed by ``self(out, weight, n_iter, warm, out)``.
        """
        base = np.asarray(base)
        if base.shape != self.shape:
            raise InputError(f"TVProx: input shape {base.shape} != {self.shape}")
        weight, n_iter = self._check(weight, n_iter)
        gather = getattr(op, "adjoint_gather", None)
        if out is None:
            out = np.empty(self.shape, dtype=self.dtype)
        fused = (gather is not None and weight > 0.0 and tuple(op.ishape) == self.shape
                 and kernels.usable(base, out, self.dual) and base.flags.c_contiguous
                 and out.flags.c_contiguous and self.dual.flags.c_contiguous)
        args = gather(y, scale, self.dtype, max_bytes=_GATHER_BYTES) if fused else None
        if args is None:
            op.adjoint_add(y, base, scale, out=out)
            return self(out, weight, n_iter, warm, out=out)
        if not warm:
            self.reset()
        self._kernel(base, weight, n_iter, out, args)
        return out

    @staticmethod
    def _check(weight, n_iter) -> tuple[float, int]:
        weight = float(weight)
        if not math.isfinite(weight) or weight < 0:
            raise InputError(f"TV weight must be finite and >= 0, got {weight}")
        n_iter = int(n_iter)
        if n_iter < 0:
            raise InputError(f"n_iter must be >= 0, got {n_iter}")
        return weight, n_iter

    def _kernel(self, v, weight, n_iter, out, gather, oscale=None) -> None:
        """The fused Chambolle pass (:func:`recon.kernels.tv.chambolle`); ``gather`` is its
        ``z, masks, a, c0, c1, sub`` (no views: a plain prox), ``oscale`` its factor per band
        on the result (None: none)."""
        from recon.kernels import tv as ktv

        t = self.dtype.type
        if oscale is None:
            oscale = np.zeros(0, self.dtype)
        with kernels.threads(self.threads):
            ktv.chambolle(v, self.dual, t(weight), t(_STEP / weight), t(_STEP), n_iter,
                          self.isotropic, out, *gather, oscale)

    def _run(self, sl: slice, v, weight, n_iter, out) -> None:
        """All dual iterations for the bands ``sl`` (bands are independent)."""
        g, y, n, sv = self._work
        p, g, y, n, sv = self.dual[:, sl], g[:, sl], y[sl], n[sl], sv[sl]
        v, out = v[sl], out[sl]
        py, px = p[0], p[1]
        # The dual components past the Neumann boundary must be zero (the gradient is zero
        # there, so the iteration keeps them at zero once they are).
        py[:, -1, :] = 0
        px[:, :, -1] = 0
        s = _STEP / weight
        if n_iter:
            # Iterate on y = s * x = s*v - step * div p, so that grad y = s * grad x is the
            # dual step itself: no separate scaling of the gradient.
            np.multiply(v, s, out=sv)
        w = y.shape[-1]
        gy, gx = g[0], g[1]
        yf, gyf, gxf = y.reshape(-1), gy.reshape(-1), gx.reshape(-1)
        for _ in range(n_iter):
            _div(p, y)
            y *= -_STEP
            y += sv
            # Differences on the flattened chunk (contiguous passes, ~2x faster than column
            # slices); the entries that straddle a row or band edge are the Neumann ones and
            # are zeroed after.
            np.subtract(yf[w:], yf[:-w], out=gyf[:-w])
            gy[:, -1, :] = 0
            np.subtract(yf[1:], yf[:-1], out=gxf[:-1])
            gx[:, :, -1] = 0
            p -= g
            if self.isotropic:
                # (p - g) / (1 + |g|); the sum of squares through einsum needs no temporary.
                np.einsum("i...,i...->...", g, g, out=n)
                np.sqrt(n, out=n)
                n += 1
                np.divide(py, n, out=py)
                np.divide(px, n, out=px)
            else:
                np.minimum(p, 1, out=p)
                np.maximum(p, -1, out=p)
        # x = v - weight * div p, written straight into `out` (which may be `v`).
        _div(p, y)
        y *= weight
        np.subtract(v, y, out=out)


def _div(p, out):
    r"""``out = div p`` for a chunk whose dual is zero past the Neumann boundary.

    Computed on the flattened chunk: the terms that wrap to the previous row or band read
    :math:`p^0` on a last row or :math:`p^1` on a last column, which are zero.
    """
    py, px = p[0], p[1]
    w = out.shape[-1]
    np.add(py, px, out=out)
    of, pyf, pxf = out.reshape(-1), py.reshape(-1), px.reshape(-1)
    of[w:] -= pyf[:-w]
    of[1:] -= pxf[:-1]
    return out


def prox_tv(v: np.ndarray, weight: float, n_iter: int = 10, isotropic: bool = True,
            dual: np.ndarray | None = None, out: np.ndarray | None = None,
            threads: int | None = None) -> np.ndarray:
    r"""Proximal map of :math:`\lambda\,\mathrm{TV}` (per band, spatial), by Chambolle's dual method.

    .. math::

        \mathrm{prox}_{\lambda\mathrm{TV}}(v) = \arg\min_x \tfrac12\|x-v\|_2^2
        + \lambda \sum_l \mathrm{TV}(x_l)

    Parameters
    ----------
    v : ndarray, shape (L, H, W)
        Band-major cube (float32 or float64; other types are converted to float32).
    weight : float
        :math:`\lambda \ge 0` (the ``weight`` of :func:`skimage.restoration.denoise_tv_chambolle`).
    n_iter : int
        Dual iterations (10 is the paper's setting for a cold start).
    isotropic : bool
        Isotropic (default) or anisotropic (paper Eq. 7) TV.
    dual : ndarray, shape (2, L, H, W), optional
        Warm start: the dual field to start from; it is updated in place, so that the next
        call can continue from it.  Zero (cold start) if omitted.
    out : ndarray, shape (L, H, W), optional
        Where to write the result; may be ``v``.
    threads : int, optional
        See :class:`TVProx`.

    Returns
    -------
    ndarray, shape (L, H, W)
    """
    v = _check_cube(v, "v")
    prox = TVProx(v.shape, v.dtype, isotropic, threads)
    if dual is not None:
        if dual.shape != prox.dual.shape or dual.dtype != v.dtype:
            raise InputError(f"dual must be {prox.dual.shape} {v.dtype}, got "
                             f"{dual.shape} {dual.dtype}")
        prox.dual = dual
    return prox(v, weight, n_iter, warm=True, out=out)
