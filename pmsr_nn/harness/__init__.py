"""The evaluation harness: scenario -> every method on the same Monte Carlo draws -> results.json,
report.md and figures (:func:`evaluate`, :func:`merge`)."""

from .evaluate import evaluate, merge
from .scenario.case_spec import CaseSpec, SegmentSpec
from .scenario.method_spec import MethodSpec
from .scenario.schema import Scenario, load_scenario

__all__ = ["evaluate", "merge", "CaseSpec", "MethodSpec", "Scenario", "SegmentSpec", "load_scenario"]
