"""Two evaluations side by side: which figures changed, and by how many Monte Carlo standard errors.

Takes two ``results.json`` (typically one scenario before and after a code change, or at two
seeds); gives, per case and row, the headline figures (position RMSE, OSPA, GOSPA) with their
difference in standard errors, and a count of every other number of the rows that differs (run
times left out: they are measurements of the machine, not of the code).

The standard error of a difference is ``sqrt(se_old^2 + se_new^2)``, the rule for two independent
sets of runs. With the same seed both files hold the same draws, so any difference at all comes
from the code; the ratio then says how it compares with the run-to-run spread.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from ...errors import ConfigError
from .result_rows import key_path
from .typed import Results

FIGURES = (("rmse_pos_m", "rmse_pos_se_m"), ("ospa_m", "ospa_se_m"), ("gospa_m", "gospa_se_m"))
"""The headline figures and the field holding each one's Monte Carlo standard error."""

SAME_RELATIVE = 1e-9
"""Two numbers this close (relative) are the same: float64 sums in another order differ by ~1e-15."""


@dataclass(frozen=True)
class Difference:
    """One figure of one row in both files (None where a file lacks it) and the standard error of
    their difference (None where either file holds none)."""

    case: str
    method: str
    figure: str
    old: float | None
    new: float | None
    se: float | None

    def verdict(self, threshold: float) -> str:
        """``same``, ``within error`` (under ``threshold`` standard errors), ``changed``, or
        ``changed (no s.e.)``, ``only old`` / ``only new``."""
        if self.old is None or self.new is None:
            return "only old" if self.new is None else "only new"
        if _same(self.old, self.new):
            return "same"
        if self.se is None or not self.se > 0:
            return "changed (no s.e.)"
        return "within error" if abs(self.new - self.old) < threshold * self.se else "changed"


def _same(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    if math.isinf(a) or math.isinf(b):  # inf - inf is NaN: equal infinities are the same value
        return a == b
    return abs(a - b) <= SAME_RELATIVE * max(abs(a), abs(b))


def load_results(path: str | Path) -> dict:
    """A ``results.json`` (or a folder holding one) as written by ``pmsr evaluate`` / ``pmsr merge``,
    read through the typed results (:meth:`~.typed.Results.from_dict`); a one-line error for
    anything else, naming the file and the key at fault (a figure that is not a number, a table
    that is not a table, a negative standard error, a missing key)."""
    path = Path(path)
    file = path / "results.json" if path.is_dir() else path
    try:
        res = json.loads(file.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no results.json (give a results.json or the folder pmsr evaluate wrote)") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"{file}: not a readable results.json ({type(exc).__name__})") from None
    if not isinstance(res, dict) or "cases" not in res:
        raise ConfigError(f"{file}: not the results of pmsr evaluate (no 'cases')")
    typed = Results.from_dict(res, source=str(file))
    # what every case and row pmsr evaluate writes holds (the typed results also read hand-made ones without)
    for case, c in res["cases"].items():
        if "methods" not in c:
            raise ConfigError(f"{file}: {key_path('cases', case)}: lacks the key 'methods'")
    for case, method, row in typed.rows():
        if row.rmse_pos_m is None:  # a bound's row has it too
            at = key_path(key_path(key_path("cases", case), "methods"), method)
            raise ConfigError(f"{file}: {at}: lacks the key 'rmse_pos_m' (or it is null): every row of a results.json "
                              "has its position RMSE")
    return res


def _number(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def headline(old: dict, new: dict) -> list[Difference]:
    """The headline figures of every (case, row) of either file, in the old file's order."""
    out = []
    for case in dict.fromkeys([*old["cases"], *new["cases"]]):
        rows_o = old["cases"].get(case, {}).get("methods", {})
        rows_n = new["cases"].get(case, {}).get("methods", {})
        for method in dict.fromkeys([*rows_o, *rows_n]):
            ro, rn = rows_o.get(method), rows_n.get(method)
            for figure, se_key in FIGURES:
                a = None if ro is None else _number(ro.get(figure))
                b = None if rn is None else _number(rn.get(figure))
                if a is None and b is None:
                    continue
                se_a = None if ro is None else _number(ro.get(se_key))
                se_b = None if rn is None else _number(rn.get(se_key))
                se = None if se_a is None or se_b is None else math.hypot(se_a, se_b)
                out.append(Difference(case, method, figure, a, b, se))
    return out


def _leaves(x, prefix: str = ""):
    """(dotted path, value) of every number, string and bool under ``x``."""
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _leaves(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _leaves(v, f"{prefix}[{i}]")
    else:
        yield prefix, x


def other_numbers(old: dict, new: dict) -> tuple[int, list[str]]:
    """Every other value of the rows present in both files, run times left out: how many were
    compared and the paths of those that differ."""
    compared, differ = 0, []
    for case, c in old["cases"].items():
        for method, ro in c.get("methods", {}).items():
            rn = new["cases"].get(case, {}).get("methods", {}).get(method)
            if rn is None:
                continue
            a, b = dict(_leaves(ro)), dict(_leaves(rn))
            for key in sorted(set(a) | set(b)):
                if "seconds" in key or key in {f for pair in FIGURES for f in pair}:
                    continue
                compared += 1
                va, vb = a.get(key, "<absent>"), b.get(key, "<absent>")
                na, nb = _number(va), _number(vb)
                same = _same(na, nb) if na is not None and nb is not None else va == vb
                if not same:
                    differ.append(f"{case} / {method} / {key}: {va} -> {vb}")
    return compared, differ


def _f(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g}"


def comparison_lines(old: dict, new: dict, threshold: float = 2.0, names: tuple[str, str] = ("old", "new"),
                     limit: int = 20) -> list[str]:
    """The comparison as text: a heading, the headline table, the other numbers that differ (at
    most ``limit`` listed) and one summary line."""
    lines = []
    if old.get("scenario") != new.get("scenario"):
        lines.append(f"note: different scenarios ({old.get('scenario')!r} and {new.get('scenario')!r})")
    same_draws = (old.get("seed"), old.get("mc_runs")) == (new.get("seed"), new.get("mc_runs"))
    lines.append(f"{names[0]}: seed {old.get('seed')}, {old.get('mc_runs')} runs; {names[1]}: seed {new.get('seed')}, "
                 f"{new.get('mc_runs')} runs" + ("; the same draws: any difference comes from the code" if same_draws else ""))
    diffs = headline(old, new)
    lines += ["", "| case | method | figure | old | new | new - old | in s.e. | verdict |", "|---|---|---|---:|---:|---:|---:|---|"]
    for d in diffs:
        delta = None if d.old is None or d.new is None else d.new - d.old
        z = None if delta is None or not d.se else delta / d.se
        lines.append(f"| {d.case} | {d.method} | {d.figure} | {_f(d.old)} | {_f(d.new)} | {_f(delta)} | "
                     f"{'-' if z is None else f'{z:+.1f}'} | {d.verdict(threshold)} |")
    compared, differ = other_numbers(old, new)
    lines += ["", f"other values of the rows in both files (run times left out): {compared} compared, {len(differ)} differ"]
    lines += [f"  {line}" for line in differ[:limit]]
    if len(differ) > limit:
        lines.append(f"  ... and {len(differ) - limit} more")
    counts = {}
    for d in diffs:
        counts[d.verdict(threshold)] = counts.get(d.verdict(threshold), 0) + 1
    lines += ["", "headline figures: " + ", ".join(f"{n} {v}" for v, n in counts.items())
              + f" (changed: at least {threshold:g} standard errors of the difference)"]
    return lines
