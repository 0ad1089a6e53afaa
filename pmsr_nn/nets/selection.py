"""Model selection as in Section 3.3 of the MDFNN paper: train u models, keep the best.

Member ``i`` trains with seed ``seed + i`` on cross-validation fold ``i`` of the pooled train
and val tracks (so each member validates on tracks the others trained on), then every member
is scored on (a) its validation fold and (b) fresh tracks drawn with a seed no training run
used. The member with the lowest fresh-track position RMSE (after the first window) is kept.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

from ..errors import ConfigError
from ..outputs import atomic_folder, check_folder_target
from ..metrics import pooled_rmse, position_columns, velocity_columns
from .inference import Tracker
from .train_config import TrainConfig
from .training import prepare_dataset, train

FRESH_SEED_OFFSET = 1_000_003
"""Fresh tracks use ``recipe seed + FRESH_SEED_OFFSET``: a random stream no training set draws from."""


def fresh_recipe(cfg: TrainConfig, tracks: int):
    """The training recipe with ``tracks`` tracks and a seed no training set draws from."""
    from ..simulation.recipe import SplitSpec
    from .train_config import resolve_recipe

    if cfg.data.path is not None:
        from ..data.store import open_dataset

        ds = open_dataset(cfg.data.path)
        try:
            recipe = ds.recipe()
        finally:
            ds.close()
    else:
        recipe = resolve_recipe(cfg.data)
    # Only evaluated, never trained on: the split labels are irrelevant, all tracks are scored.
    return recipe.with_overrides(tracks=tracks, seed=recipe.seed + FRESH_SEED_OFFSET, splits=SplitSpec(1.0, 0.0, 0.0))


def fresh_tracks(cfg: TrainConfig, tracks: int, out: Path) -> Path:
    """Simulate ``tracks`` tracks of the training recipe with an unused seed into ``out``."""
    from ..data.store import write_dataset

    write_dataset(fresh_recipe(cfg, tracks), out, progress=False, what="--fresh-tracks: dataset")
    return out


def score_on(tracker: Tracker, dataset: Path) -> dict:
    """Position and velocity RMSE of ``tracker`` on every track of ``dataset`` after the first window."""
    from ..data.store import open_dataset

    ds = open_dataset(dataset)
    try:
        z = torch.from_numpy(ds.file["measurements"][()]).double()
        x = torch.from_numpy(ds.file["states"][()]).double()
        tracker.check_compatible(ds.manifest["geometry"], ds.manifest["columns"]["measurements"], ds.manifest["dt_s"],
                                 where=f"dataset {dataset}")
    finally:
        ds.close()
    est = tracker.track(z)
    start = tracker.window
    return {"pos_rmse_m": pooled_rmse(est, x, position_columns(x.shape[-1]), start),
            "vel_rmse_mps": pooled_rmse(est, x, velocity_columns(x.shape[-1]), start)}


def select_best(cfg: TrainConfig, out: str | Path, *, members: int = 10, fresh_tracks_n: int = 20) -> dict:
    """Train ``members`` models into ``out/member-NN``, score them, copy the best to ``out/best.pt``.

    ``out`` is written atomically (:func:`pmsr_nn.outputs.atomic_folder`): a refused, failed or
    interrupted selection leaves nothing behind. Paths in ``selection.json`` are relative to ``out``.
    """
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise ConfigError(f"output folder {out} exists and is not empty; choose another --out")
    if cfg.data.fold is not None or cfg.data.folds is not None:
        raise ConfigError("select assigns the data folds itself; remove data.fold / data.folds from the config")
    inputs = [p for p in (cfg.data.path, cfg.data.recipe) if p]
    check_folder_target(out, overwrite=False, inputs=inputs)
    dataset = prepare_dataset(cfg.data)  # fail on a bad recipe before anything is written
    from ..data.store import open_dataset

    ds = open_dataset(dataset)
    try:
        pool = len(ds.split_indices("train")) + len(ds.split_indices("val"))
    finally:
        ds.close()
    if members > 1 and members > pool:
        raise ConfigError(f"--members {members}: the {pool} train+val tracks of {dataset} cannot be cut into "
                          f"{members} folds; ask for fewer members or simulate more tracks")
    from ..data.store import check_disk_space

    check_disk_space(fresh_recipe(cfg, fresh_tracks_n), out)
    with atomic_folder(out, command="select", inputs=inputs) as tmp:
        fresh = fresh_tracks(cfg, fresh_tracks_n, tmp / "fresh")
        rows = []
        console = "bar" if sys.stderr.isatty() else "none"  # one line per member; a bar while it trains
        for i in range(members):
            data = replace(cfg.data, fold=i, folds=members) if members > 1 else cfg.data
            member = replace(cfg, name=f"{cfg.name}-member{i:02d}", seed=cfg.seed + i, data=data)
            name = f"member-{i:02d}"
            t0 = time.perf_counter()
            m = train(member, tmp / name, console=console, label=f"member {i + 1}/{members}")
            scores = score_on(Tracker.load(tmp / name / "tracker.pt"), fresh)
            print(f"member {i + 1:>{len(str(members))}}/{members}  seed {member.seed}, fold {data.fold}: {m['epochs']} epochs "
                  f"in {time.perf_counter() - t0:.0f} s, validation position RMSE {m['val']['pos_rmse_m']:.1f} m, "
                  f"fresh tracks {scores['pos_rmse_m']:.1f} m", flush=True)
            rows.append({"member": i, "seed": member.seed, "fold": data.fold, "run": name,
                         "val_pos_rmse_m": m["val"]["pos_rmse_m"], "val_vel_rmse_mps": m["val"]["vel_rmse_mps"],
                         "fresh_pos_rmse_m": scores["pos_rmse_m"], "fresh_vel_rmse_mps": scores["vel_rmse_mps"],
                         "epochs": m["epochs"]})
        best = min(rows, key=lambda r: r["fresh_pos_rmse_m"])
        shutil.copyfile(tmp / best["run"] / "tracker.pt", tmp / "best.pt")
        table = selection_table(rows, best["member"], fresh_tracks_n)
        result = {"best": best["member"], "members": rows, "fresh_dataset": "fresh", "table": table,
                  "criterion": "lowest position RMSE on the fresh tracks after the first window",
                  "paths": "relative to this folder"}
        (tmp / "selection.json").write_text(json.dumps(result, indent=2) + "\n")
        (tmp / "selection.md").write_text(table + "\n")
    return result


def selection_table(rows: list[dict], best: int, fresh: int) -> str:
    lines = [
        "| member | seed | fold | epochs | val pos RMSE (m) | val vel RMSE (m/s) | fresh pos RMSE (m) | fresh vel RMSE (m/s) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        mark = " **best**" if r["member"] == best else ""
        lines.append(f"| {r['member']}{mark} | {r['seed']} | {r['fold']} | {r['epochs']} | {r['val_pos_rmse_m']:.2f} | "
                     f"{r['val_vel_rmse_mps']:.3f} | {r['fresh_pos_rmse_m']:.2f} | {r['fresh_vel_rmse_mps']:.3f} |")
    lines.append(f"\nval: every sample of every validation window of the member's fold; fresh: {fresh} new tracks, "
                 "whole sequences tracked by sliding windows, samples after the first window.")
    return "\n".join(lines)
