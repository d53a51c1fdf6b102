r"""Following a ray through the instrument: the delta-path walk shared by every tracer.

Every element after the diffuser is a delta interaction (lens, mask, prism, mirror), so a
path from the sensor to the diffuser is a walk: intersect, sample the element's BSDF (no
choice is left to chance), continue.  :func:`walk` does that for a batch of rays and records
what the tracers need: the path's throughput (hero wavelength, :mod:`sim.optics.dielectric`), where it
crosses the mask plate and where it reaches the diffuser, which mirrors it met, and where the
segment leaving the relay lens crosses the tube's exit plane (the kaleidoscope's only stop).

Why not ``SurfaceInteraction.spawn_ray``
----------------------------------------
Mitsuba continues a path from :math:`p + \epsilon\,(1 + \max_i |p_i|)\, n` (the surface
normal :math:`n`, :math:`\epsilon \approx 9 \cdot 10^{-5}` in single precision) to avoid
re-hitting the surface it leaves.  In this scene the coordinates are hundreds of millimetres,
so every crossing moves the ray by ~0.04 mm along the normal; for a ray at angle
:math:`\theta` to a lens plane that is a lateral step of :math:`0.04 \tan\theta` mm, different
for every point of the aperture: a defocus.  The image of a sensor point on the mask and on
the diffuser then spreads over pixels instead of a point, a blur no ideal-lens instrument has
(``tools/bench_transport.py --spawn`` measures it with the chief and marginal rays of one
sensor point).  :func:`continue_ray` moves the origin along the new direction instead, which
keeps the ray on its exact line (the surfaces are planes or convex, so the step cannot re-enter
the one left): the spread falls to the float32 round-off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.optics.variant import ensure_variant, register_plugin

__all__ = ["SPAWN_EPS", "continue_ray", "sensor_rays", "Walk", "walk", "register_integrator",
           "INTEGRATOR"]

#: Step along the new direction, relative to ``1 + max|p|`` (float32 keeps ~7 digits: a step of
#: 1e-5 of the coordinates clears the surface by ~100 ulps and moves nothing sideways).
SPAWN_EPS = 1e-5
#: Mitsuba plugin name of the exact path integrator (:func:`register_integrator`).
INTEGRATOR = "kaleidospec_path"


def continue_ray(si, wo_world, wavelengths):
    """The ray leaving ``si`` along ``wo_world``, its origin moved along ``wo_world`` itself
    (module notes: no sideways step, unlike ``spawn_ray``)."""
    import drjit as dr

    mi = ensure_variant()
    eps = (1.0 + dr.max(dr.abs(si.p))) * SPAWN_EPS
    return mi.Ray3f(si.p + wo_world * eps, wo_world, 0.0, wavelengths)


def sensor_rays(setup, rows, cols, aperture, wavelength_nm):
    """Rays leaving sensor points (continuous pixel coordinates ``rows``, ``cols``) through the
    aperture samples ``aperture`` (2, n) in the unit square, at ``wavelength_nm`` (all four of a
    path's wavelengths set to it)."""
    mi = ensure_variant()
    hs, ws = setup.sensor_shape
    rows = np.asarray(rows, np.float64)
    cols = np.asarray(cols, np.float64)
    pos = mi.Point2f((cols / ws).astype(np.float32), (rows / hs).astype(np.float32))
    ap = np.asarray(aperture, np.float64)
    ray, _ = setup.camera.sample_ray(0.0, 0.5, pos, mi.Point2f(ap[0].astype(np.float32),
                                                                ap[1].astype(np.float32)))
    lam = mi.Float(np.broadcast_to(np.asarray(wavelength_nm, np.float32), rows.shape).copy())
    ray.wavelengths = mi.Spectrum(lam, lam, lam, lam)
    return ray


@dataclass
class Walk:
    """What :func:`walk` records per ray (NumPy arrays, one entry per ray)."""

    weight: np.ndarray      #: throughput at the hero wavelength (0 if the diffuser is not reached)
    reached: np.ndarray     #: bool: the path reached the diffuser's front
    diffuser: np.ndarray    #: (2, n) world x, y where it reached the diffuser
    mask: np.ndarray        #: (2, n) world x, y where it crossed the mask plate
    exit: np.ndarray        #: (2, n) world x, y where the relay's outgoing segment crosses z = L
    walls: np.ndarray       #: (2, n) int: reflections off the x walls (left/right) and y walls


def walk(setup, ray, *, max_depth: int = 24) -> Walk:
    """Walk a batch of rays from the sensor to the diffuser (module notes).

    Parameters
    ----------
    setup : sim.optics.scene.TraceSetup
        The loaded scene and the planes to record (:func:`sim.optics.scene.trace_setup`).
    ray : mitsuba.Ray3f
        Rays leaving the sensor, with their wavelengths set.
    max_depth : int
        Most interactions per path (a path meets ~10 elements).
    """
    import drjit as dr

    mi = ensure_variant()
    scene, z = setup.scene, setup.z
    half_w = 0.5 * setup.tube_width
    ctx = mi.BSDFContext()
    thr = mi.Spectrum(1.0)
    active = mi.Bool(True)
    got = mi.Bool(False)
    nan = mi.Float(np.nan)
    dx, dy, mx, my, ex, ey = nan, nan, nan, nan, nan, nan
    nwx, nwy = mi.UInt32(0), mi.UInt32(0)
    for _ in range(max_depth):
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid()
        # The diffuser is the only surface at z = 0 facing +z; it emits on its front only.
        at_d = active & (dr.abs(si.p.z) < 1e-3) & (ray.d.z < 0)
        dx, dy = dr.select(at_d, si.p.x, dx), dr.select(at_d, si.p.y, dy)
        got |= at_d
        active &= ~at_d
        at_m = active & (dr.abs(si.p.z - z["mask"]) < 1e-3)
        mx, my = dr.select(at_m, si.p.x, mx), dr.select(at_m, si.p.y, my)
        if setup.tube_length is not None:
            inside = (si.p.z > -1e-3) & (si.p.z < setup.tube_length + 1e-3)
            nwx += mi.UInt32(active & inside & (dr.abs(dr.abs(si.p.x) - half_w) < 1e-3))
            nwy += mi.UInt32(active & inside & (dr.abs(dr.abs(si.p.y) - half_w) < 1e-3))
        at_r = active & (dr.abs(si.p.z - z["relay"]) < 1e-3)
        bsdf = si.bsdf(ray)
        bs, wgt = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5), active)
        thr = dr.select(active, thr * wgt, thr)
        wo = si.to_world(bs.wo)
        if setup.tube_length is not None:
            # The segment leaving the relay lens toward the tube crosses the exit plane z = L.
            t = (setup.tube_length - si.p.z) / wo.z
            ex = dr.select(at_r & (wo.z < 0), si.p.x + t * wo.x, ex)
            ey = dr.select(at_r & (wo.z < 0), si.p.y + t * wo.y, ey)
        active &= dr.any(wgt > 0)
        ray = dr.select(active, continue_ray(si, wo, ray.wavelengths), ray)
        dr.eval(ray, thr, active, got, dx, dy, mx, my, ex, ey, nwx, nwy)
        if not dr.any(active):
            break
    # The prism keeps the hero wavelength (weight 4, 0, 0, 0): the mean is its throughput.
    w = dr.select(got, (thr[0] + thr[1] + thr[2] + thr[3]) * 0.25, 0.0)
    weight = np.asarray(w, dtype=np.float64)
    n = weight.size

    def f(a, dtype=np.float64):
        # A quantity no ray ever set stays a drjit scalar: give every ray its value.
        return np.broadcast_to(np.asarray(a, dtype=dtype), (n,)).copy()

    return Walk(weight=weight, reached=f(got, bool),
                diffuser=np.stack([f(dx), f(dy)]), mask=np.stack([f(mx), f(my)]),
                exit=np.stack([f(ex), f(ey)]), walls=np.stack([f(nwx, np.int64),
                                                              f(nwy, np.int64)]))


