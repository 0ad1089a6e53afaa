"""``pmsr methods``: the method kinds a scenario's ``methods:`` list can name, with their options."""

from __future__ import annotations


def add_methods(sub) -> None:
    me = sub.add_parser("methods", help="list the method kinds a scenario can run, with their options",
                        description="Each method kind of a scenario's 'methods:' list: the product it reads, what it is, "
                        "its options with default and range; and where the trackers that are not method kinds live.")
    me.add_argument("kinds", nargs="*", help="only these kinds (default: all)")
    me.set_defaults(run=cmd_methods)


def cmd_methods(args) -> int:
    from ..methods.listing import catalogue

    print("\n".join(catalogue(args.kinds)).rstrip())
    return 0
