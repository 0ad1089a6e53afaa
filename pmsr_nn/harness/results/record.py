"""``results.json``'s content (schema in DESIGN.md): the scenario, its result kind, settings,
definitions, the paper's reference and every case's figures (:func:`~.finalise.finalise`).
"""

from __future__ import annotations

from ...environment import environment
from ..run.block_sums import BlockSums
from ..scenario.prepared import Setup
from ..scenario.references import scenario_references
from .finalise import finalise, result_kind


def build_results(setup: Setup, bs: BlockSums, device: str, merged: dict | None = None) -> dict:
    """``results.json``'s content from the sums of all blocks ``bs``; ``merged``: what a merge adds
    to the environment (the shards' commits, a preview's full run count)."""
    sc = setup.scenario
    _, _, ref_info = scenario_references(sc)
    env = {**environment(device), **(merged or {})}
    return {"scenario": sc.name, "kind": result_kind(setup), "seed": sc.seed, "mc_runs": sc.mc_runs,
            "environment": env,
            "description": sc.description, "settings": setup.settings, "definitions": setup.definitions,
            "reference": ref_info, "cases": finalise(setup, bs)}
