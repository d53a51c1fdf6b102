r"""The fast path: a design's optical maps, traced once, and frames as exact pixel integrals.

Every element between the diffuser and the sensor is specular and the system is linear in the
scene, so a band's sensor image is a fixed linear map of the scene's band.  This module keeps
that map in the form the physics gives it: the optical maps of :mod:`sim.transport.maps` (where each
sensor point looks on the mask and the diffuser, at each wavelength node, and the throughput),
traced with Mitsuba once per design, and the pixel integral of :mod:`sim.transport.pixel_integral`, which
integrates every pixel's footprint over its area, the band, the mask cells and the scene's
texels exactly (frames take every band of a view in one pass, :mod:`sim.transport.view_integral`; the
exact operator and its adjoint go band by band).  A frame is then a deterministic integral,
not a Monte Carlo draw: a capture and a scene frame made from it agree because the optics
agree, and no calibration can learn a sampling pattern (there is none to learn).  How close it
is to the converged direct render is measured by ``tools/bench_transport.py``;
:mod:`sim.transport.sampled` keeps the Monte Carlo transport as an independent cross-check.

A transport does not depend on the scene's resolution (the maps end on the diffuser in units of
the scene's side), so one trace serves the calibration targets on the view's grid and scenes at
twice that resolution.  ``seed`` picks the realisation of the trace (the jitter of the traced
sensor points and the aperture samples): the calibration captures, the scene frames and the
exact operator each use their own (:data:`SEEDS`), so no figure is scored on the realisation its
model was fitted to.

Cache files: ``<cache>/maps-<design hash>-<key>.npz``, checked entries of :mod:`recon.io.cache`
(written atomically with a checksum; one that fails its checks on load is removed with a warning
and traced again), the key hashing the band intervals, views, seed and trace settings.  The
cache folder is ``$KALEIDOSPEC_CACHE`` or ``~/.cache/kaleidospec``.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from recon.errors import InputError
from recon.kernels import cores, each
from sim.bands import band_intervals

__all__ = ["Transport", "SEEDS", "cache_dir", "build_transport", "load_or_build",
           "render_cached", "held", "release", "each", "ordered_sum", "STATS"]

#: Trace realisations: calibration captures, scene frames and the exact (oracle) operator.
SEEDS = {"captures": 0, "scene": 1, "oracle": 2}
#: Counters for tests and benchmarks: transports traced, loaded from disk.
STATS = {"built": 0, "loaded": 0}
_FORMAT = 3
#: Trace settings (part of the cache key).
TRACE = {"degree": 5, "aperture_rays": 16, "tolerance_px": 0.003}


def cache_dir() -> Path:
    """``$KALEIDOSPEC_CACHE`` or ``~/.cache/kaleidospec`` (created on demand, checked to accept
    new files: :func:`recon.io.cache.check_folder`)."""
    from recon.io.cache import check_folder

    # One line (exit 2 on the command line) when it cannot be written, before any long work.
    return check_folder(os.environ.get("KALEIDOSPEC_CACHE")
                        or Path.home() / ".cache" / "kaleidospec")


class Transport:
    """The traced optics of a design for a set of bands, and the pixel integral on them.

    Attributes
    ----------
    maps : sim.transport.maps.OpticalMaps
    intervals : (L, 2) ndarray
        Wavelength interval of every band (equal ends: monochromatic).
    band_nodes : list of int arrays
        Indices into ``maps.nodes_nm`` of each band's nodes.
    code : (n, n) int8
        The view owning every open mask cell, −1 for chrome (:meth:`Design.mask_owner`).
    sensor : (Hs, Ws)
    """

    def __init__(self, design, maps, intervals, band_nodes, *, build_seconds=0.0, path=None):
        self.design_hash = design.hash
        self.maps = maps
        self.intervals = np.asarray(intervals, np.float64).reshape(-1, 2)
        self.band_nodes = [np.asarray(b, np.int64) for b in band_nodes]
        self.sensor = (int(design.sensor_height_px), int(design.sensor_width_px))
        self.code = np.where(design.mask_pattern(), design.mask_owner(), -1).astype(np.int8)
        self.views = tuple(int(v) for v in maps.views)
        self.build_seconds = float(build_seconds)
        self.path = path
        self._tau, self._geom, self._part, self._buckets = {}, {}, {}, {}
        self._ordered = {}

    @property
    def n_bands(self) -> int:
        return len(self.band_nodes)

    def _check_band(self, l):
        if not 0 <= int(l) < self.n_bands:
            raise InputError(f"band {l} out of range 0..{self.n_bands - 1}")
        return int(l)

    def geometry(self, k: int, l: int):
        """:class:`sim.transport.pixel_integral.RowGeometry` of view index ``k`` in band ``l``."""
        key = (k, l)
        if key not in self._geom:
            from sim.transport.pixel_integral import RowGeometry

            self._geom[key] = RowGeometry(self.maps, k, self.band_nodes[l])
        return self._geom[key]

    def throughput(self, k: int, l: int | None = None) -> np.ndarray:
        """τ of view index ``k`` in band ``l`` at its pixel centres, (h, w) float32 (every
        band's, (L, h, w), when ``l`` is None)."""
        if k not in self._tau:
            from sim.transport.pixel_integral import throughput_images

            self._tau[k] = throughput_images(self.maps, k, self.band_nodes)
        return self._tau[k] if l is None else self._tau[k][l]

    def partition(self, k: int, width: int):
        """The x partition of view index ``k`` for a cube ``width`` texels wide."""
        key = (k, int(width))
        if key not in self._part:
            from sim.transport.pixel_integral import partition

            lo, hi = np.inf, -np.inf
            for l in range(self.n_bands):
                a, b = self.geometry(k, l).x_range()
                lo, hi = min(lo, a), max(hi, b)
            self._part[key] = partition(self.maps.relay[k], int(width), (lo, hi),
                                        self.code.shape[0])
        return self._part[key]

    def edges_ordered(self, k: int) -> bool:
        """Whether view index ``k``'s pixel edges are in order along every row, at every
        wavelength node: :math:`x_j(r, e + 1) - x_j(r, e) > 10^{-9}` mask units for every
        pixel row :math:`r`, edge :math:`e` and node :math:`j` (far above the round-off of
        the kernels' own evaluation).  Then every edge lies among the pieces its row spans,
        and :func:`sim.transport.view_integral.view_forward` need not check it row by row."""
        if k not in self._ordered:
            geom = self.geometry(k, 0)
            steps = np.diff(geom.pce, axis=0)
            self._ordered[k] = all(
                float((geom.prc @ self.maps.mask[k, j, 0] @ steps.T).min()) > 1e-9
                for j in range(self.maps.mask.shape[1]))
        return self._ordered[k]

    def buckets(self, k: int, width: int):
        """:func:`sim.transport.view_integral.buckets` of :meth:`partition` ``(k, width)``."""
        key = (k, int(width))
        if key not in self._buckets:
            from sim.transport.view_integral import buckets

            texel_pitch = 1.0 / (int(width) * float(self.maps.relay[k][1]))
            self._buckets[key] = buckets(self.partition(k, width)[0], texel_pitch)
        return self._buckets[key]

    def view_bands(self, f, k: int, bands=None, out=None) -> np.ndarray:
        """Irradiance (La, h, w) of view index ``k`` in ``bands`` (all by default) from the
        scene's bands ``f`` (H, W, La), band-last: all bands in one pass over the rows
        (:mod:`sim.transport.view_integral`), blocks of rows on a thread per core.  The same as
        :meth:`view_band` band by band, to a few 10⁻⁵ of the peak.

        ``out``, when given, may be larger than (La, h, w): its top-left (h, w) of each band is
        written and the rest left as it is (a zero-padded buffer for the blurs' transforms)."""
        out, blocks = self.view_blocks(f, k, bands, out)
        each(lambda block: block(), blocks)
        return out

    def view_blocks(self, f, k: int, bands=None, out=None):
        """:meth:`view_bands` as work to run: ``(out, blocks)``, ``blocks`` a list of calls
        without arguments, each integrating one block of rows into ``out`` (they write
        disjoint rows: any order, any threads).  For a caller that schedules other work
        between them (:meth:`sim.frame.FrameModel.electrons` blurs the previous view there)."""
        from sim.transport.pixel_integral import band_mean
        from sim.transport.view_integral import view_forward

        bands = list(range(self.n_bands)) if bands is None else [self._check_band(l)
                                                                  for l in bands]
        if not bands:
            raise InputError("no bands to integrate")
        f = np.ascontiguousarray(f, np.float32)
        if f.ndim != 3 or f.shape[2] != len(bands):
            raise InputError(f"scene shape {f.shape} does not hold the {len(bands)} bands asked")
        used = sorted({int(j) for l in bands for j in self.band_nodes[l]})
        where = {j: i for i, j in enumerate(used)}
        mask = self.maps.mask[k]
        cxn = mask[used, 0]
        cyl = np.stack([band_mean(mask[:, 1], self.band_nodes[l]) for l in bands])
        nodes = [np.array([where[int(j)] for j in self.band_nodes[l]], np.int64) for l in bands]
        geom = self.geometry(k, bands[0])
        if out is None:
            out = np.empty((len(bands), geom.h, geom.w), np.float32)
        elif (out.dtype != np.float32 or out.ndim != 3 or out.shape[0] != len(bands)
              or out.shape[1] < geom.h or out.shape[2] < geom.w):
            raise InputError(f"out must be float32 ({len(bands)}, ≥ {geom.h}, ≥ {geom.w}), "
                             f"got {out.dtype} {out.shape}")
        part, bucket, tau = self.partition(k, f.shape[1]), self.buckets(k, f.shape[1]), \
            self.throughput(k)
        ordered = self.edges_ordered(k)

        def block(rows):
            return lambda: view_forward(f, self.code, self.views[k], self.maps.relay[k], part,
                                        bucket, geom, cxn, cyl, nodes, bands, tau, out, rows,
                                        ordered)

        return out, [block(rows) for rows in row_blocks(geom.h, cores())]

    def view_band(self, f, k: int, l: int, out=None) -> np.ndarray:
        """Irradiance (h, w) of view index ``k`` in band ``l`` from the band image ``f`` (H, W)."""
        from sim.transport.pixel_integral import band_forward

        l = self._check_band(l)
        return band_forward(f, self.code, self.views[k], self.maps.relay[k],
                            self.partition(k, np.shape(f)[1]), self.geometry(k, l),
                            self.throughput(k, l), out)

    def view_band_adjoint(self, e, k: int, l: int, shape, fbar=None) -> np.ndarray:
        """The adjoint of :meth:`view_band`: (H, W) float64 (accumulated into ``fbar``)."""
        from sim.transport.pixel_integral import band_adjoint

        l = self._check_band(l)
        return band_adjoint(e, self.code, self.views[k], self.maps.relay[k],
                            self.partition(k, int(shape[1])), self.geometry(k, l),
                            self.throughput(k, l), shape, fbar)

    def apply(self, cube, bands=None, out=None) -> np.ndarray:
        """Per-band irradiance (L, Hs, Ws) float32 of a cube (H, W, L), every band of a view
        in one pass (:meth:`view_bands`); only ``bands`` are written when given."""
        cube = np.asarray(cube, np.float32)
        if cube.ndim != 3 or cube.shape[2] != self.n_bands:
            raise InputError(f"cube shape {cube.shape} does not have the transport's "
                             f"{self.n_bands} bands")
        if out is None:
            out = np.zeros((self.n_bands,) + self.sensor, np.float32)
        todo = list(range(self.n_bands)) if bands is None else [self._check_band(b)
                                                                 for b in bands]
        if not todo:
            return out
        f = np.ascontiguousarray(cube[:, :, todo])
        self.prepare(todo, f.shape[1])
        for k in range(len(self.views)):
            r0, c0, h, w = (int(v) for v in self.maps.rects[k])
            irr = self.view_bands(f, k, todo)
            for i, l in enumerate(todo):
                out[l, r0:r0 + h, c0:c0 + w] = irr[i]
        return out

    def prepare(self, bands, width: int) -> None:
        """Build the geometry, throughput and partitions of ``bands`` (once, before threads)."""
        for k in range(len(self.views)):
            self.partition(k, width)
            self.throughput(k, 0)
            self.edges_ordered(k)

    def nbytes(self) -> int:
        """Memory of the maps and of the throughput images computed so far."""
        m = self.maps
        return int(m.mask.nbytes + m.exit.nbytes + m.throughput.nbytes
                   + sum(t.nbytes for t in self._tau.values()))


def row_blocks(h: int, workers: int, rows: int = 48) -> list[tuple[int, int]]:
    """``h`` rows cut into blocks of about ``rows`` (at most), as many as a multiple of
    ``workers`` and of equal size to a row: rows cost alike, so every thread takes as many
    blocks and all finish together (19 blocks of 48 on two threads left one idle for a
    block's time, 5 % of a view).  Blocks of rows, not single rows: a block's first row
    locates its edges by the bucket table, the next ones by a step from the row above."""
    workers = max(1, int(workers))
    n = workers * max(1, -(-h // (workers * rows)))
    n = max(1, min(n, h))
    cuts = [h * i // n for i in range(n + 1)]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def ordered_sum(fn, items, out, add=None):
    """``out += fn(item)`` for every item, ``fn`` on a thread per usable CPU (:func:`each`), the
    sum always in the items' order (so a frame is the same to the last bit whichever thread
    finishes first, and its noise draw too).  ``fn`` may return None (nothing); ``add(out,
    part)``, when given, takes the place of ``out += part`` (a part that covers only some of
    ``out``).

    The next item starts as soon as a thread is free and the sum is taken while the others
    work (NumPy releases the GIL): a thread never waits for the slowest item of a batch, nor
    for the sum.  At most one result per thread waits in memory beyond those in flight.
    """
    items = list(items)
    workers = max(1, min(len(items), cores()))
    with ThreadPoolExecutor(workers) as pool:
        pending = deque()
        it = iter(items)
        for item in it:
            pending.append(pool.submit(fn, item))
            if len(pending) >= 2 * workers:
                break
        while pending:
            part = pending.popleft().result()
            nxt = next(it, _DONE)
            if nxt is not _DONE:
                pending.append(pool.submit(fn, nxt))
            if part is None:
                continue
            if add is None:
                out += part
            else:
                add(out, part)
    return out


_DONE = object()


def _key(design, intervals, seed) -> str:
    blob = json.dumps({
        "format": _FORMAT, "design": design.hash,
        "intervals": np.round(np.asarray(intervals, np.float64), 6).tolist(),
        "views": sorted(int(v) for v in design.views), "seed": int(seed), "trace": TRACE,
    }, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def build_transport(design, intervals, *, seed: int = 0, progress: bool = False) -> Transport:
    """Trace the optical maps for the band ``intervals`` (L, 2) (not cached)."""
    from sim.transport.maps import band_nodes, trace_maps

    iv = np.asarray(intervals, np.float64).reshape(-1, 2)
    if iv.size == 0 or np.any(iv[:, 1] < iv[:, 0]):
        raise InputError("every band interval needs lo <= hi")
    nodes, index = band_nodes(design, iv, TRACE["tolerance_px"])
    t0 = time.perf_counter()
    maps = trace_maps(design, nodes, seed=seed, degree=TRACE["degree"],
                      aperture_rays=TRACE["aperture_rays"], progress=progress)
    STATS["built"] += 1
    return Transport(design, maps, iv, index, build_seconds=time.perf_counter() - t0)


_ARRAYS = ("nodes_nm", "rects", "norm", "mask", "exit", "throughput", "relay", "fit_rms")


#: What a maps entry must hold besides the header's own list (:func:`recon.io.cache.read_npz`).
_EXPECT = {"nodes_nm": (np.floating, 1), "band_lengths": (np.integer, 1),
           "band_nodes": (np.integer, 1), "intervals": (np.floating, 2),
           "views": (np.integer, 1), **{name: None for name in _ARRAYS}}


def _save(tr: Transport, path: Path, key: str) -> None:
    from recon.io.cache import write_npz

    m = tr.maps
    arrays = {name: getattr(m, name) for name in _ARRAYS}
    arrays.update(format=np.array(_FORMAT), design_hash=np.array(tr.design_hash),
                  views=np.array(m.views, np.int64), degree=np.array(m.degree),
                  has_stop=np.array(m.has_stop), stop_half=np.array(m.stop_half),
                  seed=np.array(m.seed), seconds=np.array(m.seconds),
                  intervals=tr.intervals, build_seconds=np.array(tr.build_seconds),
                  band_lengths=np.array([b.size for b in tr.band_nodes], np.int64),
                  band_nodes=np.concatenate(tr.band_nodes).astype(np.int64))
    write_npz(path, arrays, kind="maps", design_hash=tr.design_hash, version=_FORMAT, key=key,
              compress=True)


def _load(design, path: Path, key: str) -> Transport | None:
    """The entry at ``path``, or None (none, or a damaged or foreign one: removed with one
    warning line, :func:`recon.io.cache.read_npz`)."""
    from recon.io.cache import read_npz
    from sim.transport.maps import OpticalMaps

    z = read_npz(path, kind="maps", design_hash=design.hash, version=_FORMAT, key=key,
                 expect=_EXPECT)
    if z is None:
        return None
    maps = OpticalMaps(design_hash=design.hash,
                       views=tuple(int(v) for v in z["views"]), degree=int(z["degree"]),
                       has_stop=bool(z["has_stop"]), stop_half=float(z["stop_half"]),
                       seed=int(z["seed"]), seconds=float(z["seconds"]),
                       **{name: z[name] for name in _ARRAYS})
    splits = np.cumsum(z["band_lengths"])[:-1]
    nodes = np.split(z["band_nodes"], splits)
    return Transport(design, maps, z["intervals"], nodes,
                     build_seconds=float(z["build_seconds"]), path=path)


_MEMO: dict[str, Transport] = {}


def load_or_build(design, wavelengths=None, *, sampling: str = "box", intervals=None,
                  seed: int = 0, progress: bool = False, use_disk: bool = True) -> Transport:
    """The transport of ``design`` for its bands: from memory, from the cache folder, or traced
    (and then written to the cache folder atomically).

    Parameters
    ----------
    wavelengths : array_like, optional
        Band centres (the design's by default), integrated per ``sampling``
        (:func:`sim.bands.band_intervals`), or explicit ``intervals`` (L, 2).
    seed : int
        The trace's realisation (:data:`SEEDS`).
    """
    if intervals is None:
        wl = design.wavelengths if wavelengths is None else np.asarray(wavelengths, np.float64)
        intervals = band_intervals(design, wl, sampling)
    iv = np.asarray(intervals, np.float64).reshape(-1, 2)
    key = _key(design, iv, seed)
    if key in _MEMO:
        return _MEMO[key]
    path = cache_dir() / f"maps-{design.hash}-{key}.npz"
    tr = None
    if use_disk:
        tr = _load(design, path, key)      # None: none yet, or a damaged one (removed)
        if tr is not None:
            STATS["loaded"] += 1
    if tr is None:
        tr = build_transport(design, iv, seed=seed, progress=progress)
        if use_disk:
            _save(tr, path, key)
            tr.path = path
    _MEMO[key] = tr
    return tr


def render_cached(design, cube: np.ndarray, wavelengths, *, seed: int = 0,
                  sampling: str = "box", progress: bool = False) -> np.ndarray:
    """Per-band sensor irradiance (L, Hs, Ws) float32 of ``cube`` (H, W, L) from the transport.

    ``wavelengths`` are the cube's band centres; they must be bands of the design.
    """
    from sim.bands import check_cube

    cube, wl = check_cube(design, cube, wavelengths)
    tr = load_or_build(design, wl, sampling=sampling, seed=seed, progress=progress)
    return tr.apply(cube)


def held() -> set[str]:
    """The keys of the transports held in memory now (a step that makes transports for itself
    releases those that were not held before it)."""
    return set(_MEMO)


def release(seed: int | None = None, *, keys=None) -> None:
    """Drop transports held in memory: those of ``keys`` (from :func:`held`) when given, else
    those traced with ``seed`` (a value of :data:`SEEDS`), else all of them.  The cache folder
    keeps its files."""
    if keys is not None:
        for key in keys:
            _MEMO.pop(key, None)
    elif seed is None:
        _MEMO.clear()
    else:
        for key in [k for k, tr in _MEMO.items() if int(tr.maps.seed) == int(seed)]:
            del _MEMO[key]
