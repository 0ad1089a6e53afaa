"""The text of ``pmsr methods``: each kind with the product it reads, its description and options
(:func:`catalogue`), one option a line (:func:`describe_option`)."""

from __future__ import annotations

from . import ELSEWHERE, PLUGINS, PRODUCTS, Option, method_kind, registry


def describe_option(name: str, o: Option) -> str:
    """``name: default`` and its range, choices or null meaning, in one line."""
    if o.choices:
        allowed = " | ".join(o.choices)
        when = f", read only with {o.read_when}" if o.read_when is not None else ""
        return f"{name}: {o.default} (one of {allowed}{when})"
    default = "null" if o.default is None else f"{o.default:g}" if isinstance(o.default, float) else str(o.default)
    kind = "integer" if o.kind is int else "number"
    # an open end (e.g. a probability below 1) shows as ")": "1" alone would read as allowed
    close = "]" if float(f"{o.hi:g}") == o.hi else ")"
    text = f"{name}: {default} ({kind} in [{o.lo:g}, {o.hi:g}{close}"
    text += f", or null: {o.null or 'a default taken elsewhere'}" if o.nullable else ""
    text += ", tunable" if o.tunable else ""
    text += f", read only with {o.read_when})" if o.read_when is not None else ")"
    return text


def catalogue(names: list[str] | None = None) -> list[str]:
    """The lines of ``pmsr methods``: each kind (or those ``names``) with the product it reads,
    its description and options."""
    kinds = registry()
    chosen = [method_kind(n) for n in names] if names else [kinds[k] for k in sorted(kinds)]
    lines = ["Method kinds of a scenario's 'methods:' list ({name: ..., kind: KIND, options: {...}}):", ""]
    for k in chosen:
        pooled = "; the lists pooled per receiver where the illuminator is unknown" if k.pooled_lists else ""
        lines.append(f"{k.name}  (reads {k.reads}: {PRODUCTS.get(k.reads, k.reads)}{pooled})")
        lines.append(f"    {k.description}")
        if k.name in PLUGINS:
            lines.append(f"    from: module {PLUGINS[k.name].module}, {PLUGINS[k.name]}")
        if k.needs_checkpoint:
            lines.append("    needs: checkpoint: PATH (a tracker.pt of pmsr train)")
        lines.extend(f"    {describe_option(n, o)}" for n, o in k.options.items())
        lines.append("")
    if not names:
        lines.append("Names that are not method kinds, and the kinds they mean:")
        lines.extend(f"  - {', '.join(names)}: {where}" for names, where in ELSEWHERE)
    return lines
