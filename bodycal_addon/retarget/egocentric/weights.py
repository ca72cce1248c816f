"""Raw and normalised importance weights of each element for each target (Delahaye 2023, appendix D)."""

from __future__ import annotations

import numpy as np

from .projection import Projections

MIN_DISTANCE = 1e-3  # m: raw weights are capped at 1 / MIN_DISTANCE**2 (a target on a surface)

def raw_weights(proj: Projections, heights: np.ndarray, exclude: np.ndarray | None = None,
                falloff: float = 2.0):
    """Raw contributions Λ (Delahaye 2023, appendix C): factor / |v|^2 per element, 1 / h^2 for the
    floor, distances floored at MIN_DISTANCE. `exclude` (P, E) bool zeroes own-chain elements.
    `falloff` is the exponent (the paper's 2; larger favours the closest element more).
    Returns (Λ (F, P, E), Λ_floor (F, P))."""
    if falloff == 2.0:
        lam = proj.factor / np.maximum(proj.dist * proj.dist, MIN_DISTANCE ** 2)
        floor = 1.0 / np.maximum(heights * heights, MIN_DISTANCE ** 2)
    else:
        lam = proj.factor / np.maximum(proj.dist, MIN_DISTANCE) ** falloff
        floor = 1.0 / np.maximum(np.abs(heights), MIN_DISTANCE) ** falloff
    if exclude is not None and exclude.any():
        lam = np.where(exclude, 0.0, lam)
    return lam, floor


def normalise_weights(lam: np.ndarray, lam_floor: np.ndarray):
    """The two normalisations of eq. 1, weights scaled to sum to one (not vectors to unit length):
    λ over the elements without the floor, λg with it.
    Returns (λ (F, P, E), λg (F, P, E), λg_floor (F, P)); λ is 0 where no element has weight."""
    s = lam.sum(-1)
    sg = s + lam_floor
    lam_n = np.divide(lam, s[..., None], out=np.zeros_like(lam), where=s[..., None] > 0)
    return lam_n, lam / sg[..., None], lam_floor / sg
