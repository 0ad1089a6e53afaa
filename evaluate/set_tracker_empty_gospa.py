"""The set tracker's "no target" GOSPA: what answering the empty set scores on the validation scenes
of a ``kind: set_tracker`` training config, per training seed, as training logs it
(``val/gospa_empty_set_m``: per validation batch sqrt(c^2 / 2 x targets / windows), averaged over
the batches). It draws the scenes (``SceneSampler.draw`` with the seeds validation uses) and counts
their targets; no network is read.

    python evaluate/set_tracker_empty_gospa.py [--config train/set_tracker.yaml] [--seeds 0,1,2]
        [--json evaluate/results/set_tracker_empty_gospa.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def empty_set_gospa(cfg, sampler, seed: int) -> dict:
    """Per validation batch the targets per window and the empty set's GOSPA (m), and their mean."""
    batches = []
    for i in range(cfg.optim.val_batches):
        _, truth, _, _, _ = sampler.draw((seed, 1_000_000, i), cfg.optim.batch_size)  # set_training's validation seeds
        targets = truth.shape[2]  # truth (windows, scans, targets, state): every window of a batch has as many
        batches.append({"windows": truth.shape[0], "targets_per_window": targets,
                        "gospa_empty_set_m": math.sqrt(cfg.optim.cutoff_m ** 2 / 2 * targets)})
    return {"batches": batches, "gospa_empty_set_m": sum(b["gospa_empty_set_m"] for b in batches) / len(batches)}


def main(argv=None) -> int:
    from pmsr_nn.errors import ConfigError
    from pmsr_nn.nets.scene_data import SceneSampler
    from pmsr_nn.nets.set_training import load_set_config

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default=str(ROOT / "train" / "set_tracker.yaml"))
    ap.add_argument("--seeds", default="0,1,2", help="training seeds, comma-separated")
    ap.add_argument("--json", help="write the record here")
    a = ap.parse_args(argv)
    try:
        seeds = [int(s) for s in a.seeds.split(",")]
        cfg = load_set_config(a.config)
    except (ConfigError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    sampler = SceneSampler(cfg.recipe, cfg.scenes)
    out = {str(s): empty_set_gospa(cfg, sampler, s) for s in seeds}
    for s, r in out.items():
        print(f"seed {s}: targets per window {[b['targets_per_window'] for b in r['batches']]}, "
              f"'no target' GOSPA {r['gospa_empty_set_m']:.1f} m")
    config = Path(a.config).resolve()
    record = {"config": config.relative_to(ROOT).as_posix() if config.is_relative_to(ROOT) else a.config,
              "cutoff_m": cfg.optim.cutoff_m, "val_scenes": cfg.optim.val_scenes,
              "batch_size": cfg.optim.batch_size, "seeds": out,
              "info": {"date": date.today().isoformat(), "seconds": round(time.perf_counter() - start, 1),
                       "command": "python evaluate/set_tracker_empty_gospa.py " + " ".join(argv if argv is not None else sys.argv[1:])}}
    if a.json:
        Path(a.json).write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
