"""Batched single-target filters and smoothers.

Shared Gaussian steps (:mod:`.gaussian`: predict, EKF / UKF moments, Kalman update, sequential
per-sensor update), whole-sequence KF / EKF / UKF (:mod:`.kalman`), RTS and unscented RTS
smoothers (:mod:`.smoothing`), spherical-interpolation fixes (:mod:`.spherical`, their
covariance :mod:`.fix_covariance`) and SI+KF (:mod:`.si_kf`), the bootstrap particle filter
(:mod:`.particle`) and the IMM filter (:mod:`.imm`). The PCRB lives in :mod:`pmsr_nn.bounds`.
"""

from .gaussian import (FilterError, Gaussian, SigmaPoints, kalman_update, linearised_moments, predict,
                       sequential_update, unscented_moments)
from .imm import IMMMode, IMMResult, imm, markov_transition
from .kalman import FilterResult, ekf, kalman_filter, run_gaussian_filter, ukf
from .particle import ParticleResult, particle_filter, systematic_resample
from .smoothing import SmootherResult, rts_backward, rts_smoother, unscented_rts_smoother
from .fix_covariance import fix_covariance
from .si_kf import SIKFResult, si_kf
from .spherical import spherical_interpolation

__all__ = ["FilterError", "Gaussian", "SigmaPoints", "kalman_update", "linearised_moments", "predict",
           "sequential_update", "unscented_moments", "FilterResult", "ekf", "kalman_filter", "run_gaussian_filter",
           "ukf", "IMMMode", "IMMResult", "imm", "markov_transition", "ParticleResult", "particle_filter",
           "systematic_resample", "SmootherResult", "rts_backward", "rts_smoother", "unscented_rts_smoother",
           "SIKFResult", "fix_covariance", "si_kf", "spherical_interpolation"]
