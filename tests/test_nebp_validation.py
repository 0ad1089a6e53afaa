"""evaluate/nebp_validation.py: NEBP checkpoints on a training config's validation scenes. An
untrained network (zero corrections) is BP, so its figures are BP's to the last digit; a
checkpoint for other sensors is one line and exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from pmsr_nn.nets.nebp import NEBPNet, nebp_metadata, save_nebp_checkpoint
from pmsr_nn.nets.nebp_training import Problem, load_nebp_config

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["optim.val_scenes=2", "optim.batch_size=2", "scenes.targets=[2,2]", "scenes.window=12",
         "optim.skip_scans=0", "scenes.births=0.5"]


def _run(*args: str):
    return subprocess.run([sys.executable, str(ROOT / "evaluate/nebp_validation.py"), *args], capture_output=True,
                          text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=600)


@pytest.mark.integration
def test_an_untrained_checkpoint_scores_bp_and_one_for_other_sensors_is_refused(tmp_path):
    pr = Problem(load_nebp_config(ROOT / "train/nebp.yaml", SMALL))
    torch.manual_seed(0)
    net = NEBPNet(pr.model.n_pairs, pr.model.components, hidden=8)  # heads at zero: BP
    meta = nebp_metadata({"g": 1}, list(pr.model.components), list(pr.noise_std), 1.0, 6, net, pr.scales)
    save_nebp_checkpoint(tmp_path / "zero.pt", meta, net)
    proc = _run("--config", str(ROOT / "train/nebp.yaml"), "--checkpoints", str(tmp_path / "zero.pt"), "--set", *SMALL)
    assert proc.returncode == 0, proc.stderr[-2000:]
    bp, zero = proc.stdout.strip().splitlines()
    assert bp.startswith("BP: validation GOSPA ") and zero == bp.replace("BP", str(tmp_path / "zero.pt"), 1)
    other = NEBPNet(pr.model.n_pairs + 1, pr.model.components, hidden=8)
    save_nebp_checkpoint(tmp_path / "other.pt", nebp_metadata({"g": 1}, list(pr.model.components), list(pr.noise_std),
                                                              1.0, 6, other, pr.scales), other)
    proc = _run("--config", str(ROOT / "train/nebp.yaml"), "--checkpoints", str(tmp_path / "other.pt"), "--set", *SMALL)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [f"nebp_validation: {tmp_path / 'other.pt'}: trained for "
                                                f"{pr.model.n_pairs + 1} pairs of {list(pr.model.components)}, the "
                                                f"config's scenes have {pr.model.n_pairs} of "
                                                f"{list(pr.model.components)}"]
