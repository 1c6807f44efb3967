"""Region-of-interest metrics (paper Section III-A and IV-D). Pure functions of arrays.

Two ROIs are used, on purpose:
- the *belief* ROI ``mu + beta sigma >= mu_th`` is what a robot can compute; rewards and planners
  use it;
- the *evaluation* ROI ``truth >= mu_th`` comes from the ground truth and is the same set of cells
  for every planner on a given episode; reported metrics use it.
"""

from __future__ import annotations

import numpy as np


def belief_roi(mean: np.ndarray, variance: np.ndarray, mu_th: float, beta: float = 1.0) -> np.ndarray:
    """Boolean mask of cells with ``mean + beta * sqrt(variance) >= mu_th``."""
    return mean + beta * np.sqrt(np.maximum(variance, 0.0)) >= mu_th


def truth_roi(truth: np.ndarray, mu_th: float) -> np.ndarray:
    """Boolean mask of cells whose true value is at least ``mu_th``."""
    return np.asarray(truth).reshape(-1) >= mu_th


def trace_roi(variance: np.ndarray, roi: np.ndarray) -> float:
    """Tr(P) over the ROI: the sum of marginal variances of the ROI cells."""
    return float(np.sum(variance[roi]))


def rmse_roi(mean: np.ndarray, truth: np.ndarray, roi: np.ndarray) -> float:
    """Root mean squared error of the mean against the truth over the ROI (nan if empty)."""
    if not np.any(roi):
        return float("nan")
    err = mean[roi] - np.asarray(truth).reshape(-1)[roi]
    return float(np.sqrt(np.mean(err * err)))


def reduction_pct(prior: float, now: float) -> float:
    """Reduction from ``prior`` to ``now`` in percent of ``prior`` (nan when prior is 0)."""
    if prior == 0 or not np.isfinite(prior):
        return float("nan")
    return 100.0 * (prior - now) / prior


def info_gain_reward(trace_before: float, trace_after: float, scale: float = 10.0) -> float:
    """Paper reward: ``scale * (Tr(P-) - Tr(P+)) / Tr(P-)``; 0 when the ROI is empty."""
    if trace_before <= 0:
        return 0.0
    return scale * (trace_before - trace_after) / trace_before
