"""The documents' tables that come from a record, written from it: one command regenerates them.

A generated table sits between two marker lines in a Markdown document::

    <!-- table: NAME from evaluate/results/STUDY/results.json -->
    | ... the table, written by TABLES[NAME] ... |
    <!-- end table: NAME -->

A table that quotes several records names them all, in its function's order, separated by ", "::

    <!-- table: NAME from evaluate/results/A/results.json, evaluate/results/B/results.json -->

``TABLES`` maps each NAME to its record or records (paths relative to the repository root, which
the opening marker must name, in that order) and a function of the loaded records (one argument
per record) that returns the table's lines.
Everything between the markers is the generator's; the prose around them is the document's.

    python -m pmsr_nn.harness.report.record_tables           # rewrite every marked table
    python -m pmsr_nn.harness.report.record_tables --check   # exit 1, naming each table that differs
                                                             # and each figure the prose cites wrongly
                                                             # (:mod:`.record_citations`)

``tests/test_record_tables.py`` runs the check in the default test tier.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ...errors import ConfigError
from . import bench_record_tables as bench
from . import fitee_record_tables as fitee
from . import msjpda_record_tables as msjpda
from . import multi_record_tables as multi
from . import study_record_tables as study
from .record_citations import problems

ROOT = Path(__file__).resolve().parents[3]
DOCUMENTS = ("README.md", "evaluate/RESULTS.md", "benchmarks/RESULTS.md")
"""The documents searched for markers, relative to the repository root."""

_OPEN = re.compile(r"^<!-- table: (?P<name>[\w.-]+) from (?P<records>[^\s,]+(?:, [^\s,]+)*) -->$")
_CLOSE = "<!-- end table: {name} -->"


class TableError(ConfigError):
    """A marker without its end, an unknown table name, or a marker naming another record."""


@dataclass(frozen=True)
class Table:
    record: str | tuple[str, ...]
    """The record's path, relative to the repository root, or the paths of the records it quotes."""
    lines: Callable[..., list[str]]
    """The table's Markdown lines from the loaded records, one argument each in ``paths`` order (and,
    for the paper's columns, the paper's tables)."""

    @property
    def paths(self) -> tuple[str, ...]:
        return (self.record,) if isinstance(self.record, str) else self.record

    @property
    def source(self) -> str:
        """The records as the opening marker names them."""
        return ", ".join(self.paths)


