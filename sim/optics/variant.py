"""Choose the Mitsuba 3 variant the simulator renders with.

Every optical element after the diffuser is a delta (specular) interaction and the prism needs
the wavelength of each path, so the simulator needs a *spectral* variant. ``llvm_ad_spectral``
vectorises the Python plugins (lens, prism) with drjit's LLVM backend and is much faster than
``scalar_spectral``, which runs every Python plugin call once per ray. When the LLVM backend
cannot start (no usable ``libLLVM``: drjit aborts with Debian's libLLVM-14/15 and needs ≥ 17,
found automatically or through ``DRJIT_LIBLLVM_PATH``), we fall back to ``scalar_spectral`` with
a warning rather than crash.

Call :func:`ensure_variant` before building any Mitsuba object; it is idempotent and returns the
``mitsuba`` module.
"""

from __future__ import annotations

import os
import warnings

__all__ = ["ensure_variant", "PREFERRED", "FALLBACK", "is_vectorized", "delta_bsdf_base",
           "register_plugin"]

PREFERRED = "llvm_ad_spectral"
FALLBACK = "scalar_spectral"

_chosen: str | None = None


def _try_set(mi, name: str) -> bool:
    try:
        if name not in mi.variants():
            return False
        mi.set_variant(name)
        # Building a tiny array forces drjit to initialise the backend: this is where a missing
        # or unusable libLLVM shows up, not in set_variant.
        import drjit as dr

        if name.startswith("llvm"):
            x = dr.llvm.ad.Float([1.0, 2.0])
            dr.eval(x * 2.0)
        return True
    except Exception as err:  # noqa: BLE001 - any failure means "not usable here"
        warnings.warn(f"Mitsuba variant {name} is not usable ({err}); trying another", stacklevel=3)
        return False


def ensure_variant(preferred: str | None = None):
    """Select a spectral Mitsuba variant once and return the ``mitsuba`` module.

    Parameters
    ----------
    preferred : str, optional
        Variant to try first; default ``$KALEIDOSPEC_MI_VARIANT`` or ``llvm_ad_spectral``.

    Returns
    -------
    module
        ``mitsuba`` with a spectral variant set.

    Raises
    ------
    RuntimeError
        If Mitsuba is installed without any spectral variant.
    """
    global _chosen
    import mitsuba as mi

    if _chosen is not None:
        if mi.variant() != _chosen:
            mi.set_variant(_chosen)
        return mi
    first = preferred or os.environ.get("KALEIDOSPEC_MI_VARIANT") or PREFERRED
    for name in dict.fromkeys([first, PREFERRED, FALLBACK]):
        if _try_set(mi, name):
            if name != first:
                warnings.warn(
                    f"Mitsuba variant {first} unavailable; rendering with {name} "
                    "(Python plugins run per ray, much slower)",
                    stacklevel=2,
                )
            _chosen = name
            return mi
    raise RuntimeError(
        f"no spectral Mitsuba variant available (have: {', '.join(mi.variants())}); "
        "install mitsuba>=3.5 with llvm_ad_spectral or scalar_spectral"
    )


def is_vectorized() -> bool:
    """True when the chosen variant is a JIT (vectorised) one."""
    mi = ensure_variant()
    return not mi.variant().startswith("scalar")


_delta_bases: dict = {}


def delta_bsdf_base():
    """Base class of the simulator's purely specular BSDF plugins (lens, mask, prism).

    A delta interaction has no density: ``eval`` and ``pdf`` are zero for every pair of
    directions, and all the work is in ``sample``, which subclasses implement.  All of them
    transmit through either side (one delta-transmission component, front and back), set here.
    One class per Mitsuba variant, since ``mi.BSDF`` differs between variants.
    """
    mi = ensure_variant()
    base = _delta_bases.get(mi.variant())
    if base is None:

        class DeltaBSDF(mi.BSDF):
            def __init__(self, props):
                mi.BSDF.__init__(self, props)
                self.m_flags = (mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.FrontSide
                                | mi.BSDFFlags.BackSide)
                self.m_components = [self.m_flags]

            def eval(self, ctx, si, wo, active=True):
                return mi.Spectrum(0.0)

            def pdf(self, ctx, si, wo, active=True):
                return mi.Float(0.0)

            def eval_pdf(self, ctx, si, wo, active=True):
                return mi.Spectrum(0.0), mi.Float(0.0)

            def traverse(self, callback):
                pass

        base = _delta_bases[mi.variant()] = DeltaBSDF
    return base


_plugins: set = set()


def register_plugin(kind: str, name: str, build) -> str:
    """Register with Mitsuba, once, the plugin class that ``build(mi)`` defines, as ``name``.

    ``kind`` is ``"bsdf"``, ``"texture"`` or ``"integrator"``.  A plugin class derives from the
    chosen variant's Mitsuba types, so it can only be defined once a variant is set: ``build``
    receives the ``mitsuba`` module and runs on the first call only.  Returns ``name``.
    """
    mi = ensure_variant()
    if name not in _plugins:
        cls = build(mi)
        getattr(mi, f"register_{kind}")(name, lambda props: cls(props))
        _plugins.add(name)
    return name
