"""The Monte Carlo transport: every pixel sampled with random rays, kept as sparse matrices.

The product renders with the converged transport (:mod:`sim.transport`); this one is the
independent cross-check the tests and ``tools/bench_transport.py`` hold it against, and the
measure of what a sampled simulator gets wrong (its draw).

Every element between the diffuser and the sensor is specular (delta) and the system is linear
in the scene radiance, so the per-band sensor image is

.. math:: E_l(p) = \\frac{\\pi}{1 + 4N^2} \\cdot \\frac{1}{S} \\sum_{s=1}^{S}
          \\tau_{s}\\; T_d\\, f_l\\big(t_s\\big),

where pixel *p* shoots S camera samples (uniform over the pixel, the lens aperture and the
band's wavelengths), sample *s* reaches diffuser texel :math:`t_s` with throughput
:math:`\\tau_s` (mirror reflectances, mask and quartz, prism Fresnel losses; 0 if it is blocked),
and :math:`f_l` is band *l* of the cube. Since :math:`(t_s, \\tau_s)` do not depend on the scene,
we trace them once per band and keep, per band, the sparse matrix :math:`A_l` with
:math:`A_l[p, t] = \\frac{\\pi T_d}{(1+4N^2) S}\\sum_{s: t_s = t} \\tau_s` (duplicates merged).
A frame is then :math:`E_l = A_l f_l` for every band: a gather and a ``bincount``.

The tracer here (:func:`sim.rays.walk`) is independent of Mitsuba's path integrator, which is
what makes the direct render (:mod:`sim.render`) a meaningful check of it. With the same sample
count the two estimate the same expectation; they differ only by Monte Carlo noise.

How the S samples of a pixel are drawn is the ``sampler`` (:func:`pixel_samples`): i.i.d.
(``independent``, the default) or randomised quasi-Monte Carlo (``sobol``), which stratifies
every pixel's samples over its area and its band and lowers the per-pixel error of a frame at the
same cost (``tests/sim/test_sampled.py``).

Cache files: ``<cache>/sampled-<design hash>-<key>.npz`` (``np.savez_compressed``, written to a
temporary file in the same folder and renamed; read with ``allow_pickle=False``), where the key
hashes the cube shape, samples per pixel, band intervals, views, seed and sampler. The cache
folder is ``$KALEIDOSPEC_CACHE`` or ``~/.cache/kaleidospec``.
"""

from __future__ import annotations

import hashlib
import json
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.errors import InputError
from recon.kernels import cores
from sim.bands import band_intervals
from sim.transport import cache_dir

__all__ = [
    "Transport",
    "sensor_pixels",
    "trace_band",
    "build_transport",
    "load_or_build",
    "render_cached",
    "SAMPLERS",
    "check_sampler",
    "pixel_samples",
    "STATS",
]

#: Counters for tests and benchmarks: how many bands were traced / loaded from disk.
STATS = {"traced_bands": 0, "loaded": 0, "built": 0}

_FORMAT = 1


def sensor_pixels(design, views=None, crop=None) -> np.ndarray:
    """Flat sensor pixel indices (row·W + col) of the used views' rectangles (sorted, int64).

    ``crop`` = (row0, col0, height, width) intersects them with a window (benchmarks).
    """
    H, W = design.sensor_height_px, design.sensor_width_px
    keep = np.zeros((H, W), dtype=bool)
    for v in (design.views if views is None else views):
        r0, c0, h, w = design.view_rect(v)
        keep[max(r0, 0):min(r0 + h, H), max(c0, 0):min(c0 + w, W)] = True
    if crop is not None:
        r0, c0, h, w = crop
        win = np.zeros_like(keep)
        win[max(r0, 0):r0 + h, max(c0, 0):c0 + w] = True
        keep &= win
    return np.flatnonzero(keep.ravel())


