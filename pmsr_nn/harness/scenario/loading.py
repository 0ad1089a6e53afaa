"""A scenario as a command gives it: a YAML file (or an already loaded scenario) with the command
line's ``--mc-runs``, ``--seed`` and ``--checkpoint`` applied, and the files a run of it reads.
"""

from __future__ import annotations

from pathlib import Path

from .schema import Scenario, load_scenario


def load_any(scenario: Scenario | str | Path, mc_runs: int | None = None,
             checkpoints: dict[str, str] | None = None, seed: int | None = None) -> Scenario:
    """The scenario (loaded from its YAML file if a path), with ``--mc-runs``, ``--seed`` and
    ``--checkpoint`` applied."""
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    sc = sc.with_mc_runs(mc_runs).with_seed(seed)
    return sc.with_checkpoints(checkpoints) if checkpoints else sc


def scenario_inputs(scenario: Scenario | str | Path, sc: Scenario | None) -> list[Path]:
    """Files a scenario run reads: its YAML (when ``scenario`` is a path) and every checkpoint a
    method of ``sc`` (the loaded scenario; None before loading) names."""
    paths = [] if isinstance(scenario, Scenario) else [Path(scenario)]
    for m in getattr(sc, "methods", ()):
        if getattr(m, "checkpoint", None):
            paths.append(sc.path(m.checkpoint))
    return paths
