r"""Dynamic scenes: radiance cubes that change from frame to frame.

Every animated scene is an :class:`Animation`: ``len(anim)`` frames, ``anim.frame(i)`` the
radiance cube (H, W, L) float32 that frame *i* integrates, ``anim.describe()`` its parameters
as JSON.  Time is in seconds; frame *i* opens its shutter at :math:`t_i = i / \mathrm{fps}` and
keeps it open for the exposure :math:`T_e` (``exposure_ms``), which cannot exceed the frame
period :math:`1/\mathrm{fps}`.

Motion within the exposure.  The sensor integrates the radiance over the exposure,

.. math:: f_i = \frac{1}{T_e} \int_{t_i}^{t_i + T_e} f(t)\, dt
          \approx \frac{1}{S} \sum_{s=0}^{S-1} f\big(t_i + \tfrac{s + 1/2}{S} T_e\big),

the midpoint rule with ``subframes`` = S sub-frames.  S = 1 (the default) is the scene frozen at
mid-exposure (motion blur ignored); S > 1 averages S sub-frame cubes (motion blur), at S times
the cost of building a frame.

Scenes:

- :class:`RotatingColorwheel` — the spectral colour wheel of :mod:`scenes.colorwheel` rotating
  at ``speed_deg_s`` (counter-clockwise for positive speeds): angle
  :math:`\theta(t) = \theta_0 + \omega t`.  :meth:`RotatingColorwheel.sector_masks` gives the
  pixels that lie inside each sector during the whole exposure (for per-sector colour metrics).
- :class:`MovingObject` — a disc with a ColorChecker reflectance moving at a constant velocity
  (``velocity_px_s``, wrapping around the frame) over a static background scene.
- :class:`CubeSequence` — any scene from a folder of cube files, one file per frame in natural
  sort order (``f2`` before ``f10``); every file is checked (readable, same shape and bands,
  finite, non-negative) before the first frame is built.

:func:`get_animation` builds one by name (``colorwheel``, ``moving_object``) or folder path.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from recon.errors import InputError
from scenes._common import check_shape, coverage, supersample_grid, wavelengths_or_default

__all__ = ["Animation", "RotatingColorwheel", "MovingObject", "CubeSequence", "get_animation",
           "list_animations", "CUBE_SUFFIXES"]

#: File suffixes read as one frame each from a folder (a sub-folder is a CAVE PNG stack).
CUBE_SUFFIXES = (".exr", ".npz", ".npy", ".mat")


def _positive(name: str, value, *, integer: bool = False, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise InputError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    if integer:
        if v != int(v):
            raise InputError(f"{name} must be an integer, got {value!r}")
        return int(v)
    return v


class Animation:
    """A sequence of radiance cubes with a frame clock.

    Parameters
    ----------
    n_frames : int
        Number of frames (≥ 1).
    fps : float
        Frame rate (frames per second).
    exposure_ms : float
        Exposure of each frame, 0 < exposure ≤ 1000 / fps.
    subframes : int
        Midpoint-rule sub-frames per exposure (1: the scene at mid-exposure).
    """

    kind = "animation"

    def __init__(self, n_frames: int, fps: float = 10.0, exposure_ms: float = 100.0,
                 subframes: int = 1):
        self.n_frames = _positive("frames", n_frames, integer=True)
        self.fps = _positive("fps", fps)
        self.exposure_ms = _positive("exposure_ms", exposure_ms)
        self.subframes = _positive("subframes", subframes, integer=True)
        period_ms = 1000.0 / self.fps
        if self.exposure_ms > period_ms * (1 + 1e-9):
            raise InputError(f"exposure {self.exposure_ms:g} ms is longer than the frame period "
                             f"{period_ms:g} ms at {self.fps:g} fps")
        if self.subframes > 64:
            raise InputError(f"subframes must be at most 64, got {self.subframes}")

    def __len__(self) -> int:
        return self.n_frames

    def _check_index(self, i) -> int:
        if isinstance(i, bool) or int(i) != i or not 0 <= int(i) < self.n_frames:
            raise InputError(f"frame {i!r} is outside 0..{self.n_frames - 1}")
        return int(i)

    def start_s(self, i: int) -> float:
        """Time (s) the shutter of frame ``i`` opens."""
        return self._check_index(i) / self.fps

    def sample_times(self, i: int) -> np.ndarray:
        """The S midpoint-rule times (s) within frame ``i``'s exposure."""
        t0 = self.start_s(i)
        te = self.exposure_ms * 1e-3
        return t0 + (np.arange(self.subframes) + 0.5) / self.subframes * te

    def cube_at(self, t: float) -> np.ndarray:
        """The instantaneous radiance cube at time ``t`` (s); subclasses implement it."""
        raise NotImplementedError

    def frame(self, i: int) -> np.ndarray:
        """Radiance (H, W, L) float32 integrated over frame ``i``'s exposure (mean over S)."""
        ts = self.sample_times(i)
        acc = self.cube_at(float(ts[0])).astype(np.float32, copy=True)
        for t in ts[1:]:
            acc += self.cube_at(float(t))
        if ts.size > 1:
            acc *= np.float32(1.0 / ts.size)
        return acc

    def describe(self) -> dict:
        """JSON-ready parameters (for sidecars and resume checks)."""
        return {"kind": self.kind, "frames": self.n_frames, "fps": self.fps,
                "exposure_ms": self.exposure_ms, "subframes": self.subframes}


