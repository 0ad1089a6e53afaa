"""The documents' tables that quote several records (:mod:`.record_tables`' markers naming more
than one: a study beside the recorded rows of the studies it shares its draws with, or a study's
earlier records), and the belief-propagation section's one-record tables. One function per table,
of the loaded records in the order its marker names them, returning the table's lines. Row labels
are the document's choice and sit here; every number is a record's."""

from __future__ import annotations

from .record_cells import fixed, pm, row, significant
from .msjpda_record_tables import MSJPDA_INITIATION
from .study_record_tables import DENSE, ONE_SKY, ONE_SKY_HYBRID, SHARED, SHARED_HYBRID

ONE_SKY_BP = "evaluate/results/one_sky_bp/results.json"
ONE_SKY_MANAGED = "evaluate/results/one_sky_managed/results.json"
ONE_SKY_MANAGED_PMHT = "evaluate/results/one_sky_managed_pmht/results.json"
ONE_SKY_UNSCENTED = "evaluate/results/one_sky_unscented_fixes/results.json"
DENSE_BP = "evaluate/results/dense_crossing_bp/results.json"
SHARED_BP = "evaluate/results/shared_drones_bp/results.json"
DENSE_GHOSTS = "evaluate/results/dense_crossing_ghosts/results.json"
STONESOUP = "evaluate/results/one_sky_stonesoup/results.json"
DENSE_DUPLICATE_FREE = "evaluate/results/dense_crossing_duplicate_free/results.json"
SHARED_DUPLICATE_FREE = "evaluate/results/shared_drones_duplicate_free/results.json"
DENSE_UNSCENTED = "evaluate/results/dense_crossing_unscented_fixes/results.json"
SHARED_UNSCENTED = "evaluate/results/shared_drones_unscented_fixes/results.json"
DENSE_NEBP = "evaluate/results/dense_crossing_nebp/results.json"
SHARED_NEBP = "evaluate/results/shared_drones_nebp/results.json"
ONE_SKY_NEBP = "evaluate/results/one_sky_nebp/results.json"
ONE_SKY_HARD = "evaluate/results/one_sky_hard/results.json"
ONE_SKY_NEBP_BIRTHS = "evaluate/results/one_sky_nebp_births/results.json"
NEBP_ROW = "NEBP [seed {seed}]"


def _methods(rec: dict) -> dict:
    (case,) = rec["cases"].values()
    return case["methods"]


def _gospa(m: dict) -> str:
    return pm(m["gospa_m"], m["gospa_se_m"])


def _shares(m: dict) -> str:
    return " / ".join(f"{100 * m[f'gospa_{k}_share']:.0f}" for k in ("localisation", "missed", "false"))


def _quantiles(m: dict, which: slice) -> str:
    """The runs' own GOSPA at the record's quantiles (25 %, median, 75 %, 90 %, worst), ``which`` of them."""
    return " / ".join(fixed(q, 1) for q in m["gospa_run_quantiles_m"][which])


def _seeds(methods: dict, name: str) -> str:
    """The three training seeds' GOSPA of a learned row, ``name`` with ``{seed}`` in it."""
    return " / ".join(_gospa(methods[name.format(seed=s)]) for s in range(3))


READ_DETECTIONS_SOURCES = (SHARED_BP, SHARED, SHARED_HYBRID, ONE_SKY_BP, ONE_SKY, ONE_SKY_HYBRID, ONE_SKY_MANAGED,
                           ONE_SKY_MANAGED_PMHT, ONE_SKY_UNSCENTED,
                           DENSE_BP, DENSE, DENSE_GHOSTS, MSJPDA_INITIATION, SHARED_NEBP, DENSE_NEBP, ONE_SKY_NEBP,
                           ONE_SKY_HARD, ONE_SKY_NEBP_BIRTHS)


