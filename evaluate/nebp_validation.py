"""NEBP checkpoints on the validation scenes of a training config: BP alone and each checkpoint.

The validation of ``pmsr train`` (``kind: nebp``), run on checkpoints made elsewhere: the config's
fixed validation scenes (``(seed, 1_000_000, j)``, never a recorded study's draws), with the
config's settings and any ``--set`` overrides (those of ``pmsr train``: ``scenes.births=0.6``,
``optim.skip_scans=0``). Prints the validation GOSPA (root of the mean GOSPA^2 from
``optim.skip_scans`` on) and loss of BP alone (the untrained network: zero corrections) and of each
checkpoint, which must read the config's sensors.

    python evaluate/nebp_validation.py --config train/nebp_one_sky.yaml --checkpoints models/released/nebp_one_sky_s0.pt --set seed=0 optim.skip_scans=0 scenes.births=0.6
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from pmsr_nn.errors import CheckpointError, PmsrError
from pmsr_nn.nets.nebp import load_nebp_checkpoint
from pmsr_nn.nets.nebp_training import Problem, baseline_validation, load_nebp_config, validate


def validation(config: Path, checkpoints: list[Path], overrides: list[str]) -> dict[str, dict]:
    """``{"BP": figures, path: figures}``: each one's mean validation ``gospa_m`` and ``loss``."""
    cfg = load_nebp_config(config, overrides)
    problem = Problem(cfg)
    out = {"BP": baseline_validation(cfg, problem)}
    for path in checkpoints:
        ck = load_nebp_checkpoint(path)
        if ck.meta["n_pairs"] != problem.model.n_pairs or list(ck.meta["components"]) != list(problem.model.components):
            raise CheckpointError(f"{path}: trained for {ck.meta['n_pairs']} pairs of {ck.meta['components']}, the "
                                  f"config's scenes have {problem.model.n_pairs} of {list(problem.model.components)}")
        out[str(path)] = validate(cfg, problem, ck.net)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, required=True, help="a kind: nebp training config")
    ap.add_argument("--checkpoints", type=Path, nargs="+", required=True, help="NEBP checkpoints")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="config overrides, as pmsr train's")
    a = ap.parse_args()
    torch.set_num_threads(1)
    try:
        figures = validation(a.config, a.checkpoints, a.set)
    except (PmsrError, OSError) as exc:
        print(f"nebp_validation: {exc}", file=sys.stderr)
        sys.exit(2)
    for name, f in figures.items():
        print(f"{name}: validation GOSPA {f['gospa_m']:.1f} m, loss {f['loss']:.4f}", flush=True)


if __name__ == "__main__":
    main()
