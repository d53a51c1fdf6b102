"""Proximal maps: total variation of band-major (L, H, W) cubes (:mod:`recon.prox.tv`)."""

from recon.prox.tv import TVProx, divergence, gradient, prox_tv, tv_norm, tv_norm_per_band

__all__ = ["TVProx", "divergence", "gradient", "prox_tv", "tv_norm", "tv_norm_per_band"]
