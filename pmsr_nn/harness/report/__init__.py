"""The harness's last stage: ``report.md`` and its figures from a ``results.json``.

:mod:`.document` assembles the report from the table modules (:mod:`.method_tables`,
:mod:`.multitarget_tables`, :mod:`.bound_tables`, :mod:`.plane_report`, :mod:`.rd_maps_report`,
:mod:`.front_end_report`), the honesty flags (:mod:`.flags`) and the figures (:mod:`.figures`,
:mod:`.trajectory_figure`, :mod:`.track_figure`); :mod:`.report_cells` writes the numbers.
:mod:`.record_tables` writes the repository documents' tables from the recorded results
(:mod:`.fitee_record_tables`, :mod:`.study_record_tables`, :mod:`.bench_record_tables`,
:mod:`.msjpda_record_tables`, :mod:`.multi_record_tables`; cells by
:mod:`.record_cells`); :mod:`.record_citations` checks the figures their prose cites from a record.
Imports the earlier stages only.
"""
