"""``pmsr compare``: verdicts from the numbers and their standard errors, the other values counted,
and bad input refused in one line with nothing written."""

from __future__ import annotations

import copy
import json
import math

import pytest
from test_results import designed, sampled

from pmsr_nn.cli import main
from pmsr_nn.harness.results.compare import comparison_lines, headline, other_numbers


def test_verdicts_follow_the_difference_in_standard_errors():
    old = sampled()
    old["cases"]["c"]["methods"]["S-MSJPDA"]["gospa_se_m"] = 3.0
    new = copy.deepcopy(old)
    row = new["cases"]["c"]["methods"]["S-MSJPDA"]
    row["gospa_m"] = old["cases"]["c"]["methods"]["S-MSJPDA"]["gospa_m"] + 10.0  # se of the difference: 3 sqrt(2)
    row["rmse_pos_m"] = 53.0  # no standard error in either file
    d = {(x.method, x.figure): x for x in headline(old, new)}
    g = d["S-MSJPDA", "gospa_m"]
    assert g.se == pytest.approx(3.0 * math.sqrt(2), rel=1e-12)
    assert g.verdict(2.0) == "changed" and g.verdict(2.5) == "within error"  # 10 / 4.24 = 2.36 s.e.
    assert d["S-MSJPDA", "rmse_pos_m"].verdict(2.0) == "changed (no s.e.)"
    assert d["S-MSJPDA", "ospa_m"].verdict(2.0) == "same" and d["PCRB", "rmse_pos_m"].verdict(2.0) == "same"


def test_rows_in_one_file_only_and_the_other_values_are_counted():
    old = designed()
    new = copy.deepcopy(old)
    new["cases"]["c"]["methods"]["UKF"] = copy.deepcopy(old["cases"]["c"]["methods"]["EKF"])
    new["cases"]["c"]["methods"]["EKF"]["anees"] = 0.75  # one other value changed
    new["cases"]["c"]["methods"]["EKF"]["seconds_per_run"] = 9.0  # a run time: not counted
    assert {x.verdict(2.0) for x in headline(old, new) if x.method == "UKF"} == {"only new"}
    compared, differ = other_numbers(old, new)
    assert differ == ["c / EKF / anees: 0.5 -> 0.75"]
    assert compared == len(old["cases"]["c"]["methods"]["EKF"]) - 2  # less the run time and rmse_pos_m
    text = "\n".join(comparison_lines(old, new))
    assert "the same draws" in text and "1 differ" in text and "1 only new" in text


def test_equal_infinities_are_the_same_and_unequal_ones_differ():
    """A standard error of one run is inf in both files: not a difference (inf - inf is NaN)."""
    old = designed()
    old["cases"]["c"]["methods"]["EKF"]["anees"] = math.inf
    new = copy.deepcopy(old)
    assert other_numbers(old, new)[1] == []
    new["cases"]["c"]["methods"]["EKF"]["anees"] = -math.inf
    assert other_numbers(old, new)[1] == ["c / EKF / anees: inf -> -inf"]


def test_the_command_prints_the_table_and_refuses_what_is_not_a_results_file(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b.json"
    a.mkdir()
    (a / "results.json").write_text(json.dumps(designed()))
    b.write_text(json.dumps(designed(rmse=12.0)))
    before = sorted(p.name for p in tmp_path.rglob("*"))
    assert main(["compare", str(a), str(b)]) == 0
    assert "| c | EKF | rmse_pos_m | 10.9 | 12 | 1.1 | - | changed (no s.e.) |" in capsys.readouterr().out
    (tmp_path / "x.json").write_text("[1, 2]")
    for bad, says in ((tmp_path / "none", "no results.json"), (tmp_path / "x.json", "not the results of pmsr evaluate")):
        assert main(["compare", str(a), str(bad)]) == 2
        err = capsys.readouterr().err.strip()
        assert says in err and len(err.splitlines()) == 1
    assert main(["compare", str(a), str(b), "--threshold", "0"]) == 2
    assert sorted(p.name for p in tmp_path.rglob("*")) == sorted([*before, "x.json"])  # compare writes nothing


@pytest.mark.parametrize("edit, says", [
    (lambda r: r["cases"]["c"]["methods"]["EKF"].update(rmse_pos_m="10.9"),
     "cases.c.methods.EKF.rmse_pos_m: expected a number or null, got \"10.9\""),
    (lambda r: r["cases"]["c"]["methods"]["EKF"].update(rmse_pos_m=False),
     "cases.c.methods.EKF.rmse_pos_m: expected a number or null, got false"),
    (lambda r: r.update(cases=[r["cases"]["c"]]), "cases: expected a table, got [{"),
    (lambda r: r["cases"]["c"].update(methods="EKF"), "cases.c.methods: expected a table, got \"EKF\""),
    (lambda r: r["cases"]["c"]["methods"].update({"EKF (2)": 3}), "cases.c.methods['EKF (2)']: expected a table, got 3"),
    (lambda r: r["cases"]["c"]["methods"]["EKF"].update(mse_over_bound_se=-0.5),
     "cases.c.methods.EKF.mse_over_bound_se: expected a non-negative number, got -0.5"),
    (lambda r: r["cases"]["c"]["methods"]["EKF"].update(runs=5.5), "cases.c.methods.EKF.runs: expected an integer"),
    (lambda r: r["cases"]["c"]["methods"]["EKF"].pop("rmse_pos_m"), "cases.c.methods.EKF: lacks the key 'rmse_pos_m'"),
    (lambda r: r["cases"]["c"].pop("methods"), "cases.c: lacks the key 'methods'"),
    (lambda r: r["cases"]["c"]["pcrb"].pop("pos_m"), "cases.c.pcrb: lacks the key 'pos_m'"),
])
def test_a_hand_edited_value_is_one_line_naming_the_file_and_the_key(tmp_path, capsys, edit, says):
    """Read through the typed results: a figure that is a string or a boolean was 'only old', a table
    that is a list a bug, a negative standard error 'within error', a missing figure 'only old'."""
    good, bad = tmp_path / "old.json", tmp_path / "new.json"
    good.write_text(json.dumps(designed()))
    res = designed()
    edit(res)
    bad.write_text(json.dumps(res))
    for argv in ([str(good), str(bad)], [str(bad), str(good)]):
        assert main(["compare", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"pmsr: error: {bad}: {says}"), err