@dataclass
class Transport:
    """Per-band sparse transport: for band l, ``pix[l]``, ``tex[l]``, ``w[l]`` (sorted by pixel)."""

    design_hash: str
    shape: tuple[int, int]          # cube (H, W) on the diffuser
    sensor: tuple[int, int]         # (Hs, Ws)
    wavelengths: np.ndarray         # band centres (L,)
    intervals: np.ndarray           # (L, 2) sampled interval per band
    spp: int
    pix: list
    tex: list
    w: list
    build_seconds: float = 0.0
    path: Path | None = None
    _seg: list | None = None

    def _matrix(self, l: int):
        """Band l as the distinct pixels it lights and a CSR matrix (pixels × texels).

        The entries are sorted by pixel, so each pixel's run is one CSR row and the matrix
        shares the index and weight arrays (no copy); scipy's CSR product gathers, weighs and
        sums in one pass, about twice as fast as ``take`` + ``reduceat``.
        """
        if self._seg is None:
            self._seg = [None] * len(self.pix)
        if self._seg[l] is None:
            import scipy.sparse as sp

            upix, starts = np.unique(self.pix[l], return_index=True)
            indptr = np.append(starts, self.tex[l].size).astype(np.int64 if self.tex[l].size
                                                                  >= 2**31 else np.int32)
            n_tex = self.shape[0] * self.shape[1]
            a = sp.csr_matrix((self.w[l], self.tex[l], indptr), shape=(upix.size, n_tex))
            self._seg[l] = (upix.astype(np.int64), a)
        return self._seg[l]

    def apply(self, cube: np.ndarray, bands=None, out: np.ndarray | None = None) -> np.ndarray:
        """Per-band irradiance (L, Hs, Ws) float32 of a cube (H, W, L) on this transport.

        E_l = A_l f_l: a sparse product per band (each sensor pixel sums its entries'
        ``w · f_l[tex]``), float32 throughout, bands in parallel.
        """
        cube = np.asarray(cube, dtype=np.float32)
        Hs, Ws = self.sensor
        L = len(self.pix)
        if out is None:
            out = np.zeros((L, Hs, Ws), dtype=np.float32)
        todo = [l for l in (range(L) if bands is None else bands) if self.pix[l].size]
        for l in todo:  # the matrices are built once, outside the threads
            self._matrix(l)

        def one(l):
            upix, a = self._matrix(l)
            out[l].reshape(-1)[upix] = a @ np.ascontiguousarray(cube[:, :, l]).ravel()

        # scipy's sparse product releases the GIL: bands run in parallel on every usable CPU.
        workers = min(len(todo), cores())
        if workers > 1:
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(one, todo))
        else:
            for l in todo:
                one(l)
        return out

    def nbytes(self) -> int:
        """In-memory size of the index and weight arrays."""
        return int(sum(a.nbytes for a in self.pix + self.tex + self.w))


def _trace_setup(design, shape):
    from sim.diffuser import cube_region
    from sim.scene import trace_setup

    return trace_setup(design), cube_region(design, shape)


SAMPLERS = ("independent", "sobol")


