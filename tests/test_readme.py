"""Every command of the documents works, and every link of them stays inside the repository.

The documents are ``README.md``, ``docs/*.md`` and ``evaluate/README.md``. Each ``pmsr`` / ``python``
command found in them is run on a tiny configuration (fewer tracks, epochs and Monte Carlo runs;
nothing else changed) in a sandbox folder that links the repository's `datasets/`, `train/`,
`models/` and `evaluate/`.

A command with placeholders (``RECIPE.yaml``, ``DIR``, ``[--mc-runs N]``) is parsed by the
``pmsr`` parser and its options checked. A command found in a document that no rule below covers
fails :func:`test_every_readme_command_has_a_tiny_configuration`: a new command in a document needs
its tiny configuration here. Long studies run with one Monte Carlo run in the slow tier.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from pmsr_nn.cli import DEMO_EXPECTED, build_parser, main
from pmsr_nn.timings import TIMINGS

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "evaluate" / "README.md"]
"""The documents whose commands are run (the recorded results and model cards hold records, not recipes)."""
README = (ROOT / "README.md").read_text()
LINKED = ("datasets", "train", "models", "evaluate")

TINY_TRAIN = ["data.tracks=24", "data.steps=120", "data.window=60", "data.batch_size=16", "trainer.max_epochs=1",
              "trainer.train_batches_per_epoch=2", "trainer.val_batches=1", "trainer.progress=false"]
"""A training run in seconds: 24 tracks of 120 scans, windows of 60 (room for a filter order of 30)."""


def readme_commands(text: str | None = None) -> list[str]:
    """Every ``pmsr`` / ``python`` command of ``text`` (default: every document, in order): lines of
    ```bash blocks (comments cut, lines ending in a backslash joined to the next) and inline code
    spans that start with ``pmsr `` or ``python ``, in order, without repeats."""
    texts = [text] if text is not None else [d.read_text() for d in DOCUMENTS]
    found = []
    for body in texts:
        for block in re.findall(r"```bash\n(.*?)```", body, flags=re.S):
            for line in re.sub(r"\\\n\s*", " ", block).splitlines():
                line = re.split(r"\s+#", line, maxsplit=1)[0].strip()
                found += [part.strip() for part in line.split(", ")] if line.startswith("pmsr --help") else [line]
        found += re.findall(r"`((?:pmsr|python) [^`]+)`", body)
    # "pmsr train" alone names a command in prose; "pmsr demo" runs in tests/test_demo.py
    return list(dict.fromkeys(c for c in found if c.startswith(("pmsr ", "python ")) and len(c.split()) > 2
                              or c == "pmsr --help"))


def first_hour_block() -> list[str]:
    section = README.split("## Your first hour", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, flags=re.S).group(1)
    return [re.split(r"\s+#", line, maxsplit=1)[0].strip() for line in block.splitlines() if line.strip()]


_PLACEHOLDER = re.compile(r"\[.*|\.\.\.|[A-Z][A-Z_]*(/[A-Z]+)?(\.[a-z0-9]+)?|data/SOME_DATASET")


def has_placeholder(command: str) -> bool:
    return any(_PLACEHOLDER.fullmatch(tok) for tok in command.split())


@dataclass
class Rule:
    """How a README command runs small: ``pattern`` matches it; ``tiny(argv) -> argv`` shrinks it;
    ``setup``: commands (argv lists, as given, already tiny) or callables run first; ``slow``: only in the slow tier;
    ``integration``: in the integration tier (4 s or more, run by CI after the default tier);
    ``refused``: an example of what pmsr refuses (exit code 2 expected); ``own_process``: run as
    ``python -m pmsr_nn.cli`` (DDP starts its workers by re-running the command line, which
    in-process would be pytest's)."""

    pattern: str
    tiny: callable = lambda argv: argv
    setup: list[list[str]] = field(default_factory=list)
    slow: bool = False
    integration: bool = False
    refused: bool = False
    own_process: bool = False


def _mc1(argv):
    return _set(argv, "--mc-runs", "1")


def _set(argv, option, value):
    argv = list(argv)
    if option in argv:
        argv[argv.index(option) + 1] = value
    else:
        argv += [option, value]
    return argv


def _train_tiny(argv):
    return [*argv, *TINY_TRAIN]


SMOKE = ["train", "train/smoke.yaml", "--out", "runs/smoke", "trainer.max_epochs=1"]
MDFNN = ["train", "train/mdfnn.yaml", "--out", "runs/mdfnn", *TINY_TRAIN]
FITEE = ["simulate", "datasets/fitee2023_ca.yaml", "--out", "data/fitee", "--tracks", "30", "--seed", "7"]


def tiny_blocks_scenario() -> None:
    """``tiny/drones.yaml``: evaluate/shared_drones.yaml with its EKF and UKF rows, in blocks of
    one run (so two runs make two shards); in a folder beside ``evaluate/`` so that its relative
    paths still resolve."""
    import yaml

    scenario = yaml.safe_load((ROOT / "evaluate/shared_drones.yaml").read_text())
    scenario["block_runs"] = 1
    scenario["methods"] = [m for m in scenario["methods"] if m["kind"] in ("ekf", "ukf")]
    assert len(scenario["methods"]) == 2
    Path("tiny").mkdir(exist_ok=True)
    Path("tiny/drones.yaml").write_text(yaml.safe_dump(scenario))


SHARDS = [tiny_blocks_scenario] + [["evaluate", "tiny/drones.yaml", "--out", f"runs/s{i}", "--mc-runs", "2", "--shard",
                                    f"{i}/2", "--quiet"] for i in (1, 2)]
STUDIES = ("fitee2023_mismatch", "one_sky", "remotesensing2020_icmb", "jeit2021_pmht", "fm_front_end", "daniyan_smcphd",
           "daniyan_smcphd_signals", "access2019_msjpda", "access2019_msjpda_pd", "access2019_msjpda_mbest",
           "access2019_msjpda_clutter", "access2019_msjpda_initiation", "dense_crossing", "one_sky_bp",
           "dense_crossing_bp", "shared_drones_bp", "one_sky_stonesoup", "dense_crossing_nebp", "one_sky_hard")
TINY_SCENES = ["optim.steps=2", "optim.val_every=1", "optim.val_scenes=2", "optim.batch_size=2", "scenes.targets=[2,2]"]
"""A tracker on detections trained in seconds: two steps of two scenes of two targets."""

RULES = [
    Rule(r"pmsr simulate datasets/fitee2023_ca\.yaml --out data/fitee --tracks 2000 --seed 7",
         lambda a: _set(a, "--tracks", "30")),
    Rule(r"pmsr simulate datasets/fitee2023_ca\.yaml (--variant literal --out data/literal|--out runs/more --tracks 200)",
         lambda a: _set(a, "--tracks", "30")),
    Rule(r"pmsr info data/fitee --verify --plot data/fitee\.png", setup=[FITEE]),
    Rule(r"pmsr train train/mdfnn\.yaml --out runs/mdfnn( trainer\.max_epochs=60 model\.filter_order=30)?", _train_tiny),
    Rule(r"pmsr train --resume --out runs/mdfnn", setup=[MDFNN]),
    Rule(r"pmsr train train/mdfnn\.yaml --out runs/ddp trainer\.devices=2 trainer\.strategy=ddp", _train_tiny, slow=True,
         own_process=True),
    Rule(r"pmsr track --checkpoint runs/mdfnn/tracker\.pt --input data/fitee --split test --out runs/est\.h5",
         setup=[FITEE, MDFNN]),
    Rule(r"pmsr export-onnx --checkpoint runs/mdfnn/tracker\.pt --out runs/mdfnn\.onnx", setup=[MDFNN]),
    # Stone Soup rows through the harness run in-process in tests/test_stonesoup_interop.py
    Rule(r"pmsr evaluate evaluate/stonesoup_jpda\.yaml --out runs/\w+", _mc1, slow=True),
    # every tracker of the package on one run (PMHT from detections alone takes ~15 s): the slow tier
    Rule(r"pmsr evaluate evaluate/shared_drones\.yaml --out runs/\w+", _mc1, slow=True),
    # The first hour runs this scenario (--methods, --checkpoint); as written, with the released networks:
    Rule(r"pmsr evaluate evaluate/fitee2023_three_trajectories\.yaml --out runs/eval", _mc1, slow=True),
    # ... with your own network: that row alone, on one run
    Rule(r"pmsr evaluate evaluate/fitee2023_three_trajectories\.yaml --out runs/eval --mc-runs 20 "
         r"--checkpoint MDFNN=runs/mdfnn/tracker\.pt", lambda a: _set(_mc1(a), "--methods", "MDFNN"), setup=[MDFNN],
         integration=True),
    # ... on another seed's draws: the EKF row on one run
    Rule(r"pmsr evaluate evaluate/fitee2023_three_trajectories\.yaml --out runs/eval_seed1 --seed 1",
         lambda a: _set(_mc1(a), "--methods", "EKF"), integration=True),
    # ... sharded: the EKF row on two blocks of 10 runs, one per shard
    # (shards and their merge are checked in-process in tests/test_harness.py: these three run in the slow tier)
    Rule(r"pmsr evaluate evaluate/fitee2023_three_trajectories\.yaml --out runs/s([12]) --shard \1/2",
         lambda a: _set(_set(a, "--mc-runs", "20"), "--methods", "EKF"), slow=True),
    Rule(r"pmsr evaluate evaluate/(" + "|".join(STUDIES) + r")\.yaml( --mc-runs \d+)? --out runs/\w+", _mc1, slow=True),
    # one-run blocks joined into calls of several runs: the EKF and UKF rows on two runs in one call
    Rule(r"pmsr evaluate evaluate/one_sky\.yaml --out runs/one_sky --batch-runs 10",
         lambda a: _set(_set(_set(a, "--mc-runs", "2"), "--methods", "EKF,UKF"), "--batch-runs", "2"), integration=True),
    Rule(r"pmsr merge runs/s1 runs/s2 --out runs/eval", setup=SHARDS, slow=True),
    # a bank (tests/test_block_bank.py checks it in-process): the EKF row on two blocks of 10 runs
    Rule(r"pmsr evaluate evaluate/fitee2023_three_trajectories\.yaml --out runs/bank --per-block",
         lambda a: _set(_set(a, "--mc-runs", "20"), "--methods", "EKF"), slow=True),
    Rule(r"pmsr merge runs/bank --out runs/eval_banked", slow=True, setup=[tiny_blocks_scenario, [
        "evaluate", "tiny/drones.yaml", "--out", "runs/bank", "--mc-runs", "2", "--per-block", "--quiet"]]),
    Rule(r"pmsr merge s1 s2 --out s1", refused=True, slow=True,
         setup=[a if callable(a) else [*a[:3], a[3].replace("runs/", ""), *a[4:]] for a in SHARDS]),
    Rule(r"pmsr track --checkpoint runs/smoke/tracker\.pt --input z\.csv --out z\.csv", refused=True,
         setup=[SMOKE, ["simulate", "datasets/fitee2023_ca.yaml", "--out", "data/z", "--tracks", "3", "--quiet"],
                ["export", "data/z", "--out", "z.csv"]]),
    Rule(r"pmsr front-end iq\.h5 --settings evaluate/fm_front_end\.yaml --out runs/iq",
         setup=[["python", "evaluate/make_fm_recording.py", "--out", "iq.h5", "--cpis", "2"]], integration=True),
    Rule(r"pmsr train train/smoke\.yaml --out runs/smoke", lambda a: [*a, "trainer.max_epochs=1"]),
    Rule(r"pmsr select train/mdfnn\.yaml --out runs/select --members 10",
         lambda a: [*_set(a, "--members", "2"), "--fresh-tracks", "2", *TINY_TRAIN]),
    Rule(r"pmsr track --checkpoint runs/smoke/tracker\.pt --input runs/z\.csv --out runs/est\.csv",
         setup=[SMOKE, ["simulate", "datasets/fitee2023_ca.yaml", "--out", "data/z", "--tracks", "3", "--quiet"],
                ["export", "data/z", "--out", "runs/z.csv"]]),
    Rule(r"pmsr --help|pmsr simulate --help"),
    Rule(r"pmsr methods( \w+)*"),
    # Scripts: their own tests cover them; here their options must exist (`--help` lists them).
    Rule(r"python (evaluate|benchmarks)/\w+\.py( evaluate/\w+\.yaml)?( --\S+( [^-\s]\S*)*)*"),
    Rule(r"pmsr train train/nebp(_one_sky)?\.yaml --out runs/nebp(_one_sky)?_s0 seed=0", lambda a: [*a, *TINY_SCENES, "scenes.window=12",
                                                                            "optim.skip_scans=3"]),
]


def rule_for(command: str) -> Rule | None:
    hits = [r for r in RULES if re.fullmatch(r.pattern, command)]
    assert len(hits) <= 1, f"README command {command!r} matches {len(hits)} rules"
    return hits[0] if hits else None


def test_every_readme_command_has_a_tiny_configuration():
    commands = readme_commands()
    assert len(commands) > 60  # the extraction works (the documents have about 70)
    missing = [c for c in commands if not has_placeholder(c) and rule_for(c) is None
               and c not in first_hour_block() and not c.startswith("pmsr demo")]
    assert not missing, f"README commands without a tiny configuration in tests/test_readme.py: {missing}"


def _subparser(name: str):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return sub.choices.get(name)


@pytest.mark.parametrize("command", [c for c in readme_commands() if c.startswith("pmsr ")])
def test_readme_pmsr_command_parses_and_names_existing_files(command):
    """The parser takes it (placeholders: every option exists), and repository inputs exist."""
    argv = shlex.split(command)[1:]
    if has_placeholder(command):
        sub = _subparser(argv[0])
        assert sub is not None or argv[0].startswith("-"), f"no command {argv[0]!r}"
        known = {s for a in (sub or build_parser())._actions for s in a.option_strings}
        for tok in re.findall(r"--[a-z][a-z-]*", command):
            assert tok in known, f"{command!r}: {tok} is not an option of pmsr {argv[0]}"
        return
    if "--help" in argv:
        with pytest.raises(SystemExit) as exit_:
            build_parser().parse_args(argv)
        assert exit_.value.code == 0
        return
    _, extra = build_parser().parse_known_args(argv)  # an error exits with code 2 and fails the test
    assert all(re.fullmatch(r"[a-z_.]+=\S+", e) for e in extra), f"{command!r}: not understood: {extra}"
    for tok in argv:
        if tok.startswith(tuple(f"{d}/" for d in LINKED)):
            assert (ROOT / tok).exists(), f"{command!r}: {tok} does not exist"


@pytest.fixture
def sandbox(tmp_path, monkeypatch):
    for name in LINKED:
        (tmp_path / name).symlink_to(ROOT / name)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def run(argv: list[str], own_process: bool = False) -> None:
    """One command in the sandbox (``pmsr``: in-process unless ``own_process``; ``python``: a subprocess)."""
    if argv[0] == "python" or own_process:
        command = [sys.executable, *argv[1:]] if argv[0] == "python" else [sys.executable, "-m", "pmsr_nn.cli", *argv]
        proc = subprocess.run(command, capture_output=True, text=True, timeout=600,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert proc.returncode == 0, proc.stderr[-2000:]
        return
    assert main(argv) == 0, f"pmsr {' '.join(argv)} failed"


@pytest.mark.slow  # the block's commands each run in the default tier (test_readme_command_runs_on_a_tiny_configuration); this runs them in sequence
def test_the_first_hour_runs_as_written(sandbox):
    """The README's 'Your first hour' block in order, with 1 Monte Carlo run and 1-2 epochs."""
    for command in first_hour_block():
        argv = shlex.split(command)[1:]
        if argv[0] == "evaluate":
            argv = _mc1(argv)
        if argv[0] == "train":
            argv = [*argv, "trainer.max_epochs=2"]
        run(argv)
        out = argv[argv.index("--out" if "--out" in argv else "--plot") + 1]
        assert (sandbox / out).exists(), f"{command!r} wrote no {out}"
    report = (sandbox / "runs/first/eval/report.md").read_text()
    assert "| MDFNN |" in report and "runs/smoke/tracker.pt" in (sandbox / "runs/first/eval/results.json").read_text()
    assert "| EKF |" in report and "| DFNN |" not in report  # --methods ran the rows it names, no others
    assert "| Stone Soup JPDA |" in (sandbox / "runs/first/stonesoup/report.md").read_text()
    # outputs under runs/, and the training data pmsr train simulates in its cache (data/): nothing else
    assert sorted(p.name for p in sandbox.iterdir()) == sorted([*LINKED, "data", "runs"])


def test_the_first_hour_writes_only_under_runs():
    """Every output of the block is a path under ``runs/`` (ignored by git), so a newcomer's clone stays clean."""
    outputs = []
    for command in first_hour_block():
        argv = shlex.split(command)
        outputs += [argv[i + 1] for i, a in enumerate(argv[:-1]) if a in ("--out", "--plot")]
    assert len(outputs) == len(first_hour_block())  # one output each (info: its --plot)
    assert all(o.startswith("runs/") for o in outputs), outputs
    ignored = (ROOT / ".gitignore").read_text().splitlines()
    assert "/runs/" in ignored and "/data/" in ignored  # data/: pmsr train's cache of the data it simulates


def test_the_readme_states_the_demo_time_the_demo_promises():
    """One figure for `make demo`: the text `pmsr demo` prints (DEMO_EXPECTED), once, and no other time
    beside it; `make test` has one figure of its own."""
    assert README.count(DEMO_EXPECTED) == 1
    start = README.index("`make demo` runs `pmsr demo`")
    paragraph = README[start:README.index("\n\n", start)]
    assert DEMO_EXPECTED in paragraph
    assert not re.search(r"\d\s*(min|minutes|s)\b", paragraph.replace(DEMO_EXPECTED, "")
                         .replace(TIMINGS["demo"]["date"], "")), paragraph
    make_test = next(line for line in README.splitlines() if line.startswith("make test "))
    assert re.findall(r"\d+(?:\.\d+)? minutes", make_test) == [f"{TIMINGS['make_test']['minutes']} minutes"], make_test
    assert TIMINGS["make_test"]["date"] in make_test and TIMINGS["demo"]["date"] in paragraph


def test_the_first_hour_time_is_the_recorded_one():
    """The 'Your first hour' block's total is the one of pmsr_nn/timings.py, with its date."""
    block = README[README.index("## Your first hour"):README.index("## Documentation")]
    assert re.findall(r"(\d+(?:\.\d+)?) minutes in all", block) == [f"{TIMINGS['first_hour']['minutes']}"], block
    assert f"Measured once, {TIMINGS['first_hour']['date']}" in block


@pytest.mark.parametrize("name, record", [("demo", "demo_time.json"), ("make_test", "test_suite_time.json"),
                                          ("first_hour", "first_hour_time.json")])
def test_each_quoted_time_is_its_records(name, record):
    """pmsr_nn/timings.py quotes each time as its benchmark recorded it (minutes to one decimal, date)."""
    rec = json.loads((ROOT / "benchmarks" / "results" / record).read_text())
    assert TIMINGS[name]["minutes"] == round(rec["minutes"], 1) and TIMINGS[name]["date"] == rec["info"]["date"]
    assert f"benchmarks/results/{record}" in TIMINGS[name]["source"]


def test_the_readme_is_short():
    assert len(README.splitlines()) <= 300


def markdown_files() -> list[Path]:
    """Every Markdown file of the repository: tracked, or new and not ignored (git), else every ``*.md``
    outside hidden folders and the virtual environment."""
    try:
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "*.md"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout
        files = [ROOT / f for f in out.splitlines()]
    except (OSError, subprocess.CalledProcessError):
        files = [f for f in ROOT.rglob("*.md") if not any(part.startswith(".") for part in f.relative_to(ROOT).parts)]
    return sorted(f for f in files if f.is_file())


_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")


def broken_links(path: Path, text: str) -> list[str]:
    """Relative links of Markdown ``text`` (in file ``path``) that leave the repository or name no file;
    web links (``scheme:``) and anchors within the page are not checked."""
    bad = []
    for target in _LINK.findall(re.sub(r"```.*?```", "", text, flags=re.S)):
        if re.match(r"[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith("#"):
            continue
        resolved = (path.parent / target.split("#", 1)[0]).resolve()
        if ROOT not in resolved.parents or not resolved.exists():
            bad.append(target)
    return bad


def test_the_link_check_catches_links_that_leave_the_repository():
    page = ROOT / "docs" / "page.md"
    text = "[design](design.md) [up](../shared/DESIGN.md) [gone](nothing.md) [web](https://example.org) [a](#top)"
    assert broken_links(page, text) == ["../shared/DESIGN.md", "nothing.md"]


def test_every_relative_link_of_every_document_resolves_inside_the_repository():
    files = markdown_files()
    assert ROOT / "README.md" in files and ROOT / "docs" / "design.md" in files
    bad = {str(f.relative_to(ROOT)): b for f in files if (b := broken_links(f, f.read_text()))}
    assert not bad, f"links that leave the repository or name no file: {bad}"



def python_examples() -> list[tuple[str, str]]:
    """``(name, code)`` of every ```python block of the documents."""
    return [(f"{doc.relative_to(ROOT)}, example {i + 1}", code) for doc in DOCUMENTS
            for i, code in enumerate(re.findall(r"```python\n(.*?)```", doc.read_text(), flags=re.S))]


def test_the_python_examples_import_what_exists():
    """The import lines of every Python example run (a moved or renamed function fails here, in the default tier)."""
    examples = python_examples()
    assert len(examples) >= 3  # the dataset, the filters and the tracker examples
    for name, code in examples:
        imports = "\n".join(line for line in code.splitlines() if re.match(r"(from \S+ )?import ", line))
        exec(compile(imports, name, "exec"), {})


@pytest.mark.slow
def test_the_python_examples_run(sandbox):
    """Each example as written, after the commands that make what it reads (data/fitee, runs/smoke)."""
    run(FITEE)
    run(SMOKE)
    for name, code in python_examples():
        exec(compile(code, name, "exec"), {"__name__": "docs_example"})

_REPO_PATH = re.compile(r"`((?:pmsr_nn|evaluate|datasets|train|models|benchmarks|tests|docs)/[\w./*-]*)(?:::\w+)?`")


def test_the_repository_paths_the_documents_name_exist():
    """A path in inline code (``pmsr_nn/trackers/pmht.py``, ``models/released/one_sky_*.pt``) names a file or
    folder of the repository; commands (inline code with spaces) are checked by the tests above."""
    missing = {}
    for doc in DOCUMENTS:
        gone = [p for p in _REPO_PATH.findall(doc.read_text()) if not list(ROOT.glob(p.rstrip("/")))]
        if gone:
            missing[str(doc.relative_to(ROOT))] = gone
    assert not missing, f"paths named in the documents that do not exist: {missing}"


def _other_commands(slow: bool):
    first = set(first_hour_block())
    out = []
    for c in readme_commands():
        r = rule_for(c)
        if r is not None and r.slow == slow and c not in first and not c.startswith("python ") and "--help" not in c:
            out.append(c)
    return out


def _run_with_rule(command: str) -> None:
    r = rule_for(command)
    for step in r.setup:
        step() if callable(step) else run(step)
    argv = r.tiny(shlex.split(command)[1:])
    if r.refused:
        before = sorted(p for p in Path.cwd().rglob("*") if p.is_file())
        assert main(argv) == 2, f"pmsr {' '.join(argv)} was not refused"
        assert sorted(p for p in Path.cwd().rglob("*") if p.is_file()) == before
    else:
        run(argv, own_process=r.own_process)


@pytest.mark.parametrize("command", [pytest.param(c, marks=pytest.mark.integration) if rule_for(c).integration else c
                                     for c in _other_commands(slow=False)])
def test_readme_command_runs_on_a_tiny_configuration(sandbox, command):
    _run_with_rule(command)


@pytest.mark.slow
@pytest.mark.parametrize("command", _other_commands(slow=True))
def test_readme_study_runs_with_one_monte_carlo_run(sandbox, command):
    _run_with_rule(command)


@pytest.mark.slow  # one Python process per script; the scripts' own tests run them in the default tier
def test_readme_scripts_take_the_options_they_are_given():
    """Every ``python SCRIPT ...`` of the README exists and its ``--help`` lists the options used
    (the scripts' own tests run them; their ``--help`` processes run side by side)."""
    commands = [shlex.split(c) for c in readme_commands() if c.startswith("python ")]
    for argv in commands:
        assert (ROOT / argv[1]).is_file(), f"{argv[1]} does not exist"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = [subprocess.Popen([sys.executable, str(ROOT / a[1]), "--help"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=env) for a in commands]
    for argv, proc in zip(commands, procs):
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, f"{argv[1]} --help: {err[-1000:]}"
        for opt in (a for a in argv[2:] if a.startswith("--")):
            assert opt in out, f"{argv[1]} has no option {opt}"


def test_the_demo_stage_hints_are_its_records():
    """harness.demo.REFERENCE_SECONDS from benchmarks/results/demo_time.json: seconds per training batch
    (the demo's 300 and 120 batches), per one-sky run (2) and per evaluation run (20, what is left of
    the total), each to the constant's two decimals or three figures."""
    from pmsr_nn.harness.demo import REFERENCE_SECONDS as ref

    st = json.loads((ROOT / "benchmarks" / "results" / "demo_time.json").read_text())["stages"]
    assert ref["batch"] == {"mdfnn": round(st["train_seconds"]["mdfnn"] / 300, 2),
                            "kalmannet": round(st["train_seconds"]["kalmannet"] / 120, 2)}
    rest = st["total_seconds"] - sum(st["train_seconds"].values()) - st["one_sky_seconds"]
    assert ref["run"] == {"evaluation": round(rest / 20, 2), "one_sky": round(st["one_sky_seconds"] / 2, 1)}
