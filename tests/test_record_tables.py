"""The documents' generated tables equal what their records give (issue 60): README.md,
evaluate/RESULTS.md and benchmarks/RESULTS.md, regenerated in memory by
``pmsr_nn.harness.report.record_tables``."""

from __future__ import annotations

import json

import pytest

from pmsr_nn.harness.report import record_cells as cells
from pmsr_nn.harness.report import record_tables as rt
from pmsr_nn.harness.report import fitee_record_tables as fitee
from pmsr_nn.harness.report import study_record_tables as study


def test_every_generated_table_equals_its_record():
    assert rt.differing() == [], "run: python -m pmsr_nn.harness.report.record_tables"


def test_every_table_of_the_registry_sits_in_a_document():
    found = []
    for doc in rt.DOCUMENTS:
        found += rt.regenerate((rt.ROOT / doc).read_text())[1]
    assert sorted(found) == sorted(rt.TABLES)


def test_a_changed_figure_is_found_and_rewritten():
    """A digit changed in the document's table is reported, and regenerating puts the record's back."""
    text = (rt.ROOT / "evaluate/RESULTS.md").read_text()
    rec = rt.load_record(study.ONE_SKY)
    gospa = rec["cases"]["one_sky"]["methods"]["PMHT"]["gospa_m"]  # 128.2 in the document
    old = f"| PMHT | per pair | {gospa:.1f} ± "
    assert text.count(old) == 1
    bad = text.replace(old, f"| PMHT | per pair | {gospa + 0.1:.1f} ± ")
    new, names = rt.regenerate(bad)
    assert "one_sky" in names and new == text
    assert rt.blocks(bad)["one_sky"] != rt.blocks(text)["one_sky"]


def test_markers_must_name_the_tables_record_and_close():
    text = (rt.ROOT / "README.md").read_text()
    marker = f"<!-- table: readme_three_trajectories from {fitee.THREE} -->"
    assert marker in text
    with pytest.raises(rt.TableError, match="comes from"):
        rt.regenerate(text.replace(marker, marker.replace(fitee.THREE, study.ONE_SKY)))
    with pytest.raises(rt.TableError, match="no line"):
        rt.regenerate(text.replace("<!-- end table: readme_three_trajectories -->", ""))
    with pytest.raises(rt.TableError, match="unknown table"):
        rt.regenerate(marker.replace("readme_three_trajectories", "nothing") + "\n")


def test_the_generated_cells_read_the_record_fields_they_name():
    """Against the record read here directly: the EKF's RMSE with its below-bound star, the PF's
    diverged runs, the median over the trajectories of the seconds per run."""
    rec = json.loads((rt.ROOT / fitee.THREE).read_text())
    lines = fitee.readme_three_trajectories(rec)
    ekf = next(line for line in lines if line.startswith("| EKF |"))
    t1 = rec["cases"]["trajectory_1"]["methods"]["EKF"]
    assert t1["below_bound"] and ekf.split(" | ")[1] == f"{round(t1['rmse_pos_m'], 2):.2f}*"
    pf = next(line for line in lines if line.startswith("| particle filter"))
    assert f"({rec['cases']['trajectory_1']['methods']['PF']['diverged_runs']} of 100 runs diverged" in pf
    seconds = sorted(c["methods"]["UKF"]["seconds_per_run"] for c in rec["cases"].values())
    ukf = next(line for line in fitee.results_three_trajectories(rec) if line.startswith("| UKF |"))
    assert ukf.endswith(f"| {round(seconds[1] * 1000, 1)} |")


@pytest.mark.parametrize("x, digits, text", [(48.31, 2, "48"), (16.05, 2, "16"), (1.416, 2, "1.4"),
                                             (0.9334, 2, "0.93"), (2791.67, 3, "2792"), (0.0406, 2, "0.041")])
def test_significant_figures(x, digits, text):
    assert cells.significant(x, digits) == text


@pytest.mark.parametrize("x, text", [(15593.03, "1.56e4"), (38814.2, "3.88e4"), (0.000123, "1.23e-4")])
def test_scientific(x, text):
    assert cells.scientific(x) == text