def readme_from_detections(shared_bp: dict, shared: dict, shared_hybrid: dict, one_sky_bp: dict, one_sky: dict,
                           one_sky_hybrid: dict, one_sky_managed: dict, one_sky_managed_pmht: dict, one_sky_unscented: dict,
                           dense_bp: dict, dense: dict, dense_ghosts: dict, access: dict, shared_nebp: dict,
                           dense_nebp: dict, one_sky_nebp: dict, one_sky_hard: dict, one_sky_nebp_births: dict) -> list[str]:
    """The README's trackers from detections: GOSPA ± s.e. of BP (its own studies), the model-based
    rows (the scenarios' studies), the learned gain's three seeds (the hybrid, removed under issue 56:
    its records) and NEBP's (its own studies), per
    scenario, with one_sky's duplicate-free rows (linearised and unscented fix covariances) below
    its own and its hard variant (BP and NEBP alone) after them; the Access initiation study's
    nominal case (range and Doppler only) last."""
    gain = "S-MSJPDA + learned gain [seed {seed}]"
    out = ["| scenario | BP | S-MSJPDA | P-MSJPDA | PMHT | SMC-PHD + GTDA | S-MSJPDA + learned gain, seeds 0 / 1 / 2 "
           "| NEBP, seeds 0 / 1 / 2 |",
           "|---|---:|---:|---:|---:|---:|---|---|"]
    s = _methods(shared)
    out.append(row(["`shared_drones.yaml` (Pd 0.9, 10 clutter points per pair, 50 runs)", _gospa(_methods(shared_bp)["BP"]),
                    _gospa(s["S-MSJPDA from detections"]), _gospa(s["P-MSJPDA from detections"]),
                    _gospa(s["PMHT from detections"]), "-", _seeds(_methods(shared_hybrid), gain),
                    _seeds(_methods(shared_nebp), NEBP_ROW)]))
    o = _methods(one_sky)
    out.append(row(["`one_sky.yaml` (eight drones, Pd 0.85, 10 clutter points per pair, 50 runs; hybrid rows from the "
                    "record of `one_sky_hybrid.yaml`, at c270857, NEBP rows from `one_sky_nebp.yaml`, the same runs)", _gospa(_methods(one_sky_bp)["BP"]),
                    _gospa(o["S-MSJPDA"]), _gospa(o["P-MSJPDA"]), _gospa(o["PMHT"]), _gospa(o["SMC-PHD + GTDA"]),
                    _seeds(_methods(one_sky_hybrid), gain), _seeds(_methods(one_sky_nebp), NEBP_ROW)]))
    out.append(row(["`one_sky_nebp_births.yaml` (the same runs; NEBP trained on scenes with births, starts weighed)",
                    _gospa(_methods(one_sky_nebp_births)["BP"]), "-", "-", "-", "-", "-",
                    _seeds(_methods(one_sky_nebp_births), NEBP_ROW)]))
    m = _methods(one_sky_managed)
    out.append(row(["`one_sky_managed.yaml` (the same runs; S- and P-MSJPDA with the duplicate-free "
                    "management; PMHT from `one_sky_managed_pmht.yaml`)", _gospa(_methods(one_sky_bp)["BP"]), _gospa(m["S-MSJPDA (duplicate-free)"]),
                    _gospa(m["P-MSJPDA (duplicate-free)"]),
                    _gospa(_methods(one_sky_managed_pmht)["PMHT (duplicate-free)"]), "-", "-", "-"]))
    u = _methods(one_sky_unscented)
    out.append(row(["`one_sky_unscented_fixes.yaml` (the same runs; the duplicate-free management with the fix "
                    "initiator's unscented covariance)", _gospa(_methods(one_sky_bp)["BP"]),
                    *(_gospa(u[f"{name} (duplicate-free, unscented fixes)"]) for name in ("S-MSJPDA", "P-MSJPDA", "PMHT")),
                    "-", "-", "-"]))
    h = _methods(one_sky_hard)
    out.append(row(["`one_sky_hard.yaml` (one_sky's drones with Pd 0.7 and 40 clutter points per pair, 50 runs)", _gospa(h["BP"]),
                    "-", "-", "-", "-", "-", _seeds(h, NEBP_ROW)]))
    d = _methods(dense)
    out.append(row(["`dense_crossing.yaml` (Pd 0.7, 40 clutter points per pair, 10 runs)",
                    _gospa(_methods(dense_bp)["BP"]), _gospa(d["S-MSJPDA"]), _gospa(d["P-MSJPDA"]), _gospa(d["PMHT"]),
                    _gospa(d["SMC-PHD + GTDA"]), _seeds(d, gain), _seeds(_methods(dense_nebp), NEBP_ROW)]))
    g = _methods(dense_ghosts)
    out.append(row(["`dense_crossing_ghosts.yaml` (the same runs; S-MSJPDA rows with the innovation bias test)", "-",
                    _gospa(g["S-MSJPDA + bias test"]), "-", "-", "-", _seeds(g, gain + " + bias test"), "-"]))
    a = access["cases"]["nominal"]["methods"]
    out.append(row(["`access2019_msjpda_initiation.yaml`, nominal (range and Doppler only, Pd 0.8, 50 clutter points "
                    "per pair, 10 runs; BP with two-scan initiation)", _gospa(a["BP (2-scan)"]) + " †",
                    _gospa(a["S-MSJPDA from detections"]), "-", "-", "-", "-", "-"]))
    return out


