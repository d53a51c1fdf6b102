"""A solver callback that reports progress (for the command line).

Shows the iteration, the objective (when the solver reports one), the relative change and,
when a ground truth is given, the PSNR of the current iterate (:func:`recon.metrics.psnr`
convention: both cubes divided by the truth's maximum, peak 1): a ``tqdm`` bar on a terminal,
one line when the solve ends elsewhere (:mod:`recon.progress`).
"""

from __future__ import annotations

import sys

import numpy as np

from recon.errors import InputError
from recon.progress import Silent, StepLine, is_terminal

__all__ = ["ProgressCallback"]


class ProgressCallback:
    """Solver callback that drives a progress report (:mod:`recon.progress`); use as a context
    manager (or call close()).

    Parameters
    ----------
    total : int
        The number of iterations (the bar's length; a solver's stopping rule may end sooner).
    truth : ndarray, shape (L, H, W), optional
        Band-major ground truth; adds the PSNR of every iterate (costs one pass over the cube).
    desc : str
        The bar's label.
    disable : bool
        No output (e.g. ``--quiet``); the callback still records ``history``.
    file : stream, optional
        Where to write (stderr by default); a bar on a terminal, one line at the end elsewhere.
    **tqdm_kw
        Passed to :class:`tqdm.tqdm` on a terminal (``leave=``, ...).

    Attributes
    ----------
    history : list of dict
        One entry per iteration: ``iteration``, ``objective``, ``rel_change``, ``psnr``.
    """

    def __init__(self, total: int, truth: np.ndarray | None = None, desc: str = "reconstruct",
                 disable: bool = False, file=None, **tqdm_kw):
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
        if disable:
            self.bar = Silent(total=int(total))
        elif is_terminal(sys.stderr if file is None else file):
            from tqdm.auto import tqdm

            self.bar = tqdm(total=int(total), desc=desc, unit="it", file=file, **tqdm_kw)
        else:
            self.bar = StepLine(total=int(total), desc=desc, unit="it", file=file)

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
