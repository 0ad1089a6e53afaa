"""Re-run the recorded studies that are quick to re-run, and compare each with its record.

For every ``evaluate/results/<study>/results.json`` whose scenario is ``evaluate/<study>.yaml``,
this estimates the re-run's time from the record itself (each row's seconds per run times its
runs, summed over the rows and cases: the recording machine's time, one process), and re-runs the
studies estimated under ``--max-minutes`` with the record's seed and run count:

    pmsr evaluate evaluate/<study>.yaml --out OUT/<study> --seed SEED --mc-runs RUNS --quiet

then compares the two files as ``pmsr compare`` does (:mod:`pmsr_nn.harness.results.compare`):
a study *reproduces* when every headline figure is the same (relative 1e-9) and none of the rows'
other values differs (run times left out). It prints one line per study and a Markdown table, and
with ``--json`` writes them to a file. Studies over the budget are listed as skipped, with their
estimate; a study whose re-run fails is listed with its error's last line.

    python evaluate/reproduce_records.py --out /tmp/repro --max-minutes 10 --json /tmp/repro.json
    python evaluate/reproduce_records.py --out /tmp/repro --only dense_crossing_bp,fm_front_end

``--out`` must be a new or empty folder: nothing outside it is written.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pmsr_nn.errors import ConfigError  # noqa: E402
from pmsr_nn.harness.results.compare import headline, load_results, other_numbers  # noqa: E402

RESULTS = ROOT / "evaluate" / "results"


def recorded_minutes(res: dict) -> float:
    """The record's own time for a re-run: every row's seconds per run times its runs, in minutes."""
    total = 0.0
    for case in res["cases"].values():
        for row in case.get("methods", {}).values():
            seconds, runs = row.get("seconds_per_run"), row.get("runs")
            if isinstance(seconds, (int, float)) and isinstance(runs, (int, float)):
                total += float(seconds) * float(runs)
    return total / 60.0


def studies(only: set[str] | None) -> list[str]:
    """The recorded studies with a scenario of the same name (in name order)."""
    names = sorted(p.parent.name for p in RESULTS.glob("*/results.json")
                   if (ROOT / "evaluate" / f"{p.parent.name}.yaml").is_file())
    if only is not None:
        unknown = sorted(only - set(names))
        if unknown:
            raise ConfigError(f"--only: no recorded study {', '.join(unknown)} (known: {', '.join(names)})")
        names = [n for n in names if n in only]
    return names


def verdict(old: dict, new: dict) -> dict:
    """How the re-run compares with the record: headline figures by verdict, other values compared
    and differing (the first few listed), and apart from them the fields the record predates
    (absent from it, written by the code since: they cannot be compared)."""
    counts: dict[str, int] = {}
    for d in headline(old, new):
        counts[d.verdict(2.0)] = counts.get(d.verdict(2.0), 0) + 1
    compared, found = other_numbers(old, new)
    newer = [line for line in found if ": <absent> -> " in line]
    differ = [line for line in found if ": <absent> -> " not in line]
    same = set(counts) <= {"same"} and not differ
    return {"reproduces": same, "headline": counts, "other_compared": compared - len(newer), "other_differ": len(differ),
            "fields_the_record_predates": len(newer), "first_differences": differ[:5]}


def rerun(name: str, res: dict, out: Path) -> dict:
    """Re-run one study into ``out / name`` and compare it with its record."""
    cmd = [sys.executable, "-m", "pmsr_nn.cli", "evaluate", f"evaluate/{name}.yaml", "--out", str(out / name),
           "--seed", str(res["seed"]), "--mc-runs", str(res["mc_runs"]), "--quiet"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)})
    seconds = time.perf_counter() - t0
    row = {"study": name, "command": " ".join(["pmsr", *cmd[3:]]), "seconds": round(seconds, 1)}
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        return {**row, "reproduces": False, "error": lines[-1] if lines else f"exit {proc.returncode}"}
    return {**row, **verdict(res, load_results(out / name))}


def table(rows: list[dict]) -> list[str]:
    lines = ["| study | recorded time (min) | re-run (s) | headline figures | other values differing | fields the record "
             "predates | reproduces |", "|---|---:|---:|---|---:|---:|---|"]
    for r in rows:
        if "skipped" in r:
            lines.append(f"| {r['study']} | {r['recorded_minutes']:.1f} | - | skipped: {r['skipped']} | - | - | - |")
        elif "error" in r:
            lines.append(f"| {r['study']} | {r['recorded_minutes']:.1f} | {r['seconds']} | failed: {r['error']} | - | - | no |")
        else:
            heads = ", ".join(f"{n} {v}" for v, n in r["headline"].items())
            lines.append(f"| {r['study']} | {r['recorded_minutes']:.1f} | {r['seconds']} | {heads} | "
                         f"{r['other_differ']} of {r['other_compared']} | {r['fields_the_record_predates']} | "
                         f"{'yes' if r['reproduces'] else 'no'} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="a new or empty folder for the re-runs")
    ap.add_argument("--max-minutes", type=float, default=10.0,
                    help="re-run only the studies whose record says they take less (default 10)")
    ap.add_argument("--only", help="comma-separated study names (default: every recorded study)")
    ap.add_argument("--json", help="also write the rows to this file (a new file)")
    a = ap.parse_args(argv)
    out = Path(a.out)
    try:
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise ConfigError(f"--out {out}: exists and is not an empty folder; give a new one")
        if a.json and Path(a.json).exists():
            raise ConfigError(f"--json {a.json}: exists; give a new file")
        if not a.max_minutes > 0:
            raise ConfigError(f"--max-minutes: expected a positive number, got {a.max_minutes}")
        names = studies(None if a.only is None else {s.strip() for s in a.only.split(",") if s.strip()})
    except ConfigError as exc:
        print(f"reproduce_records: {exc}", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in names:
        res = json.loads((RESULTS / name / "results.json").read_text())
        minutes = recorded_minutes(res)
        if minutes > a.max_minutes:
            rows.append({"study": name, "recorded_minutes": minutes, "skipped": f"over {a.max_minutes:g} min"})
        else:
            rows.append({"recorded_minutes": minutes, **rerun(name, res, out)})
        r = rows[-1]
        state = r.get("skipped") or r.get("error") or ("reproduces" if r["reproduces"] else
                                                        f"differs: {r['headline']}, {r['other_differ']} other values")
        print(f"{name}: {state}", flush=True)
    print("\n".join(["", *table(rows)]))
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0 if all(r.get("reproduces", True) for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
