"""Reliability over seeds as numbers: the median, the interquartile mean (IQM) and the worst seed of
one task and agent's per-seed returns. The IQM is rliable's (Agarwal et al. 2021, "Deep RL at the
Edge of the Statistical Precipice"): the mean of the middle half, `scipy.stats.trim_mean(x, 0.25)`,
which cuts `int(0.25 * n)` seeds from each end. Unlike the mean it is not moved by one seed far
out, and unlike the median it uses half the seeds; the worst seed says whether every seed learned."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import stats


def over_seeds(returns: Sequence[float]) -> dict[str, float | int]:
    """`{"seeds", "median", "iqm", "worst"}` of per-seed returns (one number per seed)."""
    values = np.asarray(returns, dtype=np.float64)
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f"over_seeds needs one return per seed (a flat, non-empty list), got shape {values.shape}")
    return {"seeds": int(values.size), "median": float(np.median(values)),
            "iqm": float(stats.trim_mean(values, 0.25)), "worst": float(values.min())}