class RotatingColorwheel(Animation):
    r"""The spectral colour wheel rotating at ``speed_deg_s``.

    The wheel angle is :math:`\theta(t) = \theta_0 + \omega t` (degrees, counter-clockwise
    with y up), rendered by :func:`scenes.colorwheel.colorwheel`.

    Parameters
    ----------
    shape : (H, W)
    wavelengths : array (L,), optional
    n_frames, fps, exposure_ms, subframes
        See :class:`Animation`.
    speed_deg_s : float
        Angular speed ω (deg/s); 36 deg/s turns the wheel once in 10 s.
    angle0_deg : float
        θ₀, the angle at t = 0.
    **wheel
        ``sectors``, ``illuminant``, ``radius``, ``hub``, ``background_reflectance``, ``aa``
        of :func:`scenes.colorwheel.colorwheel`.
    """

    kind = "colorwheel"

    def __init__(self, shape=(256, 256), wavelengths=None, *, n_frames: int = 10,
                 fps: float = 10.0, exposure_ms: float = 100.0, subframes: int = 1,
                 speed_deg_s: float = 36.0, angle0_deg: float = 0.0, **wheel):
        import inspect

        from scenes.colorwheel import colorwheel

        super().__init__(n_frames, fps, exposure_ms, subframes)
        self.shape = check_shape(shape)
        self.wavelengths = wavelengths_or_default(wavelengths)
        for name, v in (("speed_deg_s", speed_deg_s), ("angle0_deg", angle0_deg)):
            try:
                ok = math.isfinite(float(v))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise InputError(f"{name} must be a finite number, got {v!r}")
        self.speed_deg_s = float(speed_deg_s)
        self.angle0_deg = float(angle0_deg)
        allowed = {p for p, v in inspect.signature(colorwheel).parameters.items()
                   if v.kind == v.KEYWORD_ONLY} - {"angle_deg"}
        unknown = sorted(set(wheel) - allowed)
        if unknown:
            raise InputError(f"colour wheel has no parameter(s) {', '.join(unknown)}; it takes "
                             f"{', '.join(sorted(allowed))}")
        self.wheel = dict(wheel)
        self.sectors = int(self.wheel.get("sectors", 6))
        # Build a small wheel now so that bad wheel parameters fail before any work starts
        # (their checks do not depend on the size; a full frame at twice a `paper` view is
        # seconds of a video's start).
        self._colorwheel = colorwheel
        colorwheel((8, 8), self.wavelengths, angle_deg=self.angle_deg(0.0), **self.wheel)

    def angle_deg(self, t: float) -> float:
        """θ(t) in degrees."""
        return self.angle0_deg + self.speed_deg_s * float(t)

    def cube_at(self, t: float) -> np.ndarray:
        return self._colorwheel(self.shape, self.wavelengths, angle_deg=self.angle_deg(t),
                                **self.wheel)

    def sector_masks(self, i: int, margin_px: float = 1.5, *, grid_shape=None,
                     offset=(0.0, 0.0)) -> np.ndarray:
        r"""Pixels inside each sector for the whole exposure of frame ``i``: bool (N, h, w).

        A pixel counts for sector *k* when its centre lies in the sector at both ends of the
        exposure (the sector is swept through the angles between, so it is inside throughout),
        at least ``margin_px`` from the sector's straight edges, the rim and the hub: edge
        pixels mix two colours, and the reconstruction's resolution is limited there.

        ``grid_shape`` (h, w) and ``offset`` (oy, ox) describe another pixel grid whose pixel
        (y, x) sits at the scene's (y + oy, x + ox) (a reconstruction grid, see
        :func:`kaleidospec.models.grid_offset`); by default the scene's own grid.
        """
        h, w = self.shape if grid_shape is None else (int(grid_shape[0]), int(grid_shape[1]))
        oy, ox = (float(o) for o in offset)
        i = self._check_index(i)
        t0 = i / self.fps
        t1 = t0 + self.exposure_ms * 1e-3
        n = self.sectors
        masks = np.zeros((n, h, w), dtype=bool)
        if abs(self.angle_deg(t1) - self.angle_deg(t0)) >= 360.0 / n:
            return masks  # every pixel sees more than one sector during the exposure
        radius = float(self.wheel.get("radius", 0.9))
        hub = float(self.wheel.get("hub", 0.15))
        y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
        y += oy
        x += ox
        cy, cx = self.shape[0] / 2.0, self.shape[1] / 2.0
        rad = 0.5 * min(self.shape) * radius
        r = np.hypot(y - cy, x - cx)
        ring = (r < rad - margin_px) & (r > hub * rad + margin_px)
        theta = np.degrees(np.arctan2(cy - y, x - cx))  # as scenes.colorwheel.sector_index
        # Angular half-width (degrees) of the margin at radius r.
        dtheta = np.degrees(margin_px / np.maximum(r, 1e-9))

        def label(ang):
            return np.floor(((theta - ang) % 360.0) / (360.0 / n)).astype(np.int64) % n

        masks[:] = True
        for ang in (self.angle_deg(t0), self.angle_deg(t1)):
            lab = label(ang)
            inside = ring & (lab == label(ang + dtheta)) & (lab == label(ang - dtheta))
            masks &= inside[None] & (lab[None] == np.arange(n)[:, None, None])
        return masks

    def describe(self) -> dict:
        d = super().describe()
        d.update(shape=list(self.shape), speed_deg_s=self.speed_deg_s,
                 angle0_deg=self.angle0_deg, wheel=dict(self.wheel), sectors=self.sectors)
        return d