TABLES: dict[str, Table] = {
    "baselines_envelope": Table(fitee.BASELINES, fitee.baselines_envelope),
    "baselines_literal": Table(fitee.BASELINES, fitee.baselines_literal),
    "learned_vs_bounds": Table(fitee.LEARNED_BOUNDS, fitee.learned_vs_bounds),
    "readme_three_trajectories": Table(fitee.THREE, fitee.readme_three_trajectories),
    "three_trajectories": Table(fitee.THREE, fitee.results_three_trajectories),
    "three_trajectories_learned": Table(fitee.THREE, fitee.results_learned_rows),
    "three_trajectories_whole_sequence": Table(fitee.THREE, fitee.results_whole_sequence),
    "mismatch_whole_sequence": Table(fitee.MISMATCH, fitee.mismatch_whole_sequence),
    "mismatch": Table((fitee.MISMATCH, fitee.MISMATCH_FIRST), fitee.mismatch),
    "shared_drones": Table(study.SHARED, study.shared_drones),
    "one_sky": Table(study.ONE_SKY, study.one_sky),
    "one_sky_paired_own_tracks": Table(study.ONE_SKY, study.one_sky_paired_own_tracks),
    "one_sky_paired_handed": Table(study.ONE_SKY, study.one_sky_paired_handed),
    "one_sky_quantiles": Table(study.ONE_SKY, study.one_sky_quantiles),
    "daniyan_smcphd": Table(study.SMCPHD, study.daniyan_smcphd),
    "access2019_msjpda": Table(msjpda.MSJPDA, msjpda.access2019_msjpda),
    "fm_front_end": Table(study.FM, study.fm_front_end),
    "fm_range_by_kind": Table(study.FM, study.fm_range_by_kind),
    "fm_tracking": Table(study.FM, study.fm_tracking),
    "tbd_mixed": Table(study.TBD, study.tbd_mixed),
    "jeit_pmht": Table(study.JEIT, study.jeit_pmht),
    "jeit_pmht_per_target": Table(study.JEIT, study.jeit_pmht_per_target),
    "one_sky_hybrid": Table(study.ONE_SKY_HYBRID, study.one_sky_hybrid),
    "shared_drones_hybrid": Table(study.SHARED_HYBRID, study.shared_drones_hybrid),
    "dense_crossing": Table(study.DENSE, study.dense_crossing),
    "dense_crossing_burn_in": Table(study.BURN_IN_SEED1, study.dense_crossing_burn_in),
    "ablation_dfnn_vs_mdfnn": Table(fitee.DFNN_VS_MDFNN, fitee.ablation_dfnn_vs_mdfnn),
    "ablation_sequence_size": Table(fitee.SEQUENCE_SIZE, fitee.ablation_sequence_size),
    "ablation_filter_order": Table(fitee.FILTER_ORDER, fitee.ablation_filter_order),
    "ablation_altitude": Table(fitee.ALTITUDE, fitee.ablation_altitude),
    "simulate_throughput": Table(bench.SIMULATE, bench.simulate_throughput),
    "bench_filters": Table(bench.FILTERS, bench.bench_filters),
    "bench_si_kf": Table(bench.SI_KF, bench.bench_si_kf),
    "bench_particle": Table(bench.PARTICLE, bench.bench_particle),
    "bench_learned": Table(bench.LEARNED, bench.bench_learned),
    "bench_learned_first": Table(bench.LEARNED_FIRST, bench.bench_learned_first),
    "bench_pmht": Table(bench.PMHT_BENCH, bench.bench_pmht),
    "bench_pmht_stonesoup": Table(bench.PMHT_BENCH, bench.bench_pmht_stonesoup),
    "bench_msjpda_nominal": Table(bench.MSJPDA, bench.bench_msjpda_nominal),
    "bench_msjpda_rounds": Table(bench.MSJPDA, bench.bench_msjpda_rounds),
    "bench_msjpda_exact": Table(bench.MSJPDA_EXACT, bench.bench_msjpda_exact),
    "bench_tbd": Table(bench.TBD_BENCH, bench.bench_tbd),
    "bench_harness_overhead": Table(bench.HARNESS, bench.bench_harness_overhead),
    "bench_onnx": Table(bench.ONNX, bench.bench_onnx),
    "bench_phd": Table(bench.PHD, bench.bench_phd),
    "bench_front_end": Table(bench.FRONT_END, bench.bench_front_end),
    "fault_census_round3": Table(bench.FAULT_CENSUS, bench.fault_census),
    "access2019_msjpda_initiation": Table(msjpda.MSJPDA_INITIATION, msjpda.access2019_msjpda_initiation),
    "access2019_msjpda_mbest": Table(msjpda.MSJPDA_MBEST, msjpda.access2019_msjpda_mbest),
    "access2019_msjpda_pd": Table(msjpda.MSJPDA_PD, msjpda.access2019_msjpda_pd),
    "access2019_msjpda_clutter": Table(msjpda.MSJPDA_CLUTTER, msjpda.access2019_msjpda_clutter),
    "shared_drones_bp": Table(multi.SHARED_BP, multi.shared_drones_bp),
    "dense_crossing_nebp": Table(multi.DENSE_NEBP, lambda r: multi.nebp_study(r, "S-MSJPDA (oracle births)")),
    "shared_drones_nebp": Table(multi.SHARED_NEBP, lambda r: multi.nebp_study(r, "S-MSJPDA")),
    "one_sky_nebp": Table(multi.ONE_SKY_NEBP, lambda r: multi.nebp_study(r, "S-MSJPDA (oracle births)")),
    "one_sky_hard": Table(multi.ONE_SKY_HARD, lambda r: multi.nebp_study(r, "S-MSJPDA (oracle births)")),
    "one_sky_nebp_births": Table(multi.ONE_SKY_NEBP_BIRTHS, lambda r: multi.nebp_study(r, "S-MSJPDA (oracle births)")),
    "one_sky_stonesoup": Table(multi.STONESOUP, multi.one_sky_stonesoup),
    "duplicate_free": Table((multi.DENSE_DUPLICATE_FREE, multi.SHARED_DUPLICATE_FREE, multi.DENSE_UNSCENTED,
                             multi.SHARED_UNSCENTED), multi.duplicate_free),
    "one_sky_unscented_fixes": Table((multi.ONE_SKY_MANAGED, multi.ONE_SKY_MANAGED_PMHT, multi.ONE_SKY_UNSCENTED),
                                     multi.one_sky_unscented_fixes),
    # tables that quote several records
    "readme_from_detections": Table(multi.READ_DETECTIONS_SOURCES, multi.readme_from_detections),
    "dense_crossing_bp": Table((multi.DENSE_BP, study.DENSE), multi.dense_crossing_bp),
    "one_sky_bp": Table((multi.ONE_SKY_BP, multi.ONE_SKY_BP_SECOND, multi.ONE_SKY_BP_FIRST, multi.ONE_SKY_MANAGED,
                         multi.ONE_SKY_MANAGED_FIRST),
                        multi.one_sky_bp),
    "tbd_subarea": Table((multi.TBD, multi.TBD_FIRST), multi.tbd_subarea),
    "set_tracker_diagnosis": Table(multi.SET_TRACKER_DIAGNOSIS, multi.set_tracker_diagnosis),
    "bench_learned_gpu": Table((bench.LEARNED_GPU, bench.LEARNED_GPU_HOST), bench.bench_learned_gpu),
    "bench_tbd_issue37": Table(bench.TBD_ISSUE37, bench.bench_tbd_issue37),
    "bench_tbd_issue37_snr": Table(bench.TBD_ISSUE37_SNR, bench.bench_tbd_issue37_snr),
    "fault_census_before_after": Table((bench.FAULT_CENSUS_BEFORE, bench.FAULT_CENSUS_AFTER),
                                       bench.fault_census_before_after),
    "bench_set_tracker": Table((bench.SET_TRACKER_GPU, bench.SET_TRACKER_CPU), bench.bench_set_tracker),
}


