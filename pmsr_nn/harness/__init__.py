"""The evaluation harness: scenario -> every method on the same Monte Carlo draws -> results.json,
report.md and figures (:func:`evaluate`, :func:`merge`)."""

from .evaluate import evaluate, merge
from .scenario import CaseSpec, MethodSpec, Scenario, SegmentSpec, load_scenario

__all__ = ["evaluate", "merge", "CaseSpec", "MethodSpec", "Scenario", "SegmentSpec", "load_scenario"]
