"""Training ablations (sequence size, filter order, DFNN vs MDFNN): train one network per
setting with the same budget, evaluate each on the three built-in trajectories, tabulate.

Every setting trains with ``pmsr train``'s machinery on the built-in recipe (``tracks`` tracks,
envelope variant) for a fixed number of optimiser steps. The batch holds a fixed number of
scan samples (``samples_per_batch`` / window windows), so a longer sequence size does not
buy more data per step. Networks are narrower than the paper's (``ABLATION_MODEL``) so that a
whole table trains in minutes on a CPU; ``--hidden`` widens them.

The command line every ablation script under ``evaluate/`` shares (:func:`ablation_main`; the
altitude one uses :class:`ScriptParser` and :func:`pmsr_nn.outputs.atomic_folder`): ``--out`` is
required; an existing ``--out`` is replaced only with ``--overwrite``, and only where an ablation
wrote it (our marker) and it holds nothing beyond what the marker lists (pmsr's rule,
:func:`pmsr_nn.outputs.check_folder_target`: never delete what it did not write). A training
ablation writes as it goes, so an interrupted one continues in its own folder (a setting whose
run holds ``tracker.pt`` is not retrained) and its marker lists what it wrote once it finishes; a
replaced folder is moved aside until the new one is complete. Bad input is one line
``error: ...``, exit code 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import from_dict
from ..errors import ConfigError
from ..outputs import folder_contents
from .report.figures import pyplot
from .report.report_cells import fmt
from .scenario.case_spec import FITEE2023_TRAJECTORIES
from .scenario.method_spec import MethodSpec
from .scenario.references import reference_table
from .scenario.schema import FixedNoiseSpec, Scenario

ABLATION_MODEL = {"kind": "mdfnn", "hidden": [128, 96, 128], "filter_order": 20}


@dataclass
class Budget:
    """Training budget of every setting of an ablation."""

    tracks: int = 300
    epochs: int = 20
    batches_per_epoch: int = 50
    samples_per_batch: int = 12_800
    max_minutes: float = 6.0
    seed: int = 0

    def describe(self) -> str:
        return (f"{self.tracks} tracks of the built-in recipe, {self.epochs} epochs x {self.batches_per_epoch} batches of "
                f"{self.samples_per_batch} scan samples (window x windows), seed {self.seed}")


def train_config(name: str, model: dict, window: int, budget: Budget, cache_dir: Path):
    from ..nets.train_config import TrainConfig

    raw = {"name": name, "seed": budget.seed,
           "data": {"tracks": budget.tracks, "window": window, "cache_dir": str(cache_dir),
                    "batch_size": max(1, budget.samples_per_batch // window), "eval_window_stride": max(1, window // 5)},
           "model": model, "optim": {"lr": 3.0e-3, "schedule": "cosine"},
           "trainer": {"max_epochs": budget.epochs, "train_batches_per_epoch": budget.batches_per_epoch,
                       "val_batches": 20, "max_time_minutes": budget.max_minutes, "accelerator": "cpu",
                       "early_stopping_patience": None, "checkpoint_every_n_steps": 200, "progress": False}}
    return from_dict(TrainConfig, raw, where=f"ablation {name}")


class ScriptParser(argparse.ArgumentParser):
    """argparse with its errors as one line ``error: ...`` and exit code 2 (the ablation scripts)."""

    def error(self, message):
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2)


def check_ablation_folder(out: Path, overwrite: bool) -> bool:
    """Refuse (one line) an ``--out`` a training ablation may not write; True where it replaces an
    earlier ablation (``overwrite``), False for a new or empty folder or one to continue (an
    unfinished ablation of ours, without ``overwrite``)."""
    from ..outputs import check_folder_target, check_target, output_kind

    check_target(out)
    if not out.exists() or (out.is_dir() and not out.is_symlink() and not any(out.iterdir())):
        return False
    if overwrite:
        check_folder_target(out, overwrite=True, allow=("ablation",))
        return True
    if output_kind(out) != "ablation":
        raise ConfigError(f"--out {out} exists and is not an ablation folder this package wrote; an ablation only "
                          "continues in its own folder: choose another --out")
    if _marker(out).get("state") == "finished":
        raise ConfigError(f"--out {out} holds a finished ablation; pass --overwrite to replace it, or choose another --out")
    return False


def _marker(out: Path) -> dict:
    from ..outputs import MARKER

    try:
        m = json.loads((out / MARKER).read_text())
    except (OSError, ValueError):
        return {}
    return m if isinstance(m, dict) else {}


def run_ablation(settings: dict[str, tuple[dict, int]], out: Path, budget: Budget, mc_runs: int,
                 log=print) -> list[dict]:
    """Train and evaluate every setting ``label -> (model config, window)`` under ``out`` (checked
    by :func:`check_ablation_folder`).

    A setting whose run folder already holds ``tracker.pt`` is not retrained (re-running a long
    ablation after an interruption continues where it stopped)."""
    from ..nets.training import train
    from ..outputs import write_marker
    from .evaluate import evaluate

    out.mkdir(parents=True, exist_ok=True)
    write_marker(out, "ablation", state="running")
    rows = []
    for label, (model, window) in settings.items():
        run = out / "runs" / label
        t0 = time.perf_counter()
        trained_now = not (run / "tracker.pt").is_file()
        if trained_now:
            log(f"[ablation] training {label} (window {window}, {model})")
            train(train_config(label, model, window, budget, out / "data"), run)
        metrics = json.loads((run / "metrics.json").read_text())
        seconds = time.perf_counter() - t0
        sc = Scenario(name=f"ablation_{label}", cases=FITEE2023_TRAJECTORIES, noise=FixedNoiseSpec(), mc_runs=mc_runs,
                      methods=(MethodSpec("net", "learned", checkpoint=str((run / "tracker.pt").resolve())),),
                      warmup_steps=100)  # the same steps for every setting, so that rows compare
        res = evaluate(sc, out / "eval" / label, progress=False, overwrite=True)
        cases = {c: v["methods"]["net"] for c, v in res["cases"].items()}
        rows.append({"label": label, "window": window, "model": model, "epochs": metrics["epochs"],
                     "steps": metrics["global_step"], "fit_seconds": metrics.get("fit_seconds_this_session", seconds),
                     "trained_now": trained_now,
                     "val_pos_rmse_m": metrics["val"]["pos_rmse_m"],
                     "rmse_pos_m": {c: r["rmse_pos_m"] for c, r in cases.items()},
                     "bound_pos_m": {c: r["bound_pos_m"] for c, r in cases.items()},
                     "causal": all(r["causal"] for r in cases.values())})
        log(f"[ablation]   {label}: " + ", ".join(f"{c} {v:.1f} m" for c, v in rows[-1]["rmse_pos_m"].items()))
    return rows


def write_ablation(out: Path, title: str, parameter: str, rows: list[dict], budget: Budget, mc_runs: int,
                   paper: dict | None, paper_note: str, reference: str) -> str:
    """``out/table.md``, ``out/results.json`` and ``out/rmse.png``; returns the table."""
    from ..environment import environment

    cases = list(rows[0]["rmse_pos_m"])
    per_case_paper = bool(paper) and any(isinstance(v, dict) for v in paper.values())

    def ref(case, label):
        if not paper:
            return None
        row = paper.get(case, {}) if per_case_paper else paper
        return row.get(label)

    timed = any((r.get("fit_seconds") or 0) > 0 for r in rows)  # no column of zeros where nothing was trained
    head = f"| {parameter} | " + " | ".join(f"{c} (m)" + (f" | {c} paper" if per_case_paper else "") for c in cases)
    head += (" | paper (m) |" if paper and not per_case_paper else " |") + " train steps |" + (" train s |" if timed else "")
    lines = [f"## {title}", "", head, "|---|" + "---:|" * (len(cases) * (2 if per_case_paper else 1)
                                                          + (1 if paper and not per_case_paper else 0) + 1 + timed)]
    for r in rows:
        cells = []
        for c in cases:
            cells.append(fmt(r["rmse_pos_m"][c]))
            if per_case_paper:
                cells.append(fmt(ref(c, r["label"])))
        if paper and not per_case_paper:
            cells.append(fmt(ref(None, r["label"])))
        lines.append(f"| {r['label']} | " + " | ".join(cells) + f" | {r['steps']} |"
                     + (f" {seconds(r.get('fit_seconds'))} |" if timed else ""))
    bounds = " / ".join(fmt(rows[0]["bound_pos_m"][c]) for c in cases)
    lines += ["", f"Position RMSE (Eq. 31, averaged over steps 100-999) over {mc_runs} Monte Carlo "
              f"runs per trajectory of the three built-in trajectories (noise 30 m, 2 m/s, 3 deg); filtering PCRB "
              f"{bounds} m. Budget per setting: {budget.describe()}. Columns marked paper are the paper's numbers "
              f"({reference}), for reference only. {paper_note}"]
    table = "\n".join(lines)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(table + "\n")
    (out / "results.json").write_text(json.dumps({"title": title, "parameter": parameter, "rows": rows,
                                                  "budget": budget.__dict__, "mc_runs": mc_runs,
                                                  "environment": environment()}, indent=1) + "\n")
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    labels = [r["label"] for r in rows]
    xs = np.arange(len(labels))
    for c in cases:
        ax.semilogy(xs, [r["rmse_pos_m"][c] for r in rows], "o-", label=f"{c} (ours)")
        if paper:
            pv = [ref(c, lab) for lab in labels]
            if any(v is not None for v in pv):
                ax.semilogy(xs, [np.nan if v is None else v for v in pv], "x:", label=f"{c} (paper, reference)"
                            if per_case_paper else "paper (reference)")
                if not per_case_paper:
                    paper = None  # one reference curve is enough
    ax.set_xticks(xs, labels)
    ax.set(xlabel=parameter, ylabel="position RMSE (m)", title=title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "rmse.png", dpi=110)
    plt.close(fig)
    return table


def seconds(s: float | None) -> str:
    """A training time (s) for a table: whole seconds from 10 s, one decimal below, '-' where none."""
    if s is None:
        return "-"
    return f"{s:.0f}" if s >= 10 else f"{s:.1f}"


OUT_HELP = ("output folder (required): new, or an unfinished ablation of this script's to continue, or, with "
            "--overwrite, an earlier ablation to replace")
OVERWRITE_HELP = ("replace an existing --out, only where an ablation wrote it and it holds nothing else "
                  "(pmsr never deletes what it did not write)")


def ablation_main(argv, *, doc: str, title: str, parameter: str, values: list[str], settings, paper_file: Path,
                  paper_key: str, paper_note: str) -> int:
    """The command line shared by the training ablation scripts under ``evaluate/`` (see the module
    docstring for the ``--out`` / ``--overwrite`` rule).

    ``settings(values, hidden) -> {label: (model config, window)}``."""
    import shutil

    from ..errors import PmsrError
    from ..outputs import output_kind, write_marker

    p = ScriptParser(description=doc.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help=OUT_HELP)
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.add_argument("--values", nargs="+", default=values, help=f"{parameter} values (default: the paper's, {' '.join(values)})")
    p.add_argument("--mc-runs", type=int, default=20, help="Monte Carlo runs per trajectory (default 20)")
    p.add_argument("--tracks", type=int, default=Budget.tracks, help=f"training tracks (default {Budget.tracks})")
    p.add_argument("--epochs", type=int, default=Budget.epochs,
                   help=f"training epochs of --batches batches each (default {Budget.epochs})")
    p.add_argument("--batches", type=int, default=Budget.batches_per_epoch,
                   help=f"batches per epoch, each of {Budget.samples_per_batch} scan samples (default {Budget.batches_per_epoch})")
    p.add_argument("--hidden", type=int, nargs=3, default=ABLATION_MODEL["hidden"], help="hidden layer widths")
    a = p.parse_args(argv)
    old = None
    try:
        if a.mc_runs < 1 or a.tracks < 12 or a.epochs < 1 or a.batches < 1:
            raise PmsrError("--mc-runs, --epochs and --batches must be positive and --tracks at least 12")
        budget = Budget(tracks=a.tracks, epochs=a.epochs, batches_per_epoch=a.batches)
        chosen = settings(a.values, list(a.hidden))
        paper = reference_table(paper_file, paper_key)
        if check_ablation_folder(a.out, a.overwrite):  # the earlier ablation, aside until the new one is complete
            aside = a.out.parent / f".{a.out.name}.old-{os.getpid()}"
            if aside.exists() or aside.is_symlink():
                raise PmsrError(f"--out {a.out}: the name {aside} is taken; remove it if it is not yours")
            a.out.rename(aside)
            old = aside
        print(f"[ablation] budget per setting: {budget.describe()}")
        rows = run_ablation(chosen, a.out, budget, a.mc_runs)
        table = write_ablation(a.out, title, parameter, rows, budget, a.mc_runs, paper, paper_note,
                               f"{paper_file.name}: {paper_key}")
        write_marker(a.out, "ablation", state="finished", contents=folder_contents(a.out))
    except BaseException as exc:
        if old is not None:  # the earlier ablation comes back, in place of the new one (only if that is ours)
            if a.out.exists() and output_kind(a.out) == "ablation":
                shutil.rmtree(a.out, ignore_errors=True)
            if not a.out.exists():
                old.rename(a.out)
            else:
                print(f"note: the earlier ablation is kept at {old} ({a.out} holds what this package did not "
                      "write)", file=sys.stderr)
        if isinstance(exc, PmsrError):
            print(f"error: {exc}", file=sys.stderr)
            return 2
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    print(table)
    print(f"\nwrote {a.out / 'table.md'}, {a.out / 'results.json'}, {a.out / 'rmse.png'}")
    return 0
