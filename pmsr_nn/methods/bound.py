"""The information bound as a row of a scenario: ``kind: pcrb``.

The PCRB is not an estimator, so the runner calls nothing for it: its row is filled from the
bound the runner computes anyway for a case of designed targets (each target's own
per-trajectory PCRB from its birth on its clean stream, :func:`~pmsr_nn.harness.scenario.case_bounds.case_bounds`),
named and placed where the scenario lists it. Options choose which bound: ``bound`` filtering
(what a causal tracker is held to) or smoothing (one that looks ahead), ``q`` the motion model's
process noise or zero (the floor for an estimator that knew the designed flights have none). A
multi-target study (sampled truth) refuses the kind: it reads no detections.
"""

from __future__ import annotations

from . import MethodCall, MethodKind, Option, register


def _not_called(call: MethodCall):
    raise RuntimeError(f"method {call.spec.name!r}: a bound row is filled by the runner, never called")


register(MethodKind(
    "pcrb", "truth", _not_called,
    {"bound": Option("filtering", str, choices=("filtering", "smoothing")),
     "q": Option("model", str, choices=("model", "zero"))},
    bound=True,
    description="posterior Cramer-Rao bound of each target's own clean stream from its birth (not an estimator: "
                "its row is the bound; bound: filtering | smoothing, q: model | zero)"))

