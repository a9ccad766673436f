"""Colour limits that show a run's physics: robust percentiles over the whole run, fixed across its frames.

A min-max range is set by the largest outlier (a contact point, one fast particle), which leaves nearly every
particle in the bottom sliver of the colour map. `robust_limits` takes percentiles of the values of every frame
together, so that a movie's colours keep one meaning and the bulk of the particles spreads over the map; values
beyond the limits saturate. Plain numpy: the renderer, the comparison and the interactive window share it.
"""
from __future__ import annotations

import numpy as np

# fields whose values are magnitudes (never negative): a linear range starts at 0, so that the colour bar's
# bottom means "nothing"
MAGNITUDES = ("speed", "von_mises", "damage", "plastic_strain")
DEFAULT_PERCENTILES = (1.0, 99.0)
LOG_DECADES = 4.0      # a log range spans at most this many decades below its top
_SAMPLE = 400_000      # values kept from a whole run for its percentiles (a uniform subsample beyond this)


def _sample(frames, rng=None) -> np.ndarray:
    """The finite values of all frames in one array, subsampled uniformly when there are more than _SAMPLE."""
    arrays = [np.asarray(v, float).ravel() for v in frames]
    total = sum(len(a) for a in arrays)
    if total > _SAMPLE:
        rng = rng or np.random.default_rng(0)
        arrays = [a[rng.random(len(a)) < _SAMPLE / total] for a in arrays]
    v = np.concatenate(arrays) if arrays else np.zeros(0)
    return v[np.isfinite(v)]


def robust_limits(frames, field: str = "", scale: str = "linear", percentiles=DEFAULT_PERCENTILES,
                  categorical: bool = False) -> list[float]:
    """[lo, hi] for the values of every frame of a run (a list of arrays, or one array).

    linear: the given percentiles of all values (magnitude fields start at 0); log: the top percentile, and
    the bottom percentile of the positive values, at most LOG_DECADES below it. categorical (body ids): one
    colour per integer value. A flat field gets a range around its value, so that its colour is mid-map.
    """
    if isinstance(frames, np.ndarray) and frames.ndim <= 1:
        frames = [frames]
    v = _sample(frames)
    if categorical:
        top = int(np.max(v)) if len(v) else 0
        return [-0.5, max(top + 1, 2) - 0.5]
    if len(v) == 0:
        return [0.0, 1.0]
    p_lo, p_hi = float(percentiles[0]), float(percentiles[1])
    if scale == "log":
        pos = v[v > 0]
        if len(pos) == 0:
            return [1e-12, 1.0]
        hi = float(np.percentile(pos, p_hi))
        lo = max(float(np.percentile(pos, p_lo)), hi * 10.0 ** -LOG_DECADES)
        if not lo < hi:
            lo = hi / 10.0
        return [lo, hi]
    lo, hi = float(np.percentile(v, p_lo)), float(np.percentile(v, p_hi))
    if field in MAGNITUDES and lo >= 0:
        lo = 0.0
    if hi - lo <= 1e-9 * max(abs(hi), abs(lo), 1e-30):  # flat: centre the value on the map
        vmax = float(np.max(v))
        if vmax > hi:        # a flat bulk with a few larger values (a wave front): show those
            hi = vmax
        else:
            pad = 0.5 * abs(hi) if hi != 0 else 1.0
            lo, hi = (0.0 if field in MAGNITUDES and lo >= 0 else lo - pad), hi + pad
    return [lo, hi]


def normalise(values, limits, scale: str = "linear") -> np.ndarray:
    """Values -> position on the colour map in [0, 1] (clipped), as the renderer maps them."""
    v = np.asarray(values, float)
    lo, hi = float(limits[0]), float(limits[1])
    if scale == "log":
        v = np.log10(np.clip(v, lo, hi))
        lo, hi = np.log10(lo), np.log10(hi)
    return np.clip((v - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)


class LiveLimits:
    """Robust limits for a live view (the interactive window), where the run's future is unknown: percentiles of
    the frames seen since the field was chosen, over a sliding window of recent frames, widened only (so that
    colours keep their meaning while the scene settles) until `reset`."""

    def __init__(self, field: str, scale: str = "linear", fixed=None, percentiles=DEFAULT_PERCENTILES, keep: int = 30):
        self.field, self.scale, self.percentiles, self.keep = field, scale, percentiles, keep
        self.fixed = list(fixed) if fixed else None
        self.recent: list[np.ndarray] = []
        self.lim = None

    def update(self, values) -> list[float]:
        if self.fixed:
            return self.fixed
        values = np.asarray(values, float)
        if self.field in ("body", "material", "interface"):
            return robust_limits([values], self.field, categorical=True)
        finite = values[np.isfinite(values)]
        if len(finite) == 0 or np.ptp(finite) == 0:  # a flat frame (at rest at t = 0) says nothing about the range
            return self.lim or robust_limits([finite], self.field, self.scale, self.percentiles)
        self.recent = (self.recent + [values])[-self.keep:]
        lo, hi = robust_limits(self.recent, self.field, self.scale, self.percentiles)
        if self.lim is not None:
            lo, hi = min(lo, self.lim[0]), max(hi, self.lim[1])
        self.lim = [lo, hi]
        return self.lim

    def reset(self):
        self.recent, self.lim = [], None