def nebp_study(rec: dict, oracle: str) -> list[str]:
    """A NEBP study (dense_crossing_nebp, shared_drones_nebp, one_sky_nebp, one_sky_hard,
    one_sky_nebp_births): the row handed the births (``oracle``,
    which shows the draws are the main study's), BP and NEBP's three seeds: GOSPA ± s.e., the runs'
    median / 90 % / worst, the shares, false tracks, first track after birth, seconds per run."""
    methods = _methods(rec)
    dt = rec["settings"]["dt_s"]
    out = ["| row | GOSPA (m) ± s.e. | median / 90 % / worst run (m) | % loc. / missed / false | false tracks / run "
           "| first track after birth (s) | s / run |",
           "|---|---:|---|---|---:|---:|---:|"]
    for name in (oracle, "BP", *(NEBP_ROW.format(seed=s) for s in range(3))):
        m = methods[name]
        q = m["gospa_run_quantiles_m"]
        out.append(row([f"{name} (oracle births)" if name == oracle and "oracle" not in name else name, _gospa(m),
                        " / ".join(fixed(q[i], 1) for i in (1, 3, 4)), _shares(m), fixed(m["false_tracks_per_run"], 2),
                        fixed(m["scans_to_first_track"] * dt, 2), fixed(m["seconds_per_run"], 1)]))
    return out


def _recorded(m: dict, label: str) -> str:
    return row([f"{label} (recorded)", _gospa(m), "", "", f"{m['seconds_per_run']:.1f} (other processes)"])


def dense_crossing_bp(dense_bp: dict, dense: dict) -> list[str]:
    """BP's dense_crossing study (its rows and the earlier defaults' ablation rows) beside the recorded
    dense_crossing study's rows from detections on the same draws."""
    b, d = _methods(dense_bp), _methods(dense)
    out = ["| row | GOSPA (m) ± s.e. | median / 75 % / 90 % / worst run (m) | false tracks / run | s / run |",
           "|---|---:|---|---:|---:|"]
    for name in ("S-MSJPDA (oracle births)", "BP", "BP (second defaults)", "BP (first defaults)"):
        m = b[name]
        cells = [_gospa(m), _quantiles(m, slice(1, None))]
        if name == "BP":
            name, cells = f"**{name}**", [f"**{c}**" for c in cells]
        out.append(row([name, *cells, fixed(m["false_tracks_per_run"], 2), fixed(m["seconds_per_run"], 1)]))
    out += [_recorded(d["SMC-PHD + GTDA"], "SMC-PHD + GTDA"), _recorded(d["S-MSJPDA"], "S-MSJPDA"),
            _recorded(d["PMHT"], "PMHT")]
    return out