def check_sampler(sampler: str) -> str:
    """``sampler`` if it names one of :data:`SAMPLERS`, else :class:`InputError`."""
    if sampler not in SAMPLERS:
        raise InputError(f"sampler must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    return sampler


def pixel_samples(n_pixels: int, spp: int, sampler: str, rng):
    """A function giving the (5, n) unit-cube samples of flat sample indices ``s``.

    Sample ``k`` of pixel ``i`` is ``s = i·spp + k``; its five coordinates are the position in
    the pixel (2), on the lens aperture (2) and in the band's wavelength interval (1).

    ``independent``: i.i.d. uniform (plain Monte Carlo). ``sobol``: randomised quasi-Monte
    Carlo: the first ``spp`` points of one Owen-scrambled Sobol sequence, toroidally shifted by a
    random vector per pixel (Cranley–Patterson rotation), so every pixel's samples keep the
    net's stratification (with 4 samples: one in each quarter of the pixel's area, on a grid
    shifted by the rotation, and one in each quarter of the band) while pixels stay
    independent.  A pixel's integrand is piecewise constant (mask cells, scene texels, the
    band's dispersion), for which stratification cuts the error from O(spp^-1/2) towards
    O(spp^-1) (measured on `small`: about spp^-0.65).
    """
    if check_sampler(sampler) == "independent":
        return lambda s: rng.random((5, s.size))
    import warnings

    from scipy.stats import qmc

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)    # balance warning for spp not 2^m
        base = qmc.Sobol(5, scramble=True, seed=rng).random(spp).T     # (5, spp)
    shift = rng.random((5, n_pixels))

    def draw(s):
        u = base[:, s % spp] + shift[:, s // spp]
        return u - np.floor(u)

    return draw


def trace_band(design, shape, interval, spp: int, seed: int = 0, pixels=None,
               max_depth: int = 24, batch: int = 1 << 21, sampler: str = "independent",
               _setup=None):
    """Trace one band: every (pixel, sample) → (texel, throughput).

    Parameters
    ----------
    design : sim.design.Design
    shape : (H, W)
        Cube resolution on the diffuser (sets the texel grid).
    interval : (lo, hi)
        Wavelengths (nm) sampled uniformly for this band (lo == hi: monochromatic).
    spp : int
        Samples per pixel (uniform over the pixel area and the lens aperture).
    seed : int
        Seeds the NumPy generator that draws every sample (the result is deterministic).
    pixels : ndarray of int, optional
        Flat sensor pixels to trace; the used views by default.
    sampler : {"independent", "sobol"}
        How each pixel's samples are drawn (:func:`pixel_samples`).

    Returns
    -------
    pix, tex : ndarray int32
        Pixel and texel of every (pixel, texel) pair that received light, sorted by pixel.
    w : ndarray float32
        Σ τ_s · T_d · π/(1+4N²) / spp over the samples of that pair.
    """
    from sim.camera import irradiance_factor
    from sim.rays import sensor_rays, walk

    setup, region = _setup if _setup is not None else _trace_setup(design, shape)
    Ws = design.sensor_width_px
    if pixels is None:
        pixels = sensor_pixels(design)
    pixels = np.asarray(pixels, dtype=np.int64)
    rng = np.random.default_rng([int(seed), int(round(interval[0] * 1000)),
                                 int(round(interval[1] * 1000))])
    ntex = int(shape[0]) * int(shape[1])
    scale = irradiance_factor(design) * design.diffuser_transmittance / spp
    keys_all, w_all = [], []
    total = pixels.size * spp
    draw = pixel_samples(pixels.size, spp, sampler, rng)
    for start in range(0, total, batch):
        n = min(batch, total - start)
        s_idx = np.arange(start, start + n, dtype=np.int64)
        pix = pixels[s_idx // spp]
        r = (pix // Ws).astype(np.float64)
        c = (pix % Ws).astype(np.float64)
        u = draw(s_idx)
        lam = interval[0] + (interval[1] - interval[0]) * u[4]
        wk = walk(setup, sensor_rays(setup, r + u[1], c + u[0], u[2:4], lam),
                  max_depth=max_depth)
        xs = region.sx * wk.diffuser[0]
        ys = region.sy * wk.diffuser[1]
        tc = np.floor((xs - region.x0) / region.dx)
        tr = np.floor((ys - region.y0) / region.dy)
        ok = (wk.weight > 0) & (tc >= 0) & (tc < region.width) & (tr >= 0) & (tr < region.height)
        keys_all.append(pix[ok] * ntex + (tr[ok] * region.width + tc[ok]).astype(np.int64))
        w_all.append(wk.weight[ok].astype(np.float32))
    keys = np.concatenate(keys_all) if keys_all else np.zeros(0, np.int64)
    ws = np.concatenate(w_all) if w_all else np.zeros(0, np.float32)
    uk, inv = np.unique(keys, return_inverse=True)
    wsum = np.bincount(inv, weights=ws.astype(np.float64), minlength=uk.size) * scale
    STATS["traced_bands"] += 1
    return ((uk // ntex).astype(np.int32), (uk % ntex).astype(np.int32),
            wsum.astype(np.float32))


def _key(design, shape, intervals, spp, seed, pixels_desc, sampler) -> str:
    blob = json.dumps({
        "format": _FORMAT, "design": design.hash, "shape": [int(s) for s in shape],
        "intervals": np.round(np.asarray(intervals, np.float64), 6).tolist(), "spp": int(spp),
        "seed": int(seed), "pixels": pixels_desc, "sampler": sampler,
    }, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def build_transport(design, shape, wavelengths=None, *, spp: int = 4, seed: int = 0,
                    sampling: str = "box", sampler: str = "independent", crop=None,
                    progress: bool = False) -> Transport:
    """Trace the optical system for every band inside the filter's pass band (not cached)."""
    check_sampler(sampler)
    wl = design.wavelengths if wavelengths is None else np.asarray(wavelengths, np.float64)
    iv = band_intervals(design, wl, sampling)
    setup = _trace_setup(design, shape)
    pixels = sensor_pixels(design, crop=crop)
    t0 = time.perf_counter()
    pix, tex, w = [], [], []
    it = range(wl.size)
    if progress:
        from recon.progress import progress_bar

        it = progress_bar(it, desc="transport", unit="band", leave=True)
    for l in it:
        inside = (wl[l] >= design.filter_min_nm) and (wl[l] <= design.filter_max_nm)
        if not inside or iv[l, 1] < iv[l, 0]:
            pix.append(np.zeros(0, np.int32)), tex.append(np.zeros(0, np.int32))
            w.append(np.zeros(0, np.float32))
            continue
        p, t, ww = trace_band(design, shape, iv[l], spp, seed=seed + 7919 * l, pixels=pixels,
                              sampler=sampler, _setup=setup)
        pix.append(p), tex.append(t), w.append(ww)
    STATS["built"] += 1
    return Transport(design.hash, (int(shape[0]), int(shape[1])),
                     (design.sensor_height_px, design.sensor_width_px), wl, iv, int(spp),
                     pix, tex, w, build_seconds=time.perf_counter() - t0)


def _save(tr: Transport, path: Path, key: str) -> None:
    from recon.io.cache import write_npz

    arrays = {
        "format": np.array(_FORMAT), "design_hash": np.array(tr.design_hash),
        "shape": np.array(tr.shape, np.int64), "sensor": np.array(tr.sensor, np.int64),
        "wavelengths": tr.wavelengths, "intervals": tr.intervals, "spp": np.array(tr.spp),
        "build_seconds": np.array(tr.build_seconds),
    }
    for l in range(len(tr.pix)):
        # Pixel indices are sorted: their differences are small and compress well.
        arrays[f"dpix_{l}"] = np.diff(tr.pix[l], prepend=0).astype(np.int32)
        arrays[f"tex_{l}"] = tr.tex[l]
        arrays[f"w_{l}"] = tr.w[l]
    write_npz(path, arrays, kind="sampled", design_hash=tr.design_hash, version=_FORMAT, key=key,
              compress=True)


def _load(path: Path, design_hash: str, key: str) -> Transport | None:
    """The entry at ``path``, or None (none, or a damaged or foreign one: removed with one
    warning line, :func:`recon.io.cache.read_npz`)."""
    from recon.io.cache import read_npz

    z = read_npz(path, kind="sampled", design_hash=design_hash, version=_FORMAT, key=key,
                 expect={"shape": (np.integer, 1), "sensor": (np.integer, 1),
                         "wavelengths": (np.floating, 1), "intervals": (np.floating, 2)})
    if z is None:
        return None
    L = int(z["wavelengths"].size)
    if any(f"{p}_{l}" not in z for p in ("dpix", "tex", "w") for l in range(L)):
        from recon.io.cache import discard

        discard(path, "incomplete: a band's arrays are missing")
        return None
    pix = [np.cumsum(z[f"dpix_{l}"], dtype=np.int64).astype(np.int32) for l in range(L)]
    return Transport(design_hash, tuple(int(v) for v in z["shape"]),
                     tuple(int(v) for v in z["sensor"]), z["wavelengths"], z["intervals"],
                     int(z["spp"]), pix, [z[f"tex_{l}"] for l in range(L)],
                     [z[f"w_{l}"] for l in range(L)],
                     build_seconds=float(z["build_seconds"]), path=path)


_MEMO: dict[str, Transport] = {}


def load_or_build(design, shape, wavelengths=None, *, spp: int = 4, seed: int = 0,
                  sampling: str = "box", sampler: str = "independent", crop=None,
                  progress: bool = False, use_disk: bool = True) -> Transport:
    """The transport for this design/shape/bands: from memory, from the cache folder, or traced
    (and then written to the cache folder atomically)."""
    wl = design.wavelengths if wavelengths is None else np.asarray(wavelengths, np.float64)
    iv = band_intervals(design, wl, sampling)
    key = _key(design, shape, iv, spp, seed, [list(design.views), crop], sampler)
    if key in _MEMO:
        return _MEMO[key]
    path = cache_dir() / f"sampled-{design.hash}-{key}.npz"
    tr = None
    if use_disk:
        tr = _load(path, design.hash, key)  # None: none yet, or a damaged one (removed)
        if tr is not None:
            STATS["loaded"] += 1
    if tr is None:
        tr = build_transport(design, shape, wl, spp=spp, seed=seed, sampling=sampling,
                             sampler=sampler, crop=crop, progress=progress)
        if use_disk:
            _save(tr, path, key)
            tr.path = path
    _MEMO[key] = tr
    return tr


def render_cached(design, cube: np.ndarray, wavelengths, *, spp: int = 4, seed: int = 0,
                  sampling: str = "box", sampler: str = "independent", progress: bool = False,
                  crop=None) -> np.ndarray:
    """Per-band sensor irradiance (L, Hs, Ws) float32 of ``cube`` (H, W, L) from the cache.

    ``wavelengths`` are the cube's band centres; they must be bands of the design (bands
    outside the filter's pass band give dark images). The first call for a design/cube shape
    traces the optics (:func:`load_or_build`); later calls are gathers.
    """
    from sim.bands import check_cube

    cube, wl = check_cube(design, cube, wavelengths)
    tr = load_or_build(design, cube.shape[:2], wl, spp=spp, seed=seed, sampling=sampling,
                       sampler=sampler, crop=crop, progress=progress)
    return tr.apply(cube)