def load_record(path: str, root: Path | None = None) -> dict:
    """The record at ``path``, relative to ``root`` (default: the repository, ``ROOT``)."""
    return json.loads(((ROOT if root is None else root) / path).read_text())


def regenerate(text: str, root: Path | None = None, records: dict[str, dict] | None = None) -> tuple[str, list[str]]:
    """``text`` with every marked table rewritten from its record, and the names of the tables found.
    ``records``: loaded records by path (a cache shared across documents; filled as needed)."""
    records = {} if records is None else records
    lines = text.split("\n")
    out, names, i = [], [], 0
    while i < len(lines):
        match = _OPEN.match(lines[i])
        out.append(lines[i])
        i += 1
        if not match:
            continue
        name, source = match["name"], match["records"]
        if name not in TABLES:
            raise TableError(f"unknown table {name!r} (known: {', '.join(sorted(TABLES))})")
        table = TABLES[name]
        if table.source != source:
            raise TableError(f"table {name!r} comes from {table.source}, its marker names {source}")
        close = _CLOSE.format(name=name)
        try:
            end = lines.index(close, i)
        except ValueError:
            raise TableError(f"table {name!r}: no line {close!r} after its marker") from None
        for path in table.paths:
            if path not in records:
                records[path] = load_record(path, root)
        out += table.lines(*(records[path] for path in table.paths))
        out.append(close)
        names.append(name)
        i = end + 1
    return "\n".join(out), names


def differing(root: Path | None = None) -> list[str]:
    """``document: table`` for every generated table whose text differs from its record's."""
    root = ROOT if root is None else root
    records: dict[str, dict] = {}
    bad = []
    for doc in DOCUMENTS:
        text = (root / doc).read_text()
        new, names = regenerate(text, root, records)
        if new == text:
            continue
        old_blocks, new_blocks = blocks(text), blocks(new)
        bad += [f"{doc}: {n}" for n in names if old_blocks.get(n) != new_blocks.get(n)]
    return bad


def blocks(text: str) -> dict[str, str]:
    """Each marked table's text by name."""
    return {m["name"]: m["body"] for m in re.finditer(
        r"^<!-- table: (?P<name>[\w.-]+) from [^\n]+ -->\n(?P<body>.*?)^<!-- end table: (?P=name) -->$", text,
        re.S | re.M)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m pmsr_nn.harness.report.record_tables",
                                description="Rewrite the documents' tables from their records (or check them).")
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 naming each table that differs "
                                                        "and each cited figure that is not its record's")
    args = p.parse_args(argv)
    try:
        if args.check:
            bad = differing()
            for b in bad:
                print(f"differs from its record: {b}", file=sys.stderr)
            cited = [p for doc in DOCUMENTS for p in problems(ROOT / doc, ROOT)]
            for c in cited:
                print(f"cites another figure than its record: {c}", file=sys.stderr)
            return 1 if bad or cited else 0
        records: dict[str, dict] = {}
        texts = {doc: (ROOT / doc).read_text() for doc in DOCUMENTS}
        new = {doc: regenerate(text, ROOT, records) for doc, text in texts.items()}  # all, before writing any
    except (TableError, OSError, KeyError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for doc, (text, names) in new.items():
        if text != texts[doc]:
            (ROOT / doc).write_text(text)
        print(f"{doc}: {len(names)} table(s){' rewritten' if text != texts[doc] else ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