def shared_drones_bp(rec: dict) -> list[str]:
    """BP's shared_drones study: each row's GOSPA, its runs' median / 90 % / worst, shares, false
    tracks, first track after birth and seconds per run (the record's S-MSJPDA is handed the births)."""
    methods = _methods(rec)
    dt = rec["settings"]["dt_s"]
    out = ["| row | GOSPA (m) ± s.e. | median / 90 % / worst run (m) | % loc. / missed / false | false tracks / run "
           "| first track after birth (s) | s / run |",
           "|---|---:|---|---|---:|---:|---:|"]
    for name, label in (("S-MSJPDA", "S-MSJPDA (oracle births)"), ("BP", "**BP**"),
                        ("BP (second defaults)", "BP (second defaults)"), ("BP (first defaults)", "BP (first defaults)")):
        m = methods[name]
        q = m["gospa_run_quantiles_m"]
        out.append(row([label, f"**{_gospa(m)}**" if name == "BP" else _gospa(m),
                        " / ".join(fixed(q[i], 1) for i in (1, 3, 4)), _shares(m), fixed(m["false_tracks_per_run"], 2),
                        fixed(m["scans_to_first_track"] * dt, 2), fixed(m["seconds_per_run"], 1)]))
    return out


def duplicate_free(dense: dict, shared: dict, dense_unscented: dict, shared_unscented: dict) -> list[str]:
    """The duplicate-free management on dense_crossing and shared_drones: per study, the row handed
    the births, then S-, P-MSJPDA and PMHT with the default management and beneath each the
    duplicate-free one, then that with the unscented fix covariance (its own record; GOSPA, the
    runs' median / 90 % / worst, shares, false tracks, first track after birth, seconds per run)."""
    out = ["| study | row | GOSPA (m) ± s.e. | median / 90 % / worst run (m) | % loc. / missed / false "
           "| false tracks / run | first track after birth (s) | s / run |",
           "|---|---|---:|---|---|---:|---:|---:|"]
    studies = (("dense_crossing (10 runs)", dense, dense_unscented, "S-MSJPDA (oracle births)",
                ("S-MSJPDA", "P-MSJPDA", "PMHT")),
               ("shared_drones (50 runs)", shared, shared_unscented, "S-MSJPDA",
                ("S-MSJPDA from detections", "P-MSJPDA from detections", "PMHT from detections")))
    for study, rec, unscented, oracle, defaults in studies:
        methods, dt = {**_methods(rec), **_methods(unscented)}, rec["settings"]["dt_s"]
        names = [(oracle, "S-MSJPDA (oracle births)")]
        for name in defaults:
            tracker = name.split(" ")[0]
            names += [(name, tracker), (f"{tracker} (duplicate-free)", f"{tracker} (duplicate-free)"),
                      (f"{tracker} (duplicate-free, unscented fixes)", f"{tracker} (duplicate-free, **unscented fixes**)")]
        for name, label in names:
            m = methods[name]
            q = m["gospa_run_quantiles_m"]
            out.append(row([study, label, _gospa(m), " / ".join(fixed(q[i], 1) for i in (1, 3, 4)), _shares(m),
                            fixed(m["false_tracks_per_run"], 2), fixed(m["scans_to_first_track"] * dt, 2),
                            fixed(m["seconds_per_run"], 1)]))
    return out


def one_sky_stonesoup(rec: dict) -> list[str]:
    """Stone Soup's JPDA on one_sky's first 10 runs beside BP (its second defaults)."""
    methods = _methods(rec)
    out = ["| row | GOSPA (m) ± s.e. | median / 75 % / 90 % / worst run (m) | % loc. / missed / false | false tracks / run "
           "| s / run |",
           "|---|---:|---|---|---:|---:|"]
    for name, label in (("BP", "BP (second defaults)"), ("Stone Soup JPDA", "Stone Soup JPDA")):
        m = methods[name]
        out.append(row([label, _gospa(m), _quantiles(m, slice(1, None)), _shares(m),
                        fixed(m["false_tracks_per_run"], 2), fixed(m["seconds_per_run"], 1)]))
    return out


SET_TRACKER_DIAGNOSIS = tuple(f"evaluate/results/set_tracker_diagnosis/s{seed}_r{rounds}.json"
                              for seed in range(3) for rounds in (0, 1))