def register_integrator():
    """Register ``kaleidospec_path``: Mitsuba's backward path tracing through delta
    interactions, continued with :func:`continue_ray` (idempotent).

    A path from the sensor meets only delta BSDFs until it reaches the diffuser, an area
    emitter; the estimate is the path's throughput times the emitted radiance there (what
    Mitsuba's ``path`` integrator computes for such a scene, where emitter sampling never
    connects through a delta BSDF), without ``spawn_ray``'s sideways step.
    """
    return register_plugin("integrator", INTEGRATOR, _integrator_class)


def _integrator_class(mi):
    """The ``ExactPath`` plugin class for the variant ``mi``."""
    import drjit as dr

    class ExactPath(mi.SamplingIntegrator):
        def __init__(self, props):
            mi.SamplingIntegrator.__init__(self, props)
            self.max_depth = int(props.get("max_depth", 24))

        def sample(self, scene, sampler, ray, medium=None, active=True):
            ray = mi.Ray3f(ray)
            ctx = mi.BSDFContext()
            result = mi.Spectrum(0.0)
            thr = mi.Spectrum(1.0)
            act = mi.Bool(active)
            for _ in range(self.max_depth):
                si = scene.ray_intersect(ray, act)
                act &= si.is_valid()
                emitter = si.emitter(scene, act)
                hit_light = act & (emitter != None)  # noqa: E711 (drjit pointer test)
                result += dr.select(hit_light, thr * emitter.eval(si, hit_light), 0.0)
                act &= ~hit_light
                bsdf = si.bsdf(ray)
                bs, wgt = bsdf.sample(ctx, si, sampler.next_1d(act), sampler.next_2d(act), act)
                thr = dr.select(act, thr * wgt, thr)
                act &= dr.any(wgt > 0)
                ray = dr.select(act, continue_ray(si, si.to_world(bs.wo), ray.wavelengths),
                                ray)
            return result, mi.Bool(True), []

        def aov_names(self):
            return []

        def to_string(self):
            return f"ExactPath[max_depth={self.max_depth}]"

    return ExactPath
