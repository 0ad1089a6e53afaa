"""Are the fix initiator's covariances consistent? Position NEES of its fixes over many draws.

The fix initiator (:class:`pmsr_nn.trackers.fix_initiator.FixInitiator`) starts every track of a
scenario whose detections measure azimuth. Its agreement gate and each new track's covariance
read the linearised covariance ``H^-1 R H^-T`` of a pair's (bistatic range, azimuth) fix. This
script draws ``--draws`` positions uniformly over the annulus ``--radii`` (m) around the origin.
It measures each with the scenario's detection model and noise: every pair detects, no clutter.
It then prints the position NEES of:

* each pair's single fix;
* the fused fix of all agreeing pairs (the tracks' initial position; ``min_pairs`` 2).

For each, the NEES's median and mean, and the share beyond the chi-square(2) 99.9 % point (13.8),
overall and by the fix's distance from its receiver. A consistent covariance gives a median of
1.39, a mean of 2 and a share of 0.1 %. It also gives, at three fixed positions, the fixes' empirical deviation
along each principal axis of the linearised covariance at the true measurement over that axis's
linearised deviation (:func:`fixed_points`): where it is far from 1 the linearisation itself
misses the spread, wherever it is evaluated.

    python evaluate/fix_consistency.py [--scenario evaluate/one_sky_bp.yaml] [--draws 4000] [--seed 0]
        [--radii 2000,12000] [--covariance linearised|unscented] [--json evaluate/results/fix_consistency.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from datetime import date
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
CHI2_2_999 = -2.0 * math.log(1e-3)
"""The chi-square(2) 99.9 % point: 13.82."""
DISTANCE_BANDS_M = (0.0, 3000.0, 6000.0, 9000.0, 12000.0, math.inf)
"""The bands of a fix's distance from its receiver (m) the single fixes' NEES is given for."""


def summary(v: torch.Tensor) -> dict:
    """The NEES sample's count, median, mean and share beyond :data:`CHI2_2_999`."""
    return {"n": int(v.numel()), "median": float(v.median()), "mean": float(v.mean()),
            "share_beyond_999": float((v > CHI2_2_999).double().mean())}


def draw_fixes(model, draws: int, radii: tuple[float, float], seed: int, covariance: str = "linearised") -> dict:
    """NEES of the single and fused fixes of ``draws`` positions (module docstring), measured by
    ``model`` (a pair-layout :class:`~pmsr_nn.measurements.MeasurementModel` with azimuth), with the
    fix covariance ``covariance`` (:data:`~pmsr_nn.trackers.fix_initiator.FIX_COVARIANCES`)."""
    from pmsr_nn.trackers.fix_initiator import FixInitiator
    from pmsr_nn.trackers.gating import mahalanobis

    g = torch.Generator().manual_seed(seed)
    lo, hi = radii
    r = torch.sqrt(lo**2 + (hi**2 - lo**2) * torch.rand(draws, generator=g, dtype=torch.float64))  # uniform in area
    b = 2 * math.pi * torch.rand(draws, generator=g, dtype=torch.float64)
    n = 3 * len(model.pos_idx)
    pos_idx = list(model.pos_idx)
    x = torch.zeros(draws, n, dtype=torch.float64)
    x[:, pos_idx[0]], x[:, pos_idx[1]] = r * torch.sin(b), r * torch.cos(b)
    S, d = model.n_pairs, len(model.components)
    sd = torch.tensor(model.noise_std, dtype=torch.float64)
    z = (model.h(x).reshape(draws, S, d) + torch.randn(draws, S, d, generator=g, dtype=torch.float64) * sd).unsqueeze(2)
    ini = FixInitiator(covariance=covariance)
    pos, cov, ok = ini.fixes(z, model, n)
    truth = x[:, pos_idx]
    single = mahalanobis(pos[:, :, 0] - truth[:, None], cov[:, :, 0])  # (draws, S)
    ok = ok[:, :, 0]
    dist = (pos[:, :, 0] - model.geometry.pair_rx_positions(torch.float64)[None]).norm(dim=-1)
    bands = []
    for a, c in zip(DISTANCE_BANDS_M[:-1], DISTANCE_BANDS_M[1:]):
        sel = ok & (dist >= a) & (dist < c)
        if bool(sel.any()):
            bands.append({"from_m": a, "to_m": None if math.isinf(c) else c, **summary(single[sel])})
    other = torch.ones(n, dtype=torch.float64)
    gs, real = ini.initiate(z, torch.ones(draws, S, 1, dtype=torch.bool), model, n, other)
    first = real[:, 0]
    P = gs.P[first, 0][:, pos_idx][:, :, pos_idx]
    fused = mahalanobis(gs.x[first, 0][:, pos_idx] - truth[first], P)
    return {"single": summary(single[ok]), "single_by_distance": bands, "fused": summary(fused),
            "fused_share_of_draws": float(first.double().mean())}


