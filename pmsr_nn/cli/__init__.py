"""The ``pmsr`` command: one module per command (its sub-parser and its ``cmd_*`` function).

One error path for every command: an anticipated failure (a bad recipe, path, dataset,
checkpoint or device; a file that cannot be read or written; memory) is printed as one line
``pmsr: error: ...`` naming the file, key or argument at fault, exit code 2. An unexpected
exception (a bug) prints one line with a hint, exit code 1; ``--debug`` shows its traceback.
SIGINT, SIGTERM and SIGHUP stop a command cleanly (no half-written output), with one line and
exit code ``128 + signal``.
"""

from __future__ import annotations

import argparse
import sys

from .. import __version__
from ..errors import Interrupted
from . import compare, demo, evaluate, export, front_end, info, methods, simulate, track, train
from .common import Parser, describe_error, signal_name
from .demo import DEMO_EXPECTED

__all__ = ["DEMO_EXPECTED", "build_parser", "describe_error", "main"]

COMMANDS = (simulate.add_simulate, info.add_info, train.add_train, train.add_select, track.add_track,
            export.add_export, export.add_export_onnx, evaluate.add_evaluate, front_end.add_front_end,
            methods.add_methods, evaluate.add_merge, compare.add_compare, demo.add_demo)
"""Each adds one sub-command (its parser, with ``run`` = its ``cmd_*`` function), in the order of ``pmsr --help``."""


def build_parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="pmsr",
        description="Target tracking in multistatic passive radar: simulate datasets, train and "
        "evaluate trackers. Run 'pmsr COMMAND --help' for the options of a command.",
    )
    p.add_argument("--version", action="version", version=f"pmsr_nn {__version__}")
    p.add_argument("--debug", action="store_true", help="show the traceback of an unexpected error")
    common = Parser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show the traceback of an unexpected error")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _add_parser = sub.add_parser
    sub.add_parser = lambda *a, **k: _add_parser(*a, parents=[common], **k)  # --debug after the command too
    for add in COMMANDS:
        add(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # KEY=VALUE overrides may follow options (argparse stops collecting positionals there)
        if hasattr(args, "overrides") and all("=" in e and not e.startswith("-") for e in extra):
            args.overrides = [*args.overrides, *extra]
        else:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
    from ..interrupts import signals_raise

    try:
        with signals_raise():
            return args.run(args)
    except (Interrupted, KeyboardInterrupt) as exc:
        signum = exc.signum if isinstance(exc, Interrupted) else 2
        kept = getattr(exc, "kept", None) or "no partial output was left behind"
        print(f"pmsr: interrupted by {signal_name(signum)}; {kept}", file=sys.stderr)
        return 128 + signum
    except Exception as exc:
        if args.debug:
            raise
        code, line = describe_error(exc)
        print(f"pmsr: error: {line}", file=sys.stderr)
        return code
