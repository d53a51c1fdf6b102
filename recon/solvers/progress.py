"""A tqdm progress bar as a solver callback (for the command line).

Shows the iteration, the objective (when the solver reports one), the relative change and,
when a ground truth is given, the PSNR of the current iterate (:func:`recon.metrics.psnr`
convention: both cubes divided by the truth's maximum, peak 1).
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError

__all__ = ["ProgressCallback"]


class ProgressCallback:
    """Solver callback that drives a ``tqdm`` bar; use as a context manager (or call close()).

    Parameters
    ----------
    total : int
        The number of iterations (the bar's length).
    truth : ndarray, shape (L, H, W), optional
        Band-major ground truth; adds the PSNR of every iterate (costs one pass over the cube).
    desc : str
        The bar's label.
    disable : bool
        No output (e.g. ``--quiet``); the callback still records ``history``.
    **tqdm_kw
        Passed to :class:`tqdm.tqdm` (``file=``, ``leave=``, ...).

    Attributes
    ----------
    history : list of dict
        One entry per iteration: ``iteration``, ``objective``, ``rel_change``, ``psnr``.
    """

    def __init__(self, total: int, truth: np.ndarray | None = None, desc: str = "reconstruct",
                 disable: bool = False, **tqdm_kw):
        from tqdm.auto import tqdm

        if truth is not None:
            truth = np.asarray(truth)
            if truth.ndim != 3:
                raise InputError(f"truth must be a band-major (L, H, W) cube, got {truth.shape}")
            peak = float(np.max(truth))
            if not np.isfinite(peak) or peak <= 0:
                raise InputError("truth must have a positive, finite maximum")
            self._truth, self._peak = truth.astype(np.float32, copy=False), peak
        else:
            self._truth = None
        self.history: list[dict] = []
        self.bar = tqdm(total=int(total), desc=desc, disable=disable, unit="it", **tqdm_kw)

    def psnr(self, x: np.ndarray) -> float:
        """PSNR of ``x`` against the truth, peak = max(truth)."""
        if x.shape != self._truth.shape:
            raise InputError(f"iterate shape {x.shape} != truth shape {self._truth.shape}")
        d = (x - self._truth).astype(np.float64, copy=False)
        mse = float(np.vdot(d, d)) / d.size
        return float("inf") if mse == 0 else 10.0 * np.log10(self._peak**2 / mse)

    def __call__(self, iteration: int, x: np.ndarray, info: dict) -> None:
        entry = {"iteration": int(iteration), "objective": info.get("objective"),
                 "rel_change": info.get("rel_change"), "psnr": None}
        post = {}
        if entry["objective"] is not None:
            post["obj"] = f"{entry['objective']:.4g}"
        if entry["rel_change"] is not None:
            post["dx"] = f"{entry['rel_change']:.2e}"
        if self._truth is not None:
            entry["psnr"] = self.psnr(x)
            post["psnr"] = f"{entry['psnr']:.2f} dB"
        self.history.append(entry)
        self.bar.set_postfix(post, refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
