"""The map bound of a scenario's cases beside a record's map rows, without re-running any row.

For each case of a scenario with an ``rd_maps`` section, the bound the harness records as
``rd_maps.bound_pos_m`` (:func:`pmsr_nn.harness.scenario.case_bounds.maps_bound`: each target's
PCRB through every map's cells, :mod:`pmsr_nn.tbd.bound`), computed from the scenario alone (it
depends on the designed truth and the maps, not on any draw), at the last frame with a target and
as the median over the frames with one; then, from a record made before the bound was recorded,
each map row's RMS position error at that last frame and its ratio to the bound.

    python evaluate/map_bound.py evaluate/remotesensing2020_icmb.yaml --record evaluate/results/remotesensing2020_icmb/results.json --json evaluate/results/map_bounds/remotesensing2020_icmb.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from pmsr_nn.errors import PmsrError
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario


def map_bounds(scenario: Path, record: Path | None) -> dict:
    """``{case: {"bound_last_m", "bound_median_m", "last_frame", "rows": {row: {"rms_pos_last_m", "over_bound"}}}}``."""
    setup = prepare(load_scenario(scenario))
    res = json.loads(record.read_text()) if record is not None else None
    out = {}
    for case in setup.cases:
        maps = case.info.get("rd_maps")
        if not maps:
            continue
        bound = np.asarray(maps["bound_pos_m"], dtype=float)
        present = np.asarray(maps["present"], dtype=bool)
        last = int(np.nonzero(present)[0][-1])
        entry = {"last_frame": last + 1, "bound_last_m": float(bound[last]),
                 "bound_median_m": float(np.median(bound[present])), "rows": {}}
        rows = (res or {}).get("cases", {}).get(case.name, {}).get("methods", {})
        for name, row in rows.items():
            tbd = row.get("tbd")
            if tbd is not None:
                rms = float(tbd["rms_pos_last_present_m"])
                entry["rows"][name] = {"rms_pos_last_m": rms, "over_bound": rms / float(bound[last])}
        out[case.name] = entry
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", type=Path, help="a scenario with an rd_maps section")
    ap.add_argument("--record", type=Path, help="its results.json, for the map rows' errors")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    try:
        figures = map_bounds(args.scenario, args.record)
    except (PmsrError, OSError, KeyError, ValueError) as exc:
        print(f"map_bound: error: {exc}", file=sys.stderr)
        sys.exit(2)
    if not figures:
        print(f"map_bound: error: {args.scenario} has no case with range-Doppler maps", file=sys.stderr)
        sys.exit(2)
    for name, e in figures.items():
        print(f"{name}: map bound {e['bound_last_m']:.1f} m at frame {e['last_frame']} (median over the frames with a "
              f"target {e['bound_median_m']:.1f} m)")
        for row, r in e["rows"].items():
            print(f"  {row:<40} RMS pos {r['rms_pos_last_m']:8.1f} m   {r['over_bound']:6.1f} x the bound")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.json.with_suffix(".tmp")
        tmp.write_text(json.dumps({"scenario": str(args.scenario), "record": None if args.record is None else
                                   str(args.record), "cases": figures}, indent=1) + "\n")
        tmp.replace(args.json)


if __name__ == "__main__":
    main()
