"""``pmsr demo``: the main job on its built-in default, end to end in minutes on a CPU.

1. simulate a small dataset of the built-in FITEE 2023 CA recipe (envelope variant);
2. train a small MDFNN (window-local inputs, residual output) and a small KalmanNet-style tracker on
   it with ``pmsr train``'s machinery (fixed step budgets);
3. evaluate them against the EKF, UKF and SI+KF and the PCRB on the three built-in trajectories
   with fewer Monte Carlo runs than the full study, and print the comparison table;
4. a small version of the flagship scenario ``evaluate/one_sky.yaml`` (its crossing pair and its
   formation, 2 runs): the EKF and the released KalmanNet trained for its sensors on each drone's own
   stream, the PCRB, S-MSJPDA handed the births and S-MSJPDA and the belief-propagation tracker
   starting their own tracks on detections
   with missed targets and clutter, OSPA / GOSPA beside the RMSE.

Everything goes under one folder (default ``runs/demo``): ``train/mdfnn``, ``train/kalmannet`` (runs
with TensorBoard logs and ``tracker.pt``), ``data/``, ``evaluation/`` and ``one_sky/``
(results.json, report.md, figures). The networks are far smaller and trained far shorter than the released
ones (``models/released/``); the demo shows the pipeline and an honest comparison, not the
best numbers the package reaches.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

from ..config import from_dict
from ..errors import ConfigError, Interrupted
from .scenario.case_spec import FITEE2023_TRAJECTORIES
from .scenario.method_spec import MethodSpec
from .scenario.schema import FixedNoiseSpec, Scenario

DEMO_MARKER = "demo.json"
DEMO_CONTENTS = {DEMO_MARKER, ".pmsr_output.json", "data", "train", "evaluation", "one_sky"}
"""Everything a demo folder holds: a previous demo is replaced only if it holds nothing else."""

DEMO_DATA = {"tracks": 120, "window": 100, "batch_size": 128, "eval_window_stride": 20}
"""120 tracks x 1000 s: 102 for training (87 k windows), the rest for validation and test."""

DEMO_MODELS = {
    "mdfnn": {"kind": "mdfnn", "hidden": [128, 96, 128], "filter_order": 20, "filter_taps": "per_channel",
              "inputs": "local_fixes", "output": "residual"},
    "kalmannet": {"kind": "kalmannet", "rnn_hidden": 64, "inputs": "measurements_and_fixes", "output": "residual"},
}
"""The compact MDFNN of ``models/mdfnn_local.yaml`` (narrower than Table 2's 384 / 225 / 540) reading
window-local state fixes and correcting each scan's fix, and the KalmanNet-style tracker of
``models/kalmannet.yaml`` (:mod:`pmsr_nn.nets.kalmannet`).
The paper's representation (normalised raw measurements in, normalised state out) needs hours to
come near the EKF (``evaluate/RESULTS.md``); it stays in the full study, not in a minutes-long demo."""

DEMO_NAMES = {"mdfnn": "MDFNN", "kalmannet": "KalmanNet"}
"""Row names of the demo's learned trackers."""

DEMO_TRAINER = {"max_epochs": 30, "train_batches_per_epoch": 50, "val_batches": 20, "max_time_minutes": 3.5,
                "accelerator": "cpu", "early_stopping_patience": None, "checkpoint_every_n_steps": 100,
                "deterministic": True, "progress": False}
"""A fixed step budget per network (:data:`DEMO_BUDGET`), with a time cap as a safety net on slow machines."""

DEMO_BUDGET = {"mdfnn": {"max_epochs": 12, "train_batches_per_epoch": 25, "precision": "auto"},
               "kalmannet": {"max_epochs": 8, "train_batches_per_epoch": 15}}
"""MDFNN: 300 batches (float32, or bfloat16 autocast where the CPU has it natively); KalmanNet: 120
batches (it back-propagates through 100 sequential filter steps)."""

DEMO_LR = {"mdfnn": 3.0e-3, "kalmannet": 1.0e-3}
"""Peak learning rates (cosine schedule). The KalmanNet's gain feeds back into its own inputs: at
3e-3 the demo run went to NaN within 80 batches; 1e-3 is that of ``train/kalmannet.yaml``."""


def demo_train_config(kind: str, cache_dir: Path, seed: int = 0):
    from ..nets.train_config import TrainConfig

    raw = {"name": f"demo_{kind}", "seed": seed, "data": {**DEMO_DATA, "cache_dir": str(cache_dir)},
           "model": DEMO_MODELS[kind], "optim": {"lr": DEMO_LR.get(kind, 1.0e-3), "schedule": "cosine", "acceleration_weight": 0.1},
           "trainer": {**DEMO_TRAINER, **DEMO_BUDGET.get(kind, {})}}
    return from_dict(TrainConfig, raw, where="demo train config")


def demo_scenario(checkpoints: dict[str, Path], mc_runs: int) -> Scenario:
    """The three-trajectory study with EKF, UKF, SI+KF and the given learned trackers."""
    methods = [MethodSpec("EKF", "ekf"), MethodSpec("UKF", "ukf"), MethodSpec("SI+KF", "si_kf")]
    methods += [MethodSpec(name, "learned", checkpoint=str(Path(p).resolve())) for name, p in checkpoints.items()]
    return Scenario(name="demo_fitee2023_three_trajectories", cases=FITEE2023_TRAJECTORIES, methods=tuple(methods),
                    seed=0, mc_runs=mc_runs, block_runs=10, noise=FixedNoiseSpec(), warmup_steps=100,
                    description="pmsr demo: a small MDFNN and KalmanNet trained for minutes on CPU, against the EKF, UKF, "
                                "SI+KF and the PCRB on the three built-in trajectories.")


ONE_SKY = Path(__file__).resolve().parents[2] / "evaluate" / "one_sky.yaml"
"""The flagship scenario, beside the package in a clone of the repository."""

ONE_SKY_RUNS = 2
ONE_SKY_TARGETS = ("cross_1", "cross_2", "lead", "wing")
ONE_SKY_END_S = 360.0
ONE_SKY_METHODS = ("EKF", "KalmanNet [seed 0]", "PCRB", "S-MSJPDA (oracle births)", "S-MSJPDA", "BP")
"""What the demo keeps of ``evaluate/one_sky.yaml``: its crossing pair and its formation, each gone at
:data:`ONE_SKY_END_S` (after the crossing), and the rows that take seconds (the full scenario's PMHT,
PHD and Stone Soup rows take minutes per run)."""


def demo_one_sky(mc_runs: int) -> Scenario:
    """The small version of ``evaluate/one_sky.yaml`` the demo runs (:data:`ONE_SKY_TARGETS`,
    :data:`ONE_SKY_METHODS`, ``mc_runs`` runs in one block)."""
    import dataclasses

    from .scenario.schema import load_scenario

    if not ONE_SKY.is_file():
        raise ConfigError(f"the demo's last stage reads {ONE_SKY}, which this installation lacks; run the demo from a "
                          "clone of the repository")
    sc = load_scenario(ONE_SKY)
    case = sc.cases[0]
    targets = tuple(dataclasses.replace(t, death_s=min(t.end_s, ONE_SKY_END_S))
                    for t in case.targets if t.name in ONE_SKY_TARGETS)
    case = dataclasses.replace(case, targets=targets,
                               title="a crossing pair and a formation of the flagship scenario")
    return sc.replace(name="demo_one_sky", cases=(case,), methods=tuple(m for m in sc.methods if m.name in ONE_SKY_METHODS),
                      mc_runs=mc_runs, block_runs=mc_runs,
                      description="pmsr demo: four drones of evaluate/one_sky.yaml (2 transmitters x 3 receivers); the EKF "
                                  "and the released KalmanNet on each drone's stream, the PCRB, S-MSJPDA on detections "
                                  "with Pd 0.85 and clutter, handed the births and starting its own tracks, and the "
                                  "belief-propagation tracker starting its own tracks.")


def _fresh(out: Path) -> None:
    """Start from an empty ``out``; only a previous demo's folder is cleared (never the working
    directory, a parent of it, or a folder another command or the user wrote)."""
    from ..outputs import check_target, output_kind, write_marker

    check_target(out)
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise ConfigError(f"--out {out} exists and is not a folder; choose another --out")
    if out.exists() and any(out.iterdir()):
        if output_kind(out) != "demo":
            raise ConfigError(f"{out} exists and is not a pmsr demo folder; choose another --out")
        foreign = sorted(p.name for p in out.iterdir() if p.name not in DEMO_CONTENTS)
        if foreign:
            raise ConfigError(f"{out} holds files a demo does not write ({', '.join(foreign[:3])}); pmsr never "
                              "deletes what it did not write: choose another --out")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    write_marker(out, "demo", state="running")


DEMO_STAGES = 5
REFERENCE_SECONDS = {"batch": {"mdfnn": 0.30, "kalmannet": 0.44}, "run": {"evaluation": 1.24, "one_sky": 35.5}}
"""Seconds per training batch and per Monte Carlo run of each stage, so that each stage line says
what it took on 2 CPU cores, all from the demo's record (``benchmarks/results/demo_time.json``, the
quiet 2-core AMD EPYC, 2026-12-06): 90 s for 300 MDFNN batches, 53 s for 120 KalmanNet batches,
71 s for the 2 runs of the one-sky stage (its untimed warm-up run included), and for the
three-trajectory evaluation what is left of the total over its 20 runs (25 s: an upper bound, as it
includes simulating the dataset; the record keeps no time of that stage alone). The 1.0 s per run
before (2-core Intel Xeon, 2026-11-24) kept no record."""


def _about(seconds: float) -> str:
    return f"(about {max(seconds, 1):.0f} s on 2 CPU cores)"


def run_demo(out: Path, mc_runs: int = 20, progress: bool = True, log=print, verbose: bool = False) -> dict:
    """Run the demo into ``out`` (module docstring), logging one line per stage start and end.
    ``progress``: bars with time left while a stage runs; ``verbose``: Lightning's own console."""
    out = Path(out)
    _fresh(out)
    try:
        return _run(out, mc_runs, progress, log, verbose)
    except (Interrupted, KeyboardInterrupt) as exc:  # the folder stays marked as a demo: the next demo replaces it
        exc.kept = f"the unfinished demo in {out} is replaced by the next 'pmsr demo --out {out}'"
        raise


class _Stages:
    """``[i/n] what`` when a stage starts, ``      done in T: result`` when it ends."""

    def __init__(self, log, total: int):
        self.log, self.total, self.i, self.t0 = log, total, 0, None

    def start(self, what: str) -> None:
        self.i += 1
        self.t0 = time.perf_counter()
        self.log(f"[{self.i}/{self.total}] {what}")

    def done(self, result: str = "") -> float:
        seconds = time.perf_counter() - self.t0
        self.log(f"      done in {seconds:.0f} s" + (f": {result}" if result else ""))
        return seconds


def _run(out: Path, mc_runs: int, progress: bool, log, verbose: bool) -> dict:
    from ..nets.train_config import resolve_recipe
    from ..nets.training import prepare_dataset, train
    from .evaluate import evaluate

    t_start = time.perf_counter()
    (out / DEMO_MARKER).write_text(json.dumps({"started": time.strftime("%Y-%m-%d %H:%M:%S")}) + "\n")
    stages = _Stages(log, DEMO_STAGES)
    console = "lightning" if verbose else ("bar" if progress else "none")
    first = demo_train_config(next(iter(DEMO_MODELS)), out / "data")
    recipe = resolve_recipe(first.data)
    stages.start(f"simulate {recipe.tracks} tracks x {recipe.motion.steps * recipe.motion.dt_s:.0f} s of the "
                 f"{recipe.name} recipe ({recipe.variant})")
    prepare_dataset(first.data, progress=progress)
    stages.done()
    checkpoints, train_seconds = {}, {}
    for kind in DEMO_MODELS:
        cfg = demo_train_config(kind, out / "data")
        name = DEMO_NAMES.get(kind, kind.upper())
        batches = cfg.trainer.max_epochs * (cfg.trainer.train_batches_per_epoch or 0)
        stages.start(f"train a small {name}: {cfg.trainer.max_epochs} epochs x {cfg.trainer.train_batches_per_epoch} "
                     f"batches of {cfg.data.batch_size} windows "
                     + _about(batches * REFERENCE_SECONDS["batch"].get(kind, 0.2)))
        m = train(cfg, out / "train" / kind, console=console, label=f"train {name}")
        train_seconds[kind] = stages.done(f"validation position RMSE {m['val']['pos_rmse_m']:.1f} m")
        checkpoints[name] = out / "train" / kind / "tracker.pt"
    scenario = demo_scenario(checkpoints, mc_runs)
    stages.start(f"evaluate {', '.join(m.name for m in scenario.methods)}, PCRB on 3 trajectories x {mc_runs} runs "
                 + _about(mc_runs * REFERENCE_SECONDS["run"]["evaluation"]))
    res = evaluate(scenario, out / "evaluation", progress=progress)
    stages.done()
    runs = min(mc_runs, ONE_SKY_RUNS)
    stages.start(f"one sky, small: 4 drones of evaluate/one_sky.yaml, every row on the same draws, {runs} runs "
                 + _about(runs * REFERENCE_SECONDS["run"]["one_sky"]))
    res["one_sky"] = evaluate(demo_one_sky(runs), out / "one_sky", progress=progress)
    res["demo"] = {"train_seconds": train_seconds, "one_sky_seconds": stages.done(),
                   "total_seconds": time.perf_counter() - t_start}
    (out / DEMO_MARKER).write_text(json.dumps(res["demo"], indent=1) + "\n")
    return res


def demo_summary(res: dict, out: Path) -> list[str]:
    """The demo's closing console lines: the three-trajectory RMSE table, a compact multi-target
    table (every column of both is in the reports) and, one line each, whatever either report
    flags (rows below their bound beyond the Monte Carlo error, diverged runs)."""
    from .report.flags import warning_lines
    from .report.method_tables import summary_table
    from .report.report_cells import fmt, fmt_se, start_label
    from .results.typed import Results

    evaluation, sky = Results.from_dict(res), Results.from_dict(res["one_sky"])
    lines = ["", f"position RMSE (m) after the warm-up, {evaluation.mc_runs} runs per trajectory; bold: below its own "
             "bound", ""]
    lines += summary_table(evaluation, None, "", False)
    case = next(iter(sky.cases.values()))
    lines += ["", f"one sky, small: a crossing pair and a formation, 6 pairs, {sky.mc_runs} runs; every column in "
              "the report", "",
              "| method | reads | tracks start | pos RMSE (m) | OSPA (m) | GOSPA (m) | tracks / target | false / run | s / run |",
              "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for m, r in case.methods.items():  # a bound's row has no tracks: "-"
        s, t = r.sets, r.tracks
        reads = sky.settings.methods[m].reads
        lines.append(f"| {m} | {'-' if reads is None else reads} | {start_label(r, None)} | "
                     f"{fmt_se(r.rmse_pos_m, r.rmse_pos_se_m, 1)} | {fmt_se(s and s.ospa_m, s and s.ospa_se_m, 1)} | "
                     f"{fmt_se(s and s.gospa_m, s and s.gospa_se_m, 1)} | "
                     f"{fmt(t and t.confirmed_tracks_per_target, 2)} | "
                     f"{fmt(t and t.false_tracks_per_run, 2)} | {fmt(r.seconds_per_run, 2)} |")
    lines.append("")
    lines += warning_lines(evaluation) + warning_lines(sky)  # the reports' flags, one line each
    lines += [f"reports   {out / 'evaluation' / 'report.md'}  (figures beside it)",
              f"          {out / 'one_sky' / 'report.md'}",
              f"time      {res['demo']['total_seconds'] / 60:.1f} min in all",
              "next      pmsr evaluate evaluate/fitee2023_three_trajectories.yaml --out runs/eval  (the full study)"]
    return lines
