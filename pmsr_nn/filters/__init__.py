"""Batched single-target filters and smoothers: shared Gaussian steps, KF, EKF, UKF, RTS and
unscented RTS smoothers."""

from .gaussian import (FilterError, Gaussian, SigmaPoints, kalman_update, linearised_moments, predict,
                       sequential_update, unscented_moments)
from .kalman import FilterResult, ekf, kalman_filter, run_gaussian_filter, ukf
from .smoothing import SmootherResult, rts_backward, rts_smoother, unscented_rts_smoother

__all__ = ["FilterError", "Gaussian", "SigmaPoints", "kalman_update", "linearised_moments", "predict",
           "sequential_update", "unscented_moments", "FilterResult", "ekf", "kalman_filter", "run_gaussian_filter", "ukf",
           "SmootherResult", "rts_backward", "rts_smoother", "unscented_rts_smoother"]
