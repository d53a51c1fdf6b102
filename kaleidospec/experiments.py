"""The paper experiments' shared helpers (``tools/exp_*.py``): lists, labels, scores, JSON,
figures and sRGB panels.

The experiments are scripts; what more than one of them needs lives here, public.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

__all__ = ["CAVE_DEV_SCENES", "cave_folder", "parse_list", "scene_label", "finite", "metrics_of", "write_json", "save_figure",
           "srgb", "srgb_peak", "fmt", "get_design", "matplotlib_agg", "stop_rule"]


#: The CAVE scenes for development, tuning and the docs' tables; the rest of the database is
#: held out for independent evaluation.
CAVE_DEV_SCENES = ("cloth", "thread_spools", "pompoms", "chart_and_stuffed_toy",
                   "egyptian_statue", "superballs", "fake_and_real_sushi", "paints")


def cave_folder(name: str) -> Path | None:
    """The CAVE folder ``$KALEIDOSPEC_DATA/cave/<name>``, or None when the variable is unset or
    the folder absent (the data are never part of the repository)."""
    root = os.environ.get("KALEIDOSPEC_DATA")
    if not root:
        return None
    folder = Path(root) / "cave" / name
    return folder if folder.is_dir() else None


def parse_list(text: str, kind=str) -> list:
    """``"a,b,c"`` → ``[a, b, c]`` (empty items dropped)."""
    return [kind(t.strip()) for t in text.split(",") if t.strip()]


def scene_label(scene: str) -> str:
    """A short name for tables: the file's stem for a cube path, else the scene name."""
    p = Path(scene)
    return p.stem if (p.suffix or p.exists()) else scene


def finite(x):
    """JSON-safe float: ``inf`` (identical cubes) and NaN become None."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def metrics_of(cube, truth, wavelengths) -> dict:
    """PSNR (global, paper), SSIM, SAM, CIEDE2000 of ``cube`` against ``truth`` (JSON-ready)."""
    from recon.metrics import all_metrics

    m = all_metrics(cube, truth, wavelengths)
    return {k: finite(v) for k, v in m.items()}


def write_json(path: Path, obj) -> None:
    """``obj`` as sorted, indented JSON (NumPy values, tuples, sets and paths made plain),
    written atomically."""
    from recon.io.atomic import write_text

    write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (tuple, set)):
        return list(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def save_figure(fig, path: Path) -> None:
    """``fig.savefig`` to a temporary file next to ``path``, then rename."""
    import matplotlib.pyplot as plt

    from recon.io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)


def srgb(cube, wavelengths, peak):
    """Display sRGB of a cube with a fixed exposure ``peak`` (so panels compare)."""
    from recon.metrics import cube_to_srgb

    return cube_to_srgb(np.clip(cube, 0, None), wavelengths, peak=peak)


def srgb_peak(truth, wavelengths) -> float:
    """The exposure used for every panel of a scene: the truth's 99th-percentile luminance."""
    from recon.metrics import cube_to_xyz

    return float(np.percentile(cube_to_xyz(truth, wavelengths)[..., 1], 99.0))


def fmt(x, spec=".2f") -> str:
    """A table cell: ``x`` formatted, or a dash for None."""
    return "—" if x is None else format(x, spec)


def get_design(name: str, overrides: list[str] | None):
    """The preset ``name`` with ``FIELD=VALUE`` overrides (``--set``)."""
    from kaleidospec.instrument import get_design as preset, parse_overrides

    return preset(name, parse_overrides(overrides))


def matplotlib_agg():
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def stop_rule(iters: int, tol, short: bool = False) -> str:
    """The stopping rule in words."""
    if not tol:
        return f"{iters} it" if short else f"{iters} iterations"
    return (f"≤{iters} it, tol {tol:g}" if short else
            f"until a relative change < {tol:g} (at most {iters} iterations)")
