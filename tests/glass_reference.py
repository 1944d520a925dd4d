"""An independent float64 glass pane (not usdbake's ``glazing`` module): Radiance's transmissivity (glass.c, its
constants), then a slab of index n with absorption along the refracted path and every internal reflection, from
the angles (Snell) and Fresnel's sin/tan forms, averaged over the two polarisations."""

from __future__ import annotations

import numpy as np


def slab_transmittance(cos_incidence, vlt: float, n: float = 1.52) -> np.ndarray:
    """Transmittance of a pane of normal-incidence transmittance ``vlt`` crossed at cos(theta_i)."""
    theta_i = np.arccos(np.clip(np.abs(np.asarray(cos_incidence, np.float64)), 0.0, 1.0))
    tn = (np.sqrt(.8402528435 + .0072522239 * vlt * vlt) - .9166530661) / .0036261119 / vlt
    theta_t = np.arcsin(np.sin(theta_i) / n)
    absorbed = tn ** (1.0 / np.cos(theta_t))
    normal = ((n - 1) / (n + 1)) ** 2  # both forms' limit at normal incidence
    with np.errstate(invalid="ignore", divide="ignore"):
        r_s = np.where(theta_i > 1e-8, np.sin(theta_i - theta_t) ** 2 / np.sin(theta_i + theta_t) ** 2, normal)
        r_p = np.where(theta_i > 1e-8, np.tan(theta_i - theta_t) ** 2 / np.tan(theta_i + theta_t) ** 2, normal)
    out = sum(0.5 * (1 - r) ** 2 * absorbed / (1 - (r * absorbed) ** 2) for r in (r_s, r_p))
    return np.where(theta_i < np.pi / 2 - 1e-12, out, 0.0)