class MovingObject(Animation):
    r"""A disc moving at constant velocity over a static background.

    The disc (radius ``radius_px``, reflectance of ColorChecker patch ``patch`` under
    ``illuminant``) is centred at :math:`c(t) = c_0 + v t`, wrapped around the frame (a torus,
    so it never leaves), anti-aliased with ``aa``² sub-samples per pixel; it covers the
    background scene (any built-in scene of :func:`scenes.registry.get_scene`).

    Parameters
    ----------
    shape, wavelengths, n_frames, fps, exposure_ms, subframes
        See :class:`RotatingColorwheel`.
    velocity_px_s : (vx, vy)
        Pixels per second, x to the right, y down.
    start_px : (x0, y0), optional
        Centre at t = 0 (the frame centre by default).
    radius_px : float, optional
        Disc radius (min(H, W)/8 by default).
    patch : int
        ColorChecker patch index 0..23 (14, red, by default).
    background : str
        Background scene name (``natural`` by default).
    background_params : dict, optional
        Its parameters.
    """

    kind = "moving_object"

    def __init__(self, shape=(256, 256), wavelengths=None, *, n_frames: int = 10,
                 fps: float = 10.0, exposure_ms: float = 100.0, subframes: int = 1,
                 velocity_px_s=(40.0, 20.0), start_px=None, radius_px: float | None = None,
                 patch: int = 14, illuminant: str = "D65", background: str = "natural",
                 background_params: dict | None = None, aa: int = 4):
        from scenes.registry import get_scene
        from scenes.spectra import colorchecker_reflectances, illuminant as _illuminant

        super().__init__(n_frames, fps, exposure_ms, subframes)
        self.shape = h, w = check_shape(shape)
        self.wavelengths = wavelengths_or_default(wavelengths)
        try:
            self.velocity = tuple(float(v) for v in velocity_px_s)
            self.start = ((w / 2.0, h / 2.0) if start_px is None
                          else tuple(float(v) for v in start_px))
        except (TypeError, ValueError):
            raise InputError("velocity_px_s and start_px must be pairs of numbers") from None
        if len(self.velocity) != 2 or len(self.start) != 2 or not all(
                math.isfinite(v) for v in self.velocity + self.start):
            raise InputError("velocity_px_s and start_px must be two finite numbers each")
        self.radius = min(h, w) / 8.0 if radius_px is None else _positive("radius_px", radius_px)
        if not isinstance(patch, (int, np.integer)) or not 0 <= int(patch) < 24:
            raise InputError(f"patch must be a ColorChecker patch 0..23, got {patch!r}")
        self.patch = int(patch)
        self.aa = _positive("aa", aa, integer=True)
        if self.aa > 16:
            raise InputError(f"aa must be at most 16, got {aa}")
        self.background_name = str(background)
        self.background_params = dict(background_params or {})
        self.illuminant = str(illuminant)
        self.background, _ = get_scene(self.background_name, self.shape, self.wavelengths,
                                       **self.background_params)
        self.spectrum = (colorchecker_reflectances(self.wavelengths)[self.patch]
                         * _illuminant(self.illuminant, self.wavelengths)).astype(np.float32)
        self._grid = supersample_grid(h, w, self.aa)

    def centre_px(self, t: float) -> tuple[float, float]:
        """Disc centre (x, y) at time ``t`` (wrapped into the frame)."""
        h, w = self.shape
        return ((self.start[0] + self.velocity[0] * t) % w,
                (self.start[1] + self.velocity[1] * t) % h)

    def coverage(self, t: float) -> np.ndarray:
        """Fraction (H, W) float32 of each pixel covered by the disc at time ``t``."""
        h, w = self.shape
        cx, cy = self.centre_px(t)
        y, x = self._grid
        # Wrapped distance: the disc re-enters on the opposite side.
        dx = np.abs(x - cx)
        dx = np.minimum(dx, w - dx)
        dy = np.abs(y - cy)
        dy = np.minimum(dy, h - dy)
        return coverage(dx * dx + dy * dy <= self.radius ** 2, h, w, self.aa)

    def cube_at(self, t: float) -> np.ndarray:
        a = self.coverage(t)[:, :, None]
        return (self.background * (1.0 - a) + a * self.spectrum[None, None, :]).astype(np.float32)

    def describe(self) -> dict:
        d = super().describe()
        d.update(shape=list(self.shape), velocity_px_s=list(self.velocity),
                 start_px=list(self.start), radius_px=self.radius, patch=self.patch,
                 illuminant=self.illuminant, background=self.background_name,
                 background_params=self.background_params)
        return d