def set_tracker_diagnosis(*records: dict) -> list[str]:
    """evaluate/set_tracker_diagnosis.py's stages per seed and re-association rounds (one record
    each, ``SET_TRACKER_DIAGNOSIS``'s order; the script left the package with the set tracker under
    issue 56 and is at commit 4699b3d): GOSPA beside the empty set's, missed and false per
    window, the seeds' and the association's shares, position errors, existence probabilities."""
    (empty,) = {round(r["gospa_empty_set_m"]) for r in records}
    out = [f'| seed, re-association rounds | GOSPA (m), "no target" {empty} | missed / false per window '
           "| seeds that are a target's detection (base rate "
           f"{fixed(_mean([r['base_rate']['mean'] for r in records]), 2)}) "
           "| own share of a matched query's chosen weight | position error median / p90 (m): start, refined "
           "| same refinement on the target's own detections: median / p90 (m) | existence p: matched / unmatched |",
           "|---|---:|---|---:|---:|---|---|---|"]
    for path, r in zip(SET_TRACKER_DIAGNOSIS, records):
        seed = path.rsplit("/s", 1)[1].split("_")[0]

        def mp(key: str) -> str:
            return f"{r[key]['median']:.0f} / {r[key]['p90']:.0f}"
        out.append(row([f"{seed}, {r['reassociate']}", f"{r['gospa_m']:.0f}",
                        f"{r['missed_per_window']:.2f} / {r['false_per_window']:.2f}", fixed(r["seed_is_target"]["mean"], 2),
                        fixed(r["own_weight_share"]["mean"], 2), f"{mp('error_start_m')}, {mp('error_refined_m')}",
                        mp("error_true_association_m"), f"{r['p_matched']['mean']:.2f} / {r['p_unmatched']['mean']:.2f}"]))
    return out


def _mean(xs: list[float]) -> float:
    return sum(xs) / len(xs)


ONE_SKY_BP_SECOND = "evaluate/results/history/one_sky_bp_c9234c4.json"
ONE_SKY_BP_FIRST = "evaluate/results/history/one_sky_bp_ed6bff1.json"
"""one_sky_bp's two previous records (BP's second and first defaults), as git held them at c9234c4
and ed6bff1."""
ONE_SKY_MANAGED_FIRST = "evaluate/results/history/one_sky_managed_a5ceb4a.json"
"""one_sky_managed's previous record (S-MSJPDA with the duplicate-free management before its
existence deletion), as git held it at a5ceb4a."""


def one_sky_bp(current: dict, second: dict, first: dict, managed: dict, managed_first: dict) -> list[str]:
    """BP's one_sky study: its record's rows, BP of the two earlier records (the earlier defaults,
    restored from git), and S- and P-MSJPDA with the duplicate-free management (its own record, and
    S-MSJPDA's previous one without the existence deletion)."""
    dt = current["settings"]["dt_s"]
    now = _methods(current)

    def cells(m: dict, seconds: str, bold: bool = False) -> list[str]:
        c = [_gospa(m), _quantiles(m, slice(1, None)), _shares(m), fixed(m["false_tracks_per_run"], 2),
             fixed(m["confirmed_tracks_per_target"], 2), fixed(m["scans_to_first_track"] * dt, 2), seconds]
        if bold:
            c = [f"**{x}**" if i in (0, 1, 3, 5) else x for i, x in enumerate(c)]
        return c

    then = _methods(second)
    out = ["| row | GOSPA (m) ± s.e. | median / 75 % / 90 % / worst run (m) | % loc. / missed / false | false tracks / run "
           "| tracks / drone | first track after birth (s) | s / run |",
           "|---|---:|---|---|---:|---:|---:|---:|",
           row(["S-MSJPDA (oracle births)", *cells(now["S-MSJPDA (oracle births)"],
                                                   fixed(now["S-MSJPDA (oracle births)"]["seconds_per_run"], 1))]),
           row(["**BP**", *cells(now["BP"], fixed(now["BP"]["seconds_per_run"], 1), bold=True)]),
           row(["BP (second defaults), the previous record",
                *cells(then["BP"], f"{then['BP']['seconds_per_run']:.1f} (then; S-MSJPDA "
                                   f"{then['S-MSJPDA']['seconds_per_run']:.1f})")]),
           row(["BP (first defaults), the record before", *cells(_methods(first)["BP"], "(other processes)")]),
           row(["S-MSJPDA", *cells(now["S-MSJPDA"], fixed(now["S-MSJPDA"]["seconds_per_run"], 1))]),
           *(row([f"{name} (duplicate-free), `one_sky_managed.yaml`",
                  *cells(m, f"{m['seconds_per_run']:.1f} (beside its twin)")])
             for name in ("S-MSJPDA", "P-MSJPDA") for m in [_methods(managed)[f"{name} (duplicate-free)"]]),
           row(["S-MSJPDA (duplicate-free, no existence deletion), the previous record",
                *cells(_methods(managed_first)["S-MSJPDA (duplicate-free)"], "(other processes)")])]
    return out


