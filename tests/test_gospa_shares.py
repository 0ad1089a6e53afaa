"""``evaluate/gospa_shares.py``: the shares of GOSPA^p with their Monte Carlo errors, read from a bank."""

from __future__ import annotations

import numpy as np
import pytest

from pmsr_nn.errors import ConfigError
from pmsr_nn.harness import merge
from pmsr_nn.harness.evaluate import execute
from pmsr_nn.harness.run.runner import open_run
from script_loader import load_script
from test_one_scenario import two_drones

ROWS = [{"name": "own", "kind": "s_msjpda", "options": {"initiation": "detections"}}]


def test_the_error_is_the_delta_methods_and_vanishes_for_a_fixed_share():
    script = load_script("evaluate/gospa_shares.py")
    rng = np.random.default_rng(0)
    parts = {"localisation": rng.uniform(1, 2, 6), "missed": rng.uniform(0, 1, 6), "false": rng.uniform(0, 3, 6)}
    total = sum(parts.values())
    got = script.shares(parts)
    for part, v in parts.items():  # the gradient of mean(v) / mean(total) times the covariance of the two means
        g = np.array([1 / total.mean(), -v.mean() / total.mean() ** 2])
        se = np.sqrt(g @ np.cov(np.stack([v, total])) @ g / len(v))
        assert got[part] == pytest.approx((v.mean() / total.mean(), se), rel=1e-12)
    assert sum(share for share, _ in got.values()) == pytest.approx(1.0, rel=1e-12)
    # every run false in the same proportion: the share is exact, its error 0
    fixed = script.shares({"localisation": 3 * total, "missed": 0 * total, "false": total})
    assert fixed["false"][0] == pytest.approx(0.25, rel=1e-12) and fixed["false"][1] < 1e-9


@pytest.mark.integration
def test_the_shares_are_the_merged_reports_and_blocks_of_several_runs_are_refused(tmp_path):
    path = two_drones(tmp_path, methods=ROWS, mc_runs=3, block_runs=1)
    execute(open_run(path, tmp_path / "bank", target="bank", progress=False))
    row = merge([tmp_path / "bank"], tmp_path / "merged")["cases"]["c"]["methods"]["own"]
    script = load_script("evaluate/gospa_shares.py")
    got = script.shares(script.run_parts(tmp_path / "bank", None, "own"))
    for part in ("localisation", "missed", "false"):
        assert got[part][0] == pytest.approx(row[f"gospa_{part}_share"], rel=1e-12, abs=1e-15)
    (tmp_path / "two").mkdir()
    several = two_drones(tmp_path / "two", methods=ROWS)  # blocks of 2 runs
    execute(open_run(several, tmp_path / "two" / "bank", target="bank", progress=False))
    with pytest.raises(ConfigError, match="blocks of 2 runs: each run's parts need one run per block"):
        script.run_parts(tmp_path / "two" / "bank", None, "own")


@pytest.mark.integration
def test_the_missed_part_splits_into_starts_and_the_rest(tmp_path):
    """Drone a is born at scan 0 (before the 10-scan warm-up), b at scan 20: with 3 start scans the
    missed part at a start is b's scans 20-22 alone, read straight from the block sums; the two
    halves add up to the whole; with start scans as long as the case, nothing is missed elsewhere."""
    from pmsr_nn.harness.run.block_bank import bank_blocks
    from pmsr_nn.harness.run.block_sums import read_shard

    path = two_drones(tmp_path, methods=ROWS, mc_runs=3, block_runs=1, detections={
        "pd": 0.6, "clutter": {"per_scan": 3, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}})
    execute(open_run(path, tmp_path / "bank", target="bank", progress=False))
    script = load_script("evaluate/gospa_shares.py")
    assert script.birth_scans(tmp_path / "bank", "c") == [0, 20]
    whole = script.run_parts(tmp_path / "bank", None, "own")
    split = script.run_parts(tmp_path / "bank", None, "own", start_scans=3)
    assert list(split) == ["localisation", "missed at a start", "missed elsewhere", "false"]
    by_hand = [float(read_shard(f)[1].sums["c"]["own"]["gospa_missed"][0, 20:23].sum() / 90)
               for f in bank_blocks(tmp_path / "bank")]
    np.testing.assert_allclose(split["missed at a start"], by_hand, rtol=1e-12)
    np.testing.assert_allclose(split["missed at a start"] + split["missed elsewhere"], whole["missed"], rtol=1e-12)
    assert (split["missed at a start"] > 0).any()  # Pd 0.6: some run starts b a scan or more late
    every = script.run_parts(tmp_path / "bank", None, "own", start_scans=100)
    np.testing.assert_allclose(every["missed elsewhere"], 0.0, atol=1e-9 * whole["missed"].max())
    with pytest.raises(ConfigError, match="--start-scans must be at least 0"):
        script.run_parts(tmp_path / "bank", None, "own", start_scans=-1)
