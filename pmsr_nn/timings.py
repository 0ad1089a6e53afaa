"""The recorded wall-clock times the documents and the CLI quote: one entry per claim, read by
``pmsr demo`` (its header), and checked against README.md by ``tests/test_readme.py``.

Each entry: ``minutes`` (the figure quoted, rounded as quoted), ``date`` and ``machine`` of the
measurement, ``conditions`` (load, threads) and ``source`` (what measured it and what is kept of it).
A re-measurement replaces the entry; the documents follow through the tests that read it.
"""

from __future__ import annotations

TIMINGS: dict[str, dict] = {
    "demo": {
        "minutes": 4.1,
        "date": "2026-12-06",
        "machine": "2-core AMD EPYC, torch 2.13.0 CPU",
        "conditions": "no other job on the machine (load average 0.8 before)",
        "source": "`python benchmarks/time_demo.py --json benchmarks/results/demo_time.json` (the whole `pmsr demo` "
                  "command on its default, commit d8bc8ed; its stage times are in the record). The earlier 2.6 "
                  "minutes (2-core Intel Xeon, 2026-11-26) kept no record. Stage hints: harness.demo.REFERENCE_SECONDS.",
    },
    "make_test": {
        "minutes": 3.0,
        "date": "2026-12-07",
        "machine": "2-core AMD EPYC, torch 2.13.0 CPU",
        "conditions": "no other job on the machine, after the one-time set-up",
        "source": "`python benchmarks/time_tests.py --json benchmarks/results/test_suite_time.json` (the default "
                  "tier as `make test` runs it: 1712 passed in 180 s; written to /tmp and copied). The 49 tests of "
                  "4 s or more (end-to-end runs, multi-process banks, the older studies' figures) moved to the "
                  "integration tier that CI runs after it (`make test-integration`, "
                  "benchmarks/results/test_integration_time.json). Earlier: 5.3 minutes for 1761 tests at 4fe3702 "
                  "and 7.3 minutes for the 1691 tests of 0f2b2ca (2026-12-07); runs of the same tier on one quiet "
                  "machine spread by about 20%. The 3.8 minutes of 2026-11-26 (2-core Intel Xeon) kept no record.",
    },
    "first_hour": {
        "minutes": 1.7,
        "date": "2026-12-07",
        "machine": "2-core AMD EPYC, torch 2.13.0 CPU",
        "conditions": "no other job on the machine (load average 1.2 before)",
        "source": "`python benchmarks/time_first_hour.py --json benchmarks/results/first_hour_time.json` (every "
                  "command of README.md's 'Your first hour' block in order, in a temporary folder, commit "
                  "bdc1868's block; the per-command times are in the record and quoted in the README). The "
                  "earlier 2.7 minutes (2-core Intel Xeon under load, 2026-11-26) kept no record.",
    },
}


def quoted_minutes(name: str) -> str:
    """The figure as the documents quote it: ``"2.6 min"``-style text, one decimal."""
    return f"{TIMINGS[name]['minutes']:.1f} min"


DEMO_EXPECTED = f"about {quoted_minutes('demo')} on 2 CPU cores"
"""What ``pmsr demo`` promises in its header and help, and README.md says once."""