def _natural_key(p: Path):
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)]


class CubeSequence(Animation):
    """A scene from a folder of cube files, one per frame, in natural sort order.

    Files with the suffixes :data:`CUBE_SUFFIXES` and sub-folders (CAVE PNG stacks) are frames;
    hidden entries (``.name``) are ignored.  The constructor reads every file once and checks
    that it is a finite, non-negative (H, W, L) cube with wavelengths and that all share one
    shape and one band grid; then each :meth:`frame` reads its file again, resamples it onto
    ``wavelengths`` and resizes it to ``shape`` (:func:`scenes.registry.load_cube_scene`).
    ``n_frames`` (optional) takes the first frames only.  A file carries no time, so the frames
    are spaced by 1/fps and ``subframes`` must be 1.

    Raises
    ------
    InputError
        Not a folder, no cube files, an unreadable file, different shapes or band grids, a
        non-finite or negative cube, ``n_frames`` above the number of files.
    """

    kind = "cubes"

    def __init__(self, folder, shape=None, wavelengths=None, *, n_frames: int | None = None,
                 fps: float = 10.0, exposure_ms: float = 100.0, subframes: int = 1,
                 file_wavelengths=None, key: str | None = None):
        from recon.io.cubes import read_cube

        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise InputError(f"{self.folder}: not a folder of cube files")
        files = sorted((p for p in self.folder.iterdir() if not p.name.startswith(".")
                        and (p.is_dir() or p.suffix.lower() in CUBE_SUFFIXES)),
                       key=_natural_key)
        if not files:
            raise InputError(f"{self.folder}: no cube files ({', '.join(CUBE_SUFFIXES)} or CAVE "
                             "folders)")
        if n_frames is None:
            n_frames = len(files)
        if int(n_frames) > len(files):
            raise InputError(f"{self.folder}: {n_frames} frames asked for, the folder has "
                             f"{len(files)} cube files")
        if int(subframes) != 1:
            raise InputError("a folder of cubes has one cube per frame: subframes must be 1")
        super().__init__(n_frames, fps, exposure_ms, 1)
        self.files = files[:self.n_frames]
        self.wavelengths = wavelengths_or_default(wavelengths)
        self.file_wavelengths = file_wavelengths
        self.key = key
        ref_shape = ref_wl = None
        for p in self.files:
            cube, wl = read_cube(p, key=key, wavelengths=file_wavelengths)
            cube = np.asarray(cube)
            if cube.ndim != 3:
                raise InputError(f"{p}: a cube must be (H, W, L), got shape {cube.shape}")
            if wl is None:
                raise InputError(f"{p}: the file does not give wavelengths; pass file_wavelengths")
            if not np.all(np.isfinite(cube)):
                raise InputError(f"{p}: the cube holds non-finite values (NaN or Inf)")
            if np.any(cube < 0):
                raise InputError(f"{p}: the cube holds negative radiance")
            wl = np.asarray(wl, dtype=np.float64)
            if ref_shape is None:
                ref_shape, ref_wl, first = cube.shape, wl, p
            elif cube.shape != ref_shape:
                raise InputError(f"{p}: shape {cube.shape} differs from {first.name}'s {ref_shape}; "
                                 "all frames must have one shape")
            elif wl.shape != ref_wl.shape or not np.allclose(wl, ref_wl, atol=1e-6):
                raise InputError(f"{p}: its wavelengths differ from {first.name}'s")
        self.file_shape = tuple(int(s) for s in ref_shape)
        self.shape = check_shape(shape) if shape is not None else self.file_shape[:2]
        # Wavelength coverage is checked here too, once, rather than at the first frame.
        from scenes.registry import resample_bands

        resample_bands(np.zeros((1, 1, ref_wl.size), np.float32), ref_wl, self.wavelengths)

    def frame(self, i: int) -> np.ndarray:
        from scenes.registry import load_cube_scene

        return load_cube_scene(self.files[self._check_index(i)], self.shape, self.wavelengths,
                               file_wavelengths=self.file_wavelengths, key=self.key)

    def describe(self) -> dict:
        d = super().describe()
        d.update(folder=str(self.folder), files=[p.name for p in self.files],
                 file_shape=list(self.file_shape), shape=list(self.shape))
        return d


