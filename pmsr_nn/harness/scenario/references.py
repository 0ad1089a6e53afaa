"""A paper's numbers from a scenario's JSON reference file, for the columns labelled as the paper's:
one entry (:func:`reference_table`) and all a scenario names (:func:`scenario_references`)."""

from __future__ import annotations

import json
from pathlib import Path

from ...errors import ConfigError


def reference_table(path: Path, dotted: str) -> dict:
    """The entry ``dotted`` (``a.b.c``) of the JSON reference file at ``path``; a key that itself
    holds dots (``table_pd_0.8``) is matched whole, longest first."""
    try:
        node = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"reference file {path}: {exc}") from None
    parts = dotted.split(".")
    while parts:
        for n in range(len(parts), 0, -1):
            key = ".".join(parts[:n])
            if isinstance(node, dict) and key in node:
                node, parts = node[key], parts[n:]
                break
        else:
            raise ConfigError(f"reference file {path} has no entry {dotted!r}")
    return node


def paper_value(ref: dict | None, case: str, method: str, single_case: bool):
    """The paper's number for ``method`` in ``case`` (the table itself where it has one case), or None."""
    if not ref:
        return None
    row = ref if single_case else ref.get(case, {})
    v = row.get(method) if isinstance(row, dict) else None
    return v if isinstance(v, (int, float)) else None


def paper_seconds(timing: dict | None, method: str, key: str | None):
    """A study's run time of ``method`` for the case keyed ``key`` in the paper's table (seconds)."""
    if not timing or key is None:
        return None
    v = timing.get(method, {})
    v = v.get(key) if isinstance(v, dict) else None
    return v if isinstance(v, (int, float)) else None


def scenario_references(sc) -> tuple[dict | None, dict | None, dict]:
    """The paper's accuracy table and run-time table a scenario ``sc`` names (each may be None),
    and what ``results.json`` records of its reference (``{}`` without one)."""
    ref = sc.reference
    if ref is None:
        return None, None, {}
    path = sc.path(ref.file)
    name = getattr(ref, "table", None)
    table = reference_table(path, name) if name else None
    timing = reference_table(path, ref.timing) if ref.timing else None
    info = {"file": str(path), "table": name, "timing": ref.timing, "label": ref.label}
    per_target = {key: reference_table(path, getattr(ref, key)) for key in ("velocity_rmse", "anees")
                  if getattr(ref, key, None)}
    if per_target:  # the paper's per-target tables, shown beside ours
        info["per_target"] = {**per_target, "methods": dict(ref.methods),
                              **{f"{k}_key": getattr(ref, k) for k in per_target}}
    if getattr(ref, "setup", None):  # the paper's stated set-up, shown beside the scenario's
        info["setup"] = {"key": ref.setup, "table": reference_table(path, ref.setup)}
    if getattr(ref, "subarea_table", None):  # a track-before-detect sub-area study's (the Remote Sensing seed's Table 2)
        info["subarea"] = {"key": ref.subarea_table, "table": reference_table(path, ref.subarea_table)}
    return table, timing, info