def test_an_empty_cell_is_written_as_the_documents_write_it():
    assert cells.row(["a", "", "b"]) == "| a | | b |"


def test_a_bad_marker_writes_nothing(tmp_path, monkeypatch, capsys):
    """One-line error, exit 2, and no document rewritten, not even one before the bad marker."""
    record = tmp_path / "benchmarks/results/bench_filters.json"
    record.parent.mkdir(parents=True)
    record.write_text((rt.ROOT / "benchmarks/results/bench_filters.json").read_text())
    stale = "<!-- table: bench_filters from benchmarks/results/bench_filters.json -->\nold\n<!-- end table: bench_filters -->\n"
    (tmp_path / "a.md").write_text(stale)
    (tmp_path / "b.md").write_text("<!-- table: bench_filters from benchmarks/results/bench_filters.json -->\n")
    monkeypatch.setattr(rt, "ROOT", tmp_path)
    monkeypatch.setattr(rt, "DOCUMENTS", ("a.md", "b.md"))
    assert rt.main([]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "no line" in err
    assert (tmp_path / "a.md").read_text() == stale
    (tmp_path / "b.md").write_text("")
    assert rt.main(["--check"]) == 1 and rt.main([]) == 0
    assert "ekf: 10000 tracks" in (tmp_path / "a.md").read_text() and rt.main(["--check"]) == 0



def test_a_table_of_several_records_reads_each_of_them():
    """The README's trackers-from-detections table: each cell from the record its column names, read
    here directly (BP from the BP studies, the model-based rows from the scenarios' studies)."""
    from pmsr_nn.harness.report import multi_record_tables as multi
    lines = multi.readme_from_detections(*(rt.load_record(p) for p in multi.READ_DETECTIONS_SOURCES))
    rows = {line.split(" | ")[0][2:].split(" (")[0].strip("`"): line.split(" | ") for line in lines[2:]}
    bp = rt.load_record(multi.ONE_SKY_BP)["cases"]["one_sky"]["methods"]["BP"]
    assert rows["one_sky.yaml"][1] == f"{bp['gospa_m']:.1f} ± {bp['gospa_se_m']:.1f}"  # one scoring since the re-scoring
    pmht = rt.load_record(study.SHARED)["cases"]["three_drones"]["methods"]["PMHT from detections"]
    assert rows["shared_drones.yaml"][4] == f"{pmht['gospa_m']:.1f} ± {pmht['gospa_se_m']:.1f}"
    ghosts = rt.load_record(multi.DENSE_GHOSTS)["cases"]["dense_crossing"]["methods"]
    seed2 = ghosts["S-MSJPDA + learned gain [seed 2] + bias test"]
    assert rows["dense_crossing_ghosts.yaml"][-2].endswith(f"/ {seed2['gospa_m']:.1f} ± {seed2['gospa_se_m']:.1f}")
    nebp = rt.load_record(multi.DENSE_NEBP)["cases"]["dense_crossing"]["methods"]["NEBP [seed 1]"]
    assert rows["dense_crossing.yaml"][-1].split(" / ")[1] == f"{nebp['gospa_m']:.1f} ± {nebp['gospa_se_m']:.1f}"


def test_a_marker_of_several_records_names_them_all_in_order():
    text = (rt.ROOT / "evaluate/RESULTS.md").read_text()
    sources = rt.TABLES["dense_crossing_bp"].paths
    marker = f"<!-- table: dense_crossing_bp from {', '.join(sources)} -->"
    assert len(sources) == 2 and marker in text
    for wrong in (", ".join(reversed(sources)), sources[0]):
        with pytest.raises(rt.TableError, match="comes from"):
            rt.regenerate(text.replace(marker, f"<!-- table: dense_crossing_bp from {wrong} -->"))
    # a figure of the second record changed in the document is found and put back
    dense = rt.load_record(study.DENSE)["cases"]["dense_crossing"]["methods"]["PMHT"]
    old = f"| PMHT (recorded) | {dense['gospa_m']:.1f} ± "
    assert text.count(old) == 1
    bad = text.replace(old, f"| PMHT (recorded) | {dense['gospa_m'] + 0.1:.1f} ± ")
    assert rt.regenerate(bad)[0] == text
