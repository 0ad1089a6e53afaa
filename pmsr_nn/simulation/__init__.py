"""Simulators: the CA track generator and its recipe, and multi-target detections with clutter."""

from .recipe import TrackRecipe, load_recipe
from .tracks import TrackBatch, build_models, generate_tracks

__all__ = ["TrackRecipe", "load_recipe", "TrackBatch", "build_models", "generate_tracks"]
