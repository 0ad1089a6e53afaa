"""Batched single-target filters: shared Gaussian steps, EKF, UKF (smoothers, SI+KF and the
particle filter are to come)."""

from .gaussian import FilterError, Gaussian, SigmaPoints, kalman_update, linearised_moments, predict, unscented_moments
from .kalman import FilterResult, ekf, kalman_filter, run_gaussian_filter, ukf

__all__ = ["FilterError", "Gaussian", "SigmaPoints", "kalman_update", "linearised_moments", "predict",
           "unscented_moments", "FilterResult", "ekf", "kalman_filter", "run_gaussian_filter", "ukf"]
