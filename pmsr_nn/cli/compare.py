"""``pmsr compare OLD NEW``: two evaluations side by side (:mod:`pmsr_nn.harness.results.compare`)."""

from __future__ import annotations

from pathlib import Path


def add_compare(sub) -> None:
    c = sub.add_parser("compare", help="two results.json side by side: which figures changed, in standard errors",
                       description="Compare two evaluations (results.json, or the folders pmsr evaluate / pmsr merge "
                       "wrote), e.g. one scenario before and after a code change: the position RMSE, OSPA and GOSPA "
                       "of every row with the difference in Monte Carlo standard errors, and how many of the rows' "
                       "other values differ (run times left out). Writes nothing.")
    c.add_argument("old", type=Path, help="the reference results.json or its folder")
    c.add_argument("new", type=Path, help="the results.json or folder to compare with it")
    c.add_argument("--threshold", type=float, default=2.0,
                   help="standard errors of the difference from which a figure counts as changed (default 2)")
    c.set_defaults(run=cmd_compare)


def cmd_compare(args) -> int:
    from ..errors import ConfigError
    from ..harness.results.compare import comparison_lines, load_results

    if not args.threshold > 0:
        raise ConfigError(f"--threshold must be > 0 standard errors, got {args.threshold}")
    old, new = load_results(args.old), load_results(args.new)
    print("\n".join(comparison_lines(old, new, args.threshold, (str(args.old), str(args.new)))))
    return 0