def fixed_points(model, radius: float, draws: int, seed: int) -> dict:
    """At three fixed positions ``radius`` m out (bearings 30, 150 and 270 deg), each pair's fixes of
    ``draws`` noisy measurements: the empirical deviation of their errors along each principal axis
    of the linearised covariance at the true measurement, over that axis's linearised deviation
    (1 where the linearisation holds). ``ratios`` ``[point][pair][axis]``, the short axis first
    (None: no fix there), and each axis's range of ratios."""
    from pmsr_nn.trackers.fix_initiator import FixInitiator

    g = torch.Generator().manual_seed(seed)
    n, pos_idx = 3 * len(model.pos_idx), list(model.pos_idx)
    S, d = model.n_pairs, len(model.components)
    sd = torch.tensor(model.noise_std, dtype=torch.float64)
    ini, ratios = FixInitiator(), []
    for bearing in (30.0, 150.0, 270.0):
        x = torch.zeros(1, n, dtype=torch.float64)
        x[0, pos_idx[0]], x[0, pos_idx[1]] = radius * math.sin(math.radians(bearing)), radius * math.cos(math.radians(bearing))
        clean = model.h(x).reshape(1, S, d)
        _, cov0, ok0 = ini.fixes(clean.unsqueeze(2), model, n)
        z = (clean + torch.randn(draws, S, d, generator=g, dtype=torch.float64) * sd).unsqueeze(2)
        pos, _, ok = ini.fixes(z, model, n)
        err = pos[:, :, 0] - x[:, pos_idx]  # (draws, S, 2)
        row = []
        for s_ in range(S):
            keep = ok[:, s_, 0]
            if not bool(ok0[0, s_, 0]) or int(keep.sum()) < draws // 2:
                row.append(None)
                continue
            lam, vec = torch.linalg.eigh(cov0[0, s_, 0])
            proj = err[keep, s_] @ vec  # (kept, 2): errors along the principal axes
            row.append([float(v) for v in proj.std(0) / lam.sqrt()])
        ratios.append(row)
    kept = [r for row in ratios for r in row if r is not None]
    return {"radius_m": radius, "draws": draws, "ratios": ratios,
            "short_axis_ratio_range": [min(r[0] for r in kept), max(r[0] for r in kept)],
            "long_axis_ratio_range": [min(r[1] for r in kept), max(r[1] for r in kept)]}


def main(argv=None) -> int:
    from pmsr_nn.errors import ConfigError
    from pmsr_nn.harness.run.runner import prepare
    from pmsr_nn.harness.scenario.schema import load_scenario

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default=str(ROOT / "evaluate" / "one_sky_bp.yaml"))
    ap.add_argument("--draws", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--radii", default="2000,12000", help="inner,outer radius (m) of the drawn positions")
    ap.add_argument("--covariance", default="linearised", choices=("linearised", "unscented"),
                    help="the fix covariance whose NEES is measured (the initiator's option fix_covariance)")
    ap.add_argument("--json", help="write the record here")
    a = ap.parse_args(argv)
    try:
        radii = tuple(float(v) for v in a.radii.split(","))
        if len(radii) != 2 or not 0 <= radii[0] < radii[1]:
            raise ValueError(f"--radii must be inner,outer with 0 <= inner < outer, got {a.radii!r}")
        if a.draws < 10:
            raise ValueError(f"--draws must be at least 10, got {a.draws}")
        model = prepare(load_scenario(a.scenario)).cases[0].sensing.detection_model
        if model is None or "azimuth" not in model.components:
            raise ConfigError(f"{a.scenario}: its detections must measure azimuth (the fix initiator's input)")
    except (ConfigError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    with torch.no_grad():
        out = draw_fixes(model, a.draws, radii, a.seed, a.covariance)
        out["fixed_points"] = fixed_points(model, (radii[0] + radii[1]) / 2, 5 * a.draws, a.seed + 1)
    for name in ("single", "fused"):
        s = out[name]
        print(f"{name} fixes ({s['n']}): NEES median {s['median']:.2f} (1.39), mean {s['mean']:.1f} (2), "
              f"beyond the 99.9 % point {100 * s['share_beyond_999']:.1f} % (0.1 %)")
    fp = out["fixed_points"]
    short, long_ = fp["short_axis_ratio_range"], fp["long_axis_ratio_range"]
    print(f"at three fixed positions {fp['radius_m']:.0f} m out, {fp['draws']} draws each, the fixes' empirical deviation "
          f"over the linearised one: short axis {short[0]:.2f}-{short[1]:.2f}, long axis {long_[0]:.2f}-{long_[1]:.2f} (1: "
          f"the linearisation holds)")
    for band in out["single_by_distance"]:
        print(f"  single, {band['from_m']:.0f}-{band['to_m'] or 'inf'} m from the receiver ({band['n']}): median "
              f"{band['median']:.2f}, beyond 99.9 % {100 * band['share_beyond_999']:.1f} %")
    scenario = Path(a.scenario).resolve()
    record = {"scenario": scenario.relative_to(ROOT).as_posix() if scenario.is_relative_to(ROOT) else a.scenario,
              "draws": a.draws, "seed": a.seed, "radii_m": list(radii), "noise_std": list(model.noise_std),
              "covariance": a.covariance,
              "chi2_2_999": CHI2_2_999, **out,
              "info": {"date": date.today().isoformat(), "seconds": round(time.perf_counter() - start, 1),
                       "command": "python evaluate/fix_consistency.py " + " ".join(argv if argv is not None else sys.argv[1:])}}
    if a.json:
        Path(a.json).write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
