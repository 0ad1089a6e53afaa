"""``evaluate/fix_consistency.py``: the fix initiator's position NEES over many draws. Where the
fix is linear in the noise (a tiny azimuth deviation) the script's NEES must be chi-square(2);
with the recorded settings it reproduces its record."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
from pathlib import Path

import pytest

from test_track_management import model

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("fix_consistency", ROOT / "evaluate" / "fix_consistency.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("covariance", ["linearised", "unscented"])
def test_in_the_linear_regime_the_nees_is_chi_square_2(covariance):
    """Azimuth deviation 0.01 deg and range 0.1 m: the linearisation is exact to far below the noise,
    so each NEES is chi-square(2): median 1.386, mean 2, 0.1 % beyond 13.8. Tolerances: 4 standard
    errors of each statistic over the sample (median: 1 / (2 f(m) sqrt(n)), f(m) = 1/4; mean: 2 /
    sqrt(n); share: the binomial's)."""
    fc = _script()
    m = dataclasses.replace(model(), noise_std=(0.1, 2.0, math.radians(0.01)))
    out = fc.draw_fixes(m, 3000, (3000.0, 12000.0), seed=0, covariance=covariance)
    for name in ("single", "fused"):
        s = out[name]
        n = s["n"]
        assert n >= 3000 * 0.9, (name, n)
        assert abs(s["median"] - 2 * math.log(2)) < 4 / (2 * 0.25 * math.sqrt(n)), (name, s)
        assert abs(s["mean"] - 2.0) < 4 * 2 / math.sqrt(n), (name, s)
        assert abs(s["share_beyond_999"] - 1e-3) < 4 * math.sqrt(1e-3 * (1 - 1e-3) / n), (name, s)
    # at fixed positions each axis's empirical deviation is the linearised one: within 4 standard
    # errors of a sample deviation's ratio, 1 / sqrt(2 N) each
    fp = fc.fixed_points(m, 7000.0, 2000, seed=1)
    tol = 4 / math.sqrt(2 * 2000)
    for axis in ("short_axis_ratio_range", "long_axis_ratio_range"):
        assert all(abs(v - 1) < tol for v in fp[axis]), (axis, fp[axis])


def test_the_3_degree_fixes_are_not_consistent_and_the_check_would_see_it():
    """The same draws at the scenarios' 3 deg azimuth: the single fixes' tail is many times the
    0.1 % a consistent covariance gives, and at fixed positions the fixes spread along the short
    axis beyond the linearised deviation (what evaluate/RESULTS.md reports; a change that makes
    the covariance consistent must change this test and that record)."""
    fc = _script()
    out = fc.draw_fixes(model(), 3000, (3000.0, 12000.0), seed=0)
    s = out["single"]
    assert s["share_beyond_999"] > 1e-3 + 4 * math.sqrt(1e-3 / s["n"]) and s["mean"] > 2.0 + 4 * 2 / math.sqrt(s["n"])
    # the fixes spread along the short axis beyond what the linearisation gives
    assert fc.fixed_points(model(), 7000.0, 2000, seed=1)["short_axis_ratio_range"][1] > 1 + 4 / math.sqrt(2 * 2000)


@pytest.mark.integration
def test_the_record_reproduces(tmp_path):
    record = json.loads((ROOT / "evaluate/results/fix_consistency.json").read_text())
    out = tmp_path / "fc.json"
    args = ["--draws", str(record["draws"]), "--seed", str(record["seed"]), "--radii", ",".join(str(r) for r in record["radii_m"]),
            "--json", str(out)]
    assert _script().main(args) == 0
    new = json.loads(out.read_text())
    for name in ("single", "fused"):
        assert new[name]["n"] == record[name]["n"]
        for key in ("median", "mean"):
            assert new[name][key] == pytest.approx(record[name][key], rel=1e-6)
        # a NEES at the threshold may cross it by rounding on another CPU: one sample's worth
        assert abs(new[name]["share_beyond_999"] - record[name]["share_beyond_999"]) <= 1.0 / record[name]["n"] + 1e-12
    for axis in ("short_axis_ratio_range", "long_axis_ratio_range"):
        assert new["fixed_points"][axis] == pytest.approx(record["fixed_points"][axis], rel=1e-6)


def test_bad_settings_are_one_line_and_write_nothing(tmp_path, capsys):
    out = tmp_path / "fc.json"
    assert _script().main(["--radii", "5000,1000", "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--radii" in err[0] and not out.exists()


def test_the_unscented_fix_covariance_is_the_linearised_one_where_the_fix_is_linear_and_wider_across_the_range():
    """``fix_spread`` (the fix initiator's ``covariance: unscented``, BP's seed covariance): with a
    0.01 deg azimuth and 0.1 m range deviation the sigma points' fixes move linearly, so the spread
    is ``H^-1 R H^-T`` to the second-order term's share, (sqrt(3) sigma rho / radius of curvature)
    below 1e-4 here: rtol 1e-3. At the scenarios' 3 deg it is wider than the linearised covariance
    along the short axis, where the fixes spread (the test above)."""
    import torch

    from pmsr_nn.trackers.fix_initiator import FixInitiator

    for noise, linear in (((0.1, 2.0, math.radians(0.01)), True), (None, False)):
        m = model() if noise is None else dataclasses.replace(model(), noise_std=noise)
        n = 3 * len(m.pos_idx)
        x = torch.zeros(5, n, dtype=torch.float64)
        x[:, m.pos_idx[0]] = torch.tensor([3000.0, 5000.0, 7000.0, -4000.0, 9000.0])
        x[:, m.pos_idx[1]] = torch.tensor([4000.0, -6000.0, 2000.0, 5000.0, 8000.0])
        z = m.h(x).reshape(5, m.n_pairs, len(m.components)).unsqueeze(2)
        _, lin, ok = FixInitiator().fixes(z, m, n)
        _, uns, ok_u = FixInitiator(covariance="unscented").fixes(z, m, n)
        assert torch.equal(ok, ok_u) and bool(ok.any())
        if linear:
            torch.testing.assert_close(uns[ok], lin[ok], rtol=1e-3, atol=0.0)
        else:  # wider along the linearised short axis
            lam, vec = torch.linalg.eigh(lin[ok])
            short = vec[..., 0]
            across = (short.unsqueeze(-2) @ uns[ok] @ short.unsqueeze(-1)).squeeze() / lam[..., 0]
            assert bool((across > 1.2).any()), across


def test_a_fix_covariance_other_than_the_two_is_refused():
    from pmsr_nn.errors import ConfigError
    from pmsr_nn.trackers.fix_initiator import FixInitiator

    with pytest.raises(ConfigError, match="fix_covariance must be one of linearised, unscented, got 'exact'"):
        FixInitiator(covariance="exact")
