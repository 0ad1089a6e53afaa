"""The evaluation harness: scenario -> every method on the same Monte Carlo draws -> results.json,
report.md and figures (:func:`evaluate`, :func:`merge`).

Four stages, each importing only the ones before it: :mod:`.scenario` (schema, preparation),
:mod:`.run` (blocks of runs, per-block sums, shards, banks, the runner's :class:`~.run.runner.Run`),
:mod:`.results` (``results.json``'s figures) and :mod:`.report` (``report.md`` and figures). The
entry paths above them (:mod:`.evaluate`, :mod:`.dispatch`, :mod:`.demo`, :mod:`.ablation`)
compose the stages."""

from .evaluate import evaluate, merge
from .scenario.case_spec import CaseSpec, SegmentSpec
from .scenario.method_spec import MethodSpec
from .scenario.schema import Scenario, load_scenario

__all__ = ["evaluate", "merge", "CaseSpec", "MethodSpec", "Scenario", "SegmentSpec", "load_scenario"]
