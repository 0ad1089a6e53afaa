"""Accuracy metrics.

- :mod:`.pointwise`: single-target errors over Monte Carlo runs (RMSE, NEES, track loss).
- :mod:`.sets`: multi-object metrics on padded, masked sets (OSPA, GOSPA, assignments, label and identity switches).
- :mod:`.trajectory_gospa`: trajectory GOSPA with switching cost, per run (an LP / MILP per run).
"""

from __future__ import annotations

from .pointwise import (
    normalised_nees,
    pooled_rmse,
    position_columns,
    rmse_over_time,
    squared_error,
    track_loss,
    velocity_columns,
)
from .sets import GOSPA, SetScores, cardinality_error, fragmentations, gospa, identity_switches, label_switches, labelled_assignment, optimal_assignment, ospa, persistent_assignment, set_scores
from .tracks import TrackScores, matched_errors, matched_tracks, track_scores
from .trajectory_gospa import TrajectoryGOSPA, trajectory_gospa

__all__ = [
    "position_columns",
    "velocity_columns",
    "squared_error",
    "rmse_over_time",
    "pooled_rmse",
    "normalised_nees",
    "track_loss",
    "optimal_assignment",
    "persistent_assignment",
    "ospa",
    "set_scores",
    "SetScores",
    "GOSPA",
    "gospa",
    "cardinality_error",
    "labelled_assignment",
    "label_switches",
    "identity_switches",
    "fragmentations",
    "TrackScores",
    "track_scores",
    "matched_errors",
    "matched_tracks",
    "TrajectoryGOSPA",
    "trajectory_gospa",
]
