"""``pmsr methods``: every registered method kind with the product it reads, its description and
each option's default and range; unknown kinds named with the nearest ones, or where a tracker
that is not a method kind lives."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pmsr_nn.cli import main
from pmsr_nn.errors import ConfigError
from pmsr_nn.methods import ELSEWHERE, PRODUCTS, Option, method_kind, registry
from pmsr_nn.methods.listing import describe_option

ROOT = Path(__file__).resolve().parents[1]


def test_every_kind_is_listed_with_its_product_description_and_options(capsys):
    assert main(["methods"]) == 0
    out = capsys.readouterr().out
    blocks = {b.splitlines()[0].split()[0]: b for b in out.split("\n\n")[1:] if b and not b.startswith("Names")}
    kinds = registry()
    assert sorted(blocks) == sorted(kinds)
    for name, k in kinds.items():
        lines = blocks[name].splitlines()
        # read back, not rebuilt: the kind, its product and its description as printed
        head = re.fullmatch(r"(\S+)  \(reads (\w+): (.+?)(; the lists pooled per receiver where the illuminator "
                            r"is unknown)?\)", lines[0])
        assert head, lines[0]
        assert head[1] == name and head[2] == k.reads and head[3] == PRODUCTS[k.reads]
        assert (head[4] is not None) == k.pooled_lists
        assert k.description and lines[1].strip() == k.description
        shown = [ln.strip() for ln in lines[2:] if not ln.strip().startswith("needs:")]
        assert [_read_option(line) for line in shown] == [_expected(n, o) for n, o in k.options.items()], name
        assert ("needs: checkpoint" in blocks[name]) == k.needs_checkpoint
    # the closing list names what is not a kind (each name unknown) and the kinds it means (each known)
    tail = out.split("Names that are not method kinds, and the kinds they mean:\n", 1)[1].splitlines()
    assert len(tail) == len(ELSEWHERE)
    for line, (names, where) in zip(tail, ELSEWHERE):
        said, meant = line.removeprefix("  - ").split(": ", 1)
        assert said.split(", ") == list(names) and meant == where
        assert not set(names) & set(kinds)
        assert {w.strip(",;()") for w in where.split()} & set(kinds), where


def _read_option(line: str) -> tuple:
    """A printed option line read back into ``(name, default, kind, lo, hi, hi_included, nullable,
    tunable, read_when)`` (``kind``: ``integer`` / ``number`` / the choices; ``lo, hi`` None for
    choices; ``read_when`` the text after "read only with", or None)."""
    name, rest = line.split(": ", 1)
    default, _, spec = rest.partition(" (")
    assert spec.endswith(")"), line
    spec, _, when = spec[:-1].partition(", read only with ")
    when = when or None
    if spec.startswith("one of "):
        return name, default, tuple(spec[len("one of "):].split(" | ")), None, None, None, False, False, when
    m = re.fullmatch(r"(integer|number) in \[([^,]+), ([^\])]+)([\])])(, or null: .+?)?(, tunable)?", spec)
    assert m, line
    value = None if default == "null" else float(default)
    return name, value, m[1], float(m[2]), float(m[3]), m[4] == "]", m[5] is not None, m[6] is not None, when


def _expected(name: str, o: Option) -> tuple:
    """What :func:`_read_option` should read for option ``o`` (``:g`` prints 6 significant digits)."""
    when = None if o.read_when is None else str(o.read_when)
    if o.choices:
        return name, str(o.default), tuple(o.choices), None, None, None, False, False, when
    six = lambda v: float(f"{v:.6g}")  # noqa: E731
    default = None if o.default is None else six(o.default)
    return (name, default, "integer" if o.kind is int else "number", six(o.lo), six(o.hi), six(o.hi) == o.hi,
            o.nullable, o.tunable, when)


def test_one_kind_and_its_options():
    o = method_kind("s_msjpda").options
    assert describe_option("confirm_m", o["confirm_m"]) == \
        "confirm_m: 2 (integer in [1, 62], read only with initiation: detections)"
    assert describe_option("bias_burn_in", o["bias_burn_in"]) == \
        "bias_burn_in: 10 (integer in [0, 10000], read only with bias_window not null)"
    assert describe_option("gate_probability", o["gate_probability"]) == "gate_probability: 0.999 (number in [0.5, 1))"
    assert describe_option("initiation", o["initiation"]) == "initiation: oracle (one of oracle | detections)"
    q = method_kind("ekf").options["q"]
    assert describe_option("q", q) == "q: null (number in [0, 1e+06], or null: the recipe's q, tunable)"
    assert describe_option("x", Option(None, int, 1, 5, nullable=True)) == \
        "x: null (integer in [1, 5], or null: a default taken elsewhere)"


@pytest.mark.parametrize("name, message", [
    ("ekff", "unknown method kind 'ekff' (did you mean ekf?); known: bp, bp_3d, detect_then_track, ekf,"),
    ("smsjpda", "(did you mean s_msjpda or p_msjpda?)"),
    ("ICMB", "unknown method kind 'ICMB' (did you mean icmb"),
    ("track-before-detect", "kinds pmb, icmb, modified_icmb and detect_then_track"),
    ("gtda", "kind smc_phd (Cartesian, every pair) or smc_phd_pair (one pair's bistatic range and range-rate"),
    ("crb", "the posterior Cramer-Rao bound is kind pcrb"),
    ("zzzz", "unknown method kind 'zzzz'; known: bp, bp_3d, detect_then_track, ekf,"),
])
def test_unknown_kinds_name_the_nearest_or_where_they_live(capsys, name, message):
    with pytest.raises(ConfigError) as err:
        method_kind(name)
    assert message in str(err.value) and "\n" not in str(err.value)
    assert main(["methods", name]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err.strip() == f"pmsr: error: {err.value}"


def test_the_places_the_hints_name_exist():
    for _, where in ELSEWHERE:
        for word in where.replace(";", " ").replace(")", " ").split():
            if word.startswith(("evaluate/", "pmsr_nn/")):
                assert (ROOT / word).is_file(), word