_NAMED = {"colorwheel": RotatingColorwheel, "moving_object": MovingObject}


def list_animations() -> list[str]:
    """Names of the built-in animated scenes (a folder path is also accepted)."""
    return sorted(_NAMED)


def get_animation(name, shape=(256, 256), wavelengths=None, *, n_frames: int | None = None,
                  fps: float = 10.0, exposure_ms: float = 100.0, subframes: int = 1,
                  **params) -> Animation:
    """An animated scene by name (:func:`list_animations`) or from a folder of cube files.

    ``n_frames`` defaults to 10 for built-in scenes and to every file of a folder.  Other
    keywords go to the scene's class; unknown ones raise :class:`InputError`.
    """
    import inspect

    name = str(name)
    if name in _NAMED:
        cls = _NAMED[name]
        allowed = {p for p, v in inspect.signature(cls.__init__).parameters.items()
                   if v.kind == v.KEYWORD_ONLY}
        if cls is RotatingColorwheel:
            from scenes.colorwheel import colorwheel

            allowed |= {p for p, v in inspect.signature(colorwheel).parameters.items()
                        if v.kind == v.KEYWORD_ONLY} - {"angle_deg"}
        unknown = sorted(set(params) - allowed)
        if unknown:
            raise InputError(f"animated scene {name!r} has no parameter(s) {', '.join(unknown)}")
        return cls(shape, wavelengths, n_frames=10 if n_frames is None else n_frames, fps=fps,
                   exposure_ms=exposure_ms, subframes=subframes, **params)
    p = Path(name)
    if p.is_dir():
        unknown = sorted(set(params) - {"file_wavelengths", "key"})
        if unknown:
            raise InputError(f"a folder of cubes takes only file_wavelengths and key, not "
                             f"{', '.join(unknown)}")
        return CubeSequence(p, shape, wavelengths, n_frames=n_frames, fps=fps,
                            exposure_ms=exposure_ms, subframes=subframes, **params)
    if p.exists():
        raise InputError(f"{name}: an animated scene from files needs a folder of cubes")
    raise InputError(f"unknown animated scene {name!r}; built-in: {', '.join(list_animations())}, "
                     "or a folder of cube files")
