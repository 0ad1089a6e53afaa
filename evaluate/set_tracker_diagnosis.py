"""Where a set tracker checkpoint (pmsr_nn/nets/set_tracker.py) loses: its stages, one by one, on
fresh scenes of its training distribution.

Per stage, against the simulator's truth and detection origins:

* *seeds*: the share of the queries' seed tokens that are a target's detection (the base rate is
  the share of such tokens among all);
* *association*: per query matched to a target (Hungarian, as the loss), the share of its top-k
  association weight on that target's own detections, and the share of those detections in its top k;
* *state*: the matched queries' position errors before and after the refinement, and after the
  same Gauss-Newton steps on the target's own detections alone (the association made perfect);
* *existence*: the existence probabilities of matched and unmatched queries;
* *GOSPA* (c 500 m, p 2) of the predictions that say they exist, beside the empty set's.

    python evaluate/set_tracker_diagnosis.py --checkpoint CK [--batches 4 --scenes 32 --json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    from pmsr_nn.nets.scene_data import SceneConfig, SceneSampler
    from pmsr_nn.nets.set_inference import load_set_checkpoint
    from pmsr_nn.nets.set_refine import gauss_newton
    from pmsr_nn.nets.set_tracker import detection_tokens, match
    from pmsr_nn.nets.set_training import gospa_parts

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--batches", type=int, default=4)
    ap.add_argument("--scenes", type=int, default=32, help="scenes per batch (one target count per batch)")
    ap.add_argument("--seed", type=int, default=77)
    ap.add_argument("--reassociate", type=int, help="re-association rounds at inference (default: the checkpoint's)")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    ck = load_set_checkpoint(a.checkpoint)
    net, cut = ck.net, 500.0
    if a.reassociate is not None:
        net.cfg = replace(net.cfg, reassociate=a.reassociate)
    scenes = ck.meta["training"]["config"]["scenes"]
    sampler = SceneSampler(str(ROOT / "datasets" / "fitee2023_ca.yaml"), SceneConfig(**{
        k: tuple(v) if isinstance(v, list) else v for k, v in scenes.items()}))
    stats = {k: [] for k in ("seed_is_target", "base_rate", "own_weight_share", "own_recall", "error_start_m",
                             "error_refined_m", "error_true_association_m", "p_matched", "p_unmatched")}
    sq = missed = false = n_truth = windows = 0
    with torch.no_grad():
        for b in range(a.batches):
            scans, truth, *_ = sampler.draw((a.seed, b), a.scenes)
            toks = detection_tokens(scans.z, scans.valid, sampler.model, net.cfg)
            out = net(toks)
            origin = scans.origin.reshape(a.scenes, -1)
            usable = torch.isfinite(out.objectness)
            tp = truth[:, -1][..., [0, 3]]
            Q = out.pos.shape[1]
            seed = out.objectness.topk(Q, -1).indices
            stats["seed_is_target"].append(float((origin.gather(1, seed) >= 0).double().mean()))
            stats["base_rate"].append(float((origin[usable] >= 0).double().mean()))
            p = torch.sigmoid(out.logit)
            iw, iq, jn = [], [], []  # the matched (window, query, target) triples of the batch
            for w in range(a.scenes):  # GOSPA and the Hungarian matching: one assignment problem per window
                s2, ok, mi, fa = gospa_parts(out.pos[w], p[w], tp[w], cut)
                sq, missed, false, n_truth, windows = sq + s2, missed + mi, false + fa, n_truth + len(tp[w]), windows + 1
                d = torch.cdist(out.pos[w].double(), tp[w].double()).numpy()
                rows, cols = match(np.minimum(d, cut) / cut - p[w].double().numpy()[:, None])
                iw += [w] * len(rows)
                iq += rows.tolist()
                jn += cols.tolist()
            iw, iq, jn = torch.tensor(iw), torch.tensor(iq), torch.tensor(jn)
            matched = torch.zeros_like(p, dtype=torch.bool)
            matched[iw, iq] = True
            stats["p_unmatched"] += p[~matched].tolist()
            stats["p_matched"] += p[iw, iq].tolist()
            top, idx = out.assoc[iw, iq].topk(min(net.cfg.top_k, out.assoc.shape[-1]))  # (P, k)
            wk = torch.sigmoid(top).double()
            mine = origin[iw] == jn[:, None]  # (P, T): each matched target's own detections
            own = mine.gather(1, idx).double()
            stats["own_weight_share"] += ((wk * own).sum(-1) / wk.sum(-1).clamp_min(1e-12)).tolist()
            stats["own_recall"] += (own.sum(-1) / mine.sum(-1).clamp_min(1)).tolist()
            truth_pos = tp[iw, jn]
            stats["error_start_m"] += (out.pos0[iw, iq] - truth_pos).norm(dim=-1).tolist()
            stats["error_refined_m"] += (out.pos[iw, iq] - truth_pos).norm(dim=-1).tolist()
            # the same refinement on each target's own detections alone (every other token weighs 0)
            pos, _, _ = gauss_newton(out.pos0[iw, iq], out.vel[iw, iq], toks.z[iw], toks.pair[iw], toks.age[iw],
                                     mine.double(), net.model, net.dt, net.dim_x, max(net.cfg.refine_iterations, 1),
                                     (net.cfg.prior_position_m, net.cfg.prior_velocity_mps))
            stats["error_true_association_m"] += (pos - truth_pos).norm(dim=-1).tolist()
    c2 = cut**2 / 2
    report = {"checkpoint": str(a.checkpoint), "reassociate": net.cfg.reassociate, "command": "python evaluate/set_tracker_diagnosis.py " + " ".join(
                  sys.argv[1:] if argv is None else argv), "windows": windows,
              "gospa_m": math.sqrt((sq + c2 * (missed + false)) / windows),
              "gospa_empty_set_m": math.sqrt(c2 * n_truth / windows),
              "missed_per_window": missed / windows, "false_per_window": false / windows}
    for k, v in stats.items():
        v = np.asarray(v, dtype=float)
        report[k] = {"n": int(v.size), "mean": float(v.mean()), "median": float(np.median(v)),
                     "p90": float(np.quantile(v, 0.9))}
    for k, v in report.items():
        print(f"{k:26s} {v}")
    if a.json:
        a.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
