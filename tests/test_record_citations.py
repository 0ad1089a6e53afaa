"""Figures the documents' prose quotes from a record, cited as a link to it with the key as title
(``pmsr_nn.harness.report.record_citations``, issue 60): every citation in README.md,
evaluate/RESULTS.md and benchmarks/RESULTS.md resolves and quotes its record's value."""

from __future__ import annotations

import json

import pytest

from pmsr_nn.harness.report import record_citations as rc
from pmsr_nn.harness.report import record_tables as rt


def test_every_citation_in_the_documents_quotes_its_record():
    found = 0
    for doc in rt.DOCUMENTS:
        assert rc.problems(rt.ROOT / doc, rt.ROOT) == []
        found += len(rc.citations((rt.ROOT / doc).read_text()))
    assert found >= 20  # the documents cite; a syntax change that finds none would pass vacuously


@pytest.fixture
def repo(tmp_path):
    (tmp_path / "results").mkdir()
    (tmp_path / "results/r.json").write_text(json.dumps(
        {"cases": {"pd_0.65": {"methods": {"S-MSJPDA + gain [seed 0]": {"gospa_m": 24.349, "seconds": 0.09345}}}},
         "runs": [3.0, 1234.5], "ok": True}))
    return tmp_path


@pytest.mark.parametrize("cite, ok", [
    ('[24.3](results/r.json "cases/pd_0.65/methods/S-MSJPDA + gain [seed 0]/gospa_m")', True),
    ('[24.35](results/r.json "cases/pd_0.65/methods/S-MSJPDA + gain [seed 0]/gospa_m")', True),
    ('[24.4](results/r.json "cases/pd_0.65/methods/S-MSJPDA + gain [seed 0]/gospa_m")', False),  # wrong figure
    ('[24](results/r.json "cases/pd_0.65/methods/S-MSJPDA + gain [seed 0]/gospa_m")', True),
    ('[93.5](results/r.json "cases/pd_0.65/methods/S-MSJPDA + gain [seed 0]/seconds x 1000")', True),
    ('[93.4](results/r.json "cases/pd_0.65/methods/S-MSJPDA + gain [seed 0]/seconds x 1000")', False),
    ('[1,234.5](results/r.json "runs/1")', True),
    ('[1,234](results/r.json "runs/1")', True),  # a tie: either way
    ('[1,236](results/r.json "runs/1")', False),
    ('[3](results/r.json "runs/2")', False),  # no such index
    ('[3](results/r.json "runs/x")', False),
    ('[1](results/r.json "ok")', False),  # not a number
    ('[24.3](results/other.json "cases")', False),  # no such file
    ('[24.3](../outside.json "a")', False),  # outside the repository
])
def test_a_citation_resolves_only_to_its_records_value(repo, cite, ok):
    (repo.parent / "outside.json").write_text('{"a": 24.3}')
    doc = repo / "doc.md"
    doc.write_text(f"Some prose,\nthen a figure {cite} m.\n")
    (c,) = rc.citations(doc.read_text())
    assert c.line == 2
    assert (rc.problems(doc, repo) == []) == ok


def test_a_document_in_a_folder_links_relative_to_itself(repo):
    (repo / "sub").mkdir()
    doc = repo / "sub/doc.md"
    doc.write_text('[3.0](../results/r.json "runs/0") and [3.0](results/r.json "runs/0")\n')
    (problem,) = rc.problems(doc, repo)
    assert "no record results/r.json" in problem


@pytest.mark.parametrize("x, figure, ok", [(1.085, "1.09", True), (1.085, "1.08", True), (1.0851, "1.08", False),
                                           (-2.5, "-2", True), (-2.5, "-3", True), (2.49, "3", False), (0.5, "+1", True)])
def test_a_tie_is_rounded_either_way(x, figure, ok):
    """1.085 is stored as 1.08499...: Python formats it 1.08, its decimal text rounds half up to 1.09;
    a figure off the tie has one rounding only."""
    assert rc.quotes(x, figure) == ok


def test_the_check_command_names_a_wrong_citation(repo, monkeypatch, capsys):
    (repo / "doc.md").write_text('a figure [24.4](results/r.json "cases/pd_0.65/methods/S-MSJPDA + gain [seed 0]/gospa_m")\n')
    monkeypatch.setattr(rt, "ROOT", repo)
    monkeypatch.setattr(rt, "DOCUMENTS", ("doc.md",))
    assert rt.main(["--check"]) == 1
    assert "doc.md:1:" in capsys.readouterr().err
    (repo / "doc.md").write_text('a figure [24.3](results/r.json "cases/pd_0.65/methods/S-MSJPDA + gain [seed 0]/gospa_m")\n')
    assert rt.main(["--check"]) == 0