def one_sky_unscented_fixes(managed: dict, managed_pmht: dict, unscented: dict) -> list[str]:
    """S-, P-MSJPDA and PMHT with the duplicate-free management on one_sky, each with the fix
    initiator's linearised covariance (one_sky_managed's and one_sky_managed_pmht's records) and
    beneath it with the unscented one (one_sky_unscented_fixes')."""
    dt = unscented["settings"]["dt_s"]
    out = ["| row | fix covariance | GOSPA (m) ± s.e. | median / 75 % / 90 % / worst run (m) | % loc. / missed / false "
           "| false tracks / run | tracks / drone | first track after birth (s) | s / run |",
           "|---|---|---:|---|---|---:|---:|---:|---:|"]
    before = {**_methods(managed), **_methods(managed_pmht)}
    after = _methods(unscented)
    for name in ("S-MSJPDA", "P-MSJPDA", "PMHT"):
        for label, m in (("linearised", before[f"{name} (duplicate-free)"]),
                         ("**unscented**", after[f"{name} (duplicate-free, unscented fixes)"])):
            out.append(row([f"{name} (duplicate-free)", label, _gospa(m), _quantiles(m, slice(1, None)), _shares(m),
                            fixed(m["false_tracks_per_run"], 2), fixed(m["confirmed_tracks_per_target"], 2),
                            fixed(m["scans_to_first_track"] * dt, 2), fixed(m["seconds_per_run"], 1)]))
    return out


TBD = "evaluate/results/remotesensing2020_icmb/results.json"
TBD_FIRST = "evaluate/results/history/remotesensing2020_icmb_b77ce5e.json"
"""The TBD study's first recording (the seed's SNR estimate; as git held it at b77ce5e, before the
record's layout moved each map row's figures under ``tbd``)."""


def tbd_subarea(current: dict, first: dict) -> list[str]:
    """The sub-area study (the seed's Table 2): power ratio, seconds per run and detected-frame
    rate at the table's frame, ours (the first recording's in brackets) beside the seed's."""
    paper = current["reference"]["subarea"]["table"]
    now, then = current["cases"]["mixed"]["methods"], first["cases"]["mixed"]["methods"]
    out = ["| sub-area | power ratio % (ours / seed) | s per run (ours / seed) | detected % frame 15 (ours / seed) |",
           "|---|---|---|---|"]
    for i, size in enumerate(paper["size"]):
        name = {"5x5": "modified ICMB", "full": "modified ICMB full map"}.get(size, f"modified ICMB {size}")
        m, old = now[name], then[name]

        def secs(x: float) -> str:
            return fixed(x, 2 if x < 10 else 1)
        out.append(row(["whole map" if size == "full" else size,
                        f"{significant(100 * m['tbd']['power_ratio'], 3)} / {paper['power_ratio_pct'][i]}",
                        f"{secs(m['seconds_per_run'])} ({secs(old['seconds_per_run'])}) / {paper['computation_time_s'][i]}",
                        f"{100 * m['tbd']['detected_rate_table_frame']:.0f} ({100 * old['detected_rate_table2_frame']:.0f}) "
                        f"/ {paper['detected_frame_rate_pct'][i]}"]))
    return out
