"""Ablation: a planar (2-D) EKF tracking targets that fly at an altitude above ground sensors.

Reproduces Table 7 and Fig. 11 of the MDFNN paper (Xu, Yi et al., FITEE 2023, Section 4.4): the
1T-3R geometry of ``datasets/fitee2023_ca.yaml``, targets in level flight at altitude
``h = 0, 100, 200, 300, 500 m`` above ground sensors (z = 0), measured with the 3-D bistatic
range / range-rate / azimuth model, and tracked by an EKF that uses the 2-D CA motion model and
the 2-D (planar) measurement model. At ``h = 0`` that EKF is the matched filter; above it every
bistatic range it is given is longer than the planar one by about ``h^2 / (2 d)`` per leg
(``d`` the horizontal distance of that leg), a bias the filter does not know about.

    python evaluate/ablation_altitude.py --out runs/ablation_altitude
    python evaluate/ablation_altitude.py --out /tmp/alt --tracks 300 --steps 300 --altitudes 0 500

What is drawn, and what changes between rows
    Truth: ``--tracks`` tracks of the recipe's (envelope) variant drawn ONCE with the package's
    3-D generator (``generate_tracks`` on the recipe with ``dim = 3``) at altitude 0, so its
    envelope and near-sensor checks (50 m, ``min_sensor_distance_m``) act on the horizontal
    path. For altitude ``h`` the same states get ``z = h`` (``vz = az = 0``: level flight, the
    recipe's ``q_psd_vertical = 0``). Drawing at each altitude instead would make the
    near-sensor check vacuous for ``h >= 50 m`` (a track could pass right over a receiver, where
    the planar model is singular) and could change which tracks are kept; with the draw at
    ``h = 0`` the horizontal motion is identical in every row (a test checks that it also equals
    what ``generate_tracks`` gives at altitude ``h`` when no rejection differs).
    Measurements: the paper's simulation deviations, the same for every track: 30 m (range),
    2 m/s (range-rate), 3 deg (azimuth), not the recipe's per-track uniform draws. The noise
    realisation is the same at every altitude too (common random numbers, one seeded stream per
    chunk), so the only thing that changes between rows is ``h``.
    Prior: per track, mean = 2-D truth at step 0 + a draw from N(0, P0), P0 =
    diag(``initiation_prior_sd()**2``) (100 m, 5 m/s, 0.02 m/s^2 per axis); the same draw for
    every altitude. Tracker: ``pmsr_nn.filters.ekf`` with the 2-D CA model, the recipe's
    effective jerk PSD ``q`` (1e-7 m^2/s^5 for the envelope variant) and ``R`` = diag(30 m,
    2 m/s, 3 deg)^2.

RMSE (printed with the table)
    Eq. 31 of the paper: at each step, the root of the mean over tracks of the squared
    horizontal (x, y) position error; ``rmse_pos_m`` is that curve averaged over the steps from
    ``--warmup`` (default 100) to the end. ``pooled_rmse_pos_m`` is the root of the mean over
    tracks and those steps; ``mean_track_rmse_pos_m`` the mean over tracks of each track's own
    RMSE over those steps (one reading of the caption "means of the position tracking RMSE for
    10 000 trajectories"). A track is *diverged* when its own RMSE over those steps exceeds 1 km
    or is not finite; diverged tracks stay in every RMSE (never dropped). A chunk in which the
    EKF stops on a non-finite state is split until the failing tracks are isolated; those get
    NaN estimates, are counted as non-finite, and make the RMSE NaN (reported, not hidden).
    ANEES is the mean over tracks and steps of ``e^T P^-1 e / 6`` (6-D state; 1 when consistent).
    The per-trajectory filtering PCRB of the matched planar problem (h = 0) is given for scale.

Track length (``--steps``, default 1000)
    The paper does not state how long its 10 000 tracks are; its dataset tracks are 1000 s and
    the recipe's default is 1000 samples at T = 1 s, so we use 1000. One timing run on this
    project's 2-core CPU (idle, 2 torch threads; 500 tracks x 1000 steps x 5 altitudes) took
    7.7 s of compute (EKF 5.9 s, PCRB 1.0 s, truth 0.24 s); time is linear in tracks x steps,
    so the full 10 000 tracks take a few minutes (the recorded full run: 128 s of wall-clock,
    ``environment.wall_seconds`` in evaluate/results/ablation_altitude/results.json), well inside a
    10-15 minute budget and no reason to shorten the tracks. On a CPU shared with another multi-threaded job, use
    ``--threads 1``: with another 2-thread job holding both cores, a small run with 2 torch
    threads was measured about 50x slower than on the idle machine.

Outputs (``--out DIR``, required; written into a temporary folder beside DIR and renamed at the
end, so a failed run leaves no DIR; an existing DIR is replaced only with ``--overwrite`` and only
where an ablation wrote it and it holds nothing else, the rule of every ablation script,
:mod:`pmsr_nn.harness.ablation`): ``results.json`` (per altitude: RMSE, |RMSE - RMSE_0|, pooled,
diverged count, seconds; settings, environment), ``table.md`` (ours beside the paper's Table 7,
the paper's column labelled as a reference) and ``rmse_vs_time.png`` (the Fig. 11 analogue).
Nothing is trained: the table's time column is the EKF's. Bad input is one line ``error: ...``
and exit code 2, with nothing written.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch
from tqdm.auto import tqdm

import pmsr_nn
from pmsr_nn.bounds import pcrb
from pmsr_nn.errors import PmsrError
from pmsr_nn.filters import FilterError, Gaussian, ekf
from pmsr_nn.harness.ablation import OVERWRITE_HELP, ScriptParser
from pmsr_nn.metrics import squared_error
from pmsr_nn.outputs import atomic_folder, check_folder_target
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.recipe import TrackRecipe, load_recipe
from pmsr_nn.simulation.tracks import build_models, generate_tracks

ROOT = Path(__file__).resolve().parents[1]
RECIPE = ROOT / "datasets" / "fitee2023_ca.yaml"
PAPER_TABLES = ROOT / "evaluate" / "reference" / "paper_tables.json"
PAPER_KEY = ("fitee2023_mdfnn", "table7_altitude_ekf_rmse_pos_m")

DEFAULT_ALTITUDES = (0.0, 100.0, 200.0, 300.0, 500.0)
NOISE_STD = (30.0, 2.0, math.radians(3.0))  # range (m), range-rate (m/s), azimuth (rad)
CHUNK_TRACKS = 1000  # tracks per batched EKF call (a 1000 x 1000-step chunk peaks near 1 GB)
DIVERGED_M = 1000.0
# Independent random streams of seeded_generator(seed, stream, chunk).
STREAM_TRUTH, STREAM_NOISE, STREAM_PRIOR = 1, 2, 3
POS2, VEL2 = (0, 3), (1, 4)  # horizontal position / velocity columns of the 2-D and 3-D CA states
Z_COLS = (6, 7, 8)  # z, vz, az of the 3-D state


class InputError(ValueError):
    """Bad input from the user: reported as one line ``error: ...`` and exit code 2."""


# -- recipes and draws --------------------------------------------------------------------
def recipes(steps: int, seed: int, altitude_m: float = 0.0, base: TrackRecipe | None = None) -> tuple[TrackRecipe, TrackRecipe]:
    """The planar recipe the EKF uses and the 3-D recipe of targets at ``altitude_m``.

    ``tracks`` of the recipe is left alone: the generator is told how many tracks to draw, and
    the recipe's split check would refuse fewer than 10.
    """
    base = load_recipe(RECIPE) if base is None else base
    motion = replace(base.motion, steps=steps, initial=replace(base.motion.initial, altitude_m=(altitude_m, altitude_m)))
    planar = replace(base.with_overrides(seed=seed, dim=2), window=min(base.window, steps), motion=replace(motion, initial=base.motion.initial))
    lifted = replace(planar, dim=3, motion=motion)
    return planar, lifted


def draw_ground_truth(recipe3d_ground: TrackRecipe, n: int, seed: int, chunk: int) -> torch.Tensor:
    """3-D truth ``(n, K, 9)`` at altitude 0 for chunk ``chunk`` (the horizontal motion of every row)."""
    if recipe3d_ground.dim != 3 or recipe3d_ground.motion.initial.altitude_m != (0.0, 0.0):
        raise ValueError("the ground truth is drawn with the 3-D recipe at altitude 0")
    batch, _ = generate_tracks(recipe3d_ground, n, seeded_generator(seed, STREAM_TRUTH, chunk))
    return batch.states


def at_altitude(states: torch.Tensor, altitude_m: float) -> torch.Tensor:
    """The same 3-D states in level flight at ``altitude_m``: z = h, vz = az = 0."""
    out = states.clone()
    out[..., Z_COLS[0]] = altitude_m
    out[..., Z_COLS[1]] = 0.0
    out[..., Z_COLS[2]] = 0.0
    return out


def prior_for(truth2d: torch.Tensor, sd: torch.Tensor, seed: int, chunk: int) -> Gaussian:
    """Per-track prior: mean = truth at step 0 + N(0, diag(sd^2)), covariance diag(sd^2)."""
    n, d = truth2d.shape[0], truth2d.shape[-1]
    x0 = truth2d[:, 0] + torch.randn(n, d, generator=seeded_generator(seed, STREAM_PRIOR, chunk), dtype=truth2d.dtype) * sd
    return Gaussian(x0, torch.diag(sd**2).expand(n, d, d).clone())


def ekf_isolating_failures(prior: Gaussian, z: torch.Tensor, motion, dt: float, q, model, R) -> tuple[torch.Tensor, torch.Tensor, int]:
    """EKF means ``(B, K, n)`` and covariances; runs on which the EKF fails (a non-finite state or
    covariance, :class:`FilterError`) are isolated by halving the batch and get NaN estimates.
    Returns ``(x, P, failed_runs)``."""
    try:
        res = ekf(prior, z, motion, dt, q, model, R)
        return res.x, res.P, 0
    except FilterError:
        B = z.shape[0]
        if B == 1:
            n = prior.x.shape[-1]
            nan = float("nan")
            return z.new_full((1, z.shape[1], n), nan), z.new_full((1, z.shape[1], n, n), nan), 1
        h = B // 2
        parts = [ekf_isolating_failures(Gaussian(prior.x[s], prior.P[s]), z[s], motion, dt, q, model, R)
                 for s in (slice(0, h), slice(h, B))]
        return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]), parts[0][2] + parts[1][2]


# -- the study ----------------------------------------------------------------------------
def check_inputs(tracks: int, steps: int, altitudes, seed: int, warmup: int) -> list[float]:
    """Validate the study's parameters; returns the altitudes as sorted floats."""
    if tracks < 1:
        raise InputError(f"--tracks must be at least 1, got {tracks}")
    if steps < 2:
        raise InputError(f"--steps must be at least 2, got {steps}")
    if seed < 0:
        raise InputError(f"--seed must be non-negative, got {seed}")
    if not 0 <= warmup < steps:
        raise InputError(f"--warmup must be in [0, --steps) = [0, {steps}), got {warmup}")
    alts = [float(h) for h in altitudes]
    if not alts:
        raise InputError("give at least one altitude")
    bad = [h for h in alts if not (math.isfinite(h) and h >= 0)]
    if bad:
        raise InputError(f"altitudes must be finite and non-negative (m), got {bad[0]:g}")
    if len(set(alts)) != len(alts):
        raise InputError(f"altitudes must be distinct, got {[f'{h:g}' for h in alts]}")
    if 0.0 not in alts:
        raise InputError("altitudes must include 0 (RMSE_0, the reference of |RMSE - RMSE_0|)")
    return sorted(alts)


def run(tracks: int = 10_000, steps: int = 1000, altitudes=DEFAULT_ALTITUDES, seed: int = 0, warmup: int = 100,
        chunk_tracks: int = CHUNK_TRACKS, progress: bool = True) -> dict:
    """Run the study; returns the results (JSON-ready) with per-altitude RMSE curves.

    ``chunk_tracks`` is part of the draw (each chunk has its own random streams): the same
    ``(seed, chunk_tracks)`` give the same numbers, and a run with more tracks extends one with
    fewer.
    """
    alts = check_inputs(tracks, steps, altitudes, seed, warmup)
    if chunk_tracks < 1:
        raise InputError(f"chunk_tracks must be at least 1, got {chunk_tracks}")
    planar, ground = recipes(steps, seed, 0.0)
    motion2, model2 = build_models(planar)
    dt, q = planar.motion.dt_s, planar.effective_motion().q_psd
    sd = planar.initiation_prior_sd()
    P0 = torch.diag(sd**2)
    noise = torch.tensor(NOISE_STD, dtype=torch.float64)
    R = model2.R(noise)
    # One 3-D measurement model per altitude; build_models(recipe at h) is the package's own.
    model3 = {h: build_models(recipes(steps, seed, h)[1])[1] for h in alts}

    K, n_chunks = steps, math.ceil(tracks / chunk_tracks)
    sse_pos = {h: torch.zeros(K, dtype=torch.float64) for h in alts}
    sse_vel = {h: torch.zeros(K, dtype=torch.float64) for h in alts}
    track_mse = {h: [] for h in alts}  # per-track mean squared position error over steps >= warmup
    nees_sum = {h: 0.0 for h in alts}
    failed = {h: 0 for h in alts}
    seconds = {h: 0.0 for h in alts}
    bound_sum = torch.zeros(K, 6, 6, dtype=torch.float64)
    t_truth = t_bound = 0.0
    bar = tqdm(total=n_chunks * len(alts), unit="altitude-chunk", desc="altitude study", disable=None if progress else True, leave=False)
    for c in range(n_chunks):
        n = min(chunk_tracks, tracks - c * chunk_tracks)
        t0 = time.perf_counter()
        ground_truth = draw_ground_truth(ground, n, seed, c)
        truth2 = ground_truth[..., :6]  # [x, vx, ax, y, vy, ay]: the planar model's state
        prior = prior_for(truth2, sd, seed, c)
        t_truth += time.perf_counter() - t0
        t0 = time.perf_counter()
        bound_sum += pcrb(truth2, motion2, dt, q, model2, R, P0, form="per_trajectory", smoothing=False).filtering * n
        t_bound += time.perf_counter() - t0
        for h in alts:
            bar.set_postfix_str(f"chunk {c + 1}/{n_chunks}, h = {h:g} m")
            t0 = time.perf_counter()
            z = model3[h].sample(at_altitude(ground_truth, h), noise, generator=seeded_generator(seed, STREAM_NOISE, c))
            x, P, bad = ekf_isolating_failures(prior, z, motion2, dt, q, model2, R)
            seconds[h] += time.perf_counter() - t0
            e2 = squared_error(x, truth2, POS2)  # (n, K)
            sse_pos[h] += e2.sum(0)
            sse_vel[h] += squared_error(x, truth2, VEL2).sum(0)
            track_mse[h].append(e2[:, warmup:].mean(1))
            err = (x - truth2)[:, warmup:].unsqueeze(-1)
            nees_sum[h] += float((err.transpose(-1, -2) @ torch.linalg.solve(P[:, warmup:], err)).sum()) / 6
            failed[h] += bad
            bar.update(1)
    bar.close()

    curves, cases = {}, {}
    bound_pos = torch.diagonal(bound_sum / tracks, dim1=-2, dim2=-1)[..., list(POS2)].sum(-1).sqrt()
    bound_vel = torch.diagonal(bound_sum / tracks, dim1=-2, dim2=-1)[..., list(VEL2)].sum(-1).sqrt()
    for h in alts:
        rmse_t = (sse_pos[h] / tracks).sqrt()
        mse_track = torch.cat(track_mse[h])
        rms_track = mse_track.sqrt()
        diverged = ~torch.isfinite(rms_track) | (rms_track > DIVERGED_M)
        curves[h] = rmse_t
        cases[h] = {
            "altitude_m": h,
            "rmse_pos_m": float(rmse_t[warmup:].mean()),
            "rmse_vel_mps": float((sse_vel[h] / tracks).sqrt()[warmup:].mean()),
            "pooled_rmse_pos_m": float(mse_track.mean().sqrt()),
            "mean_track_rmse_pos_m": float(rms_track.mean()),
            "anees": nees_sum[h] / (tracks * (K - warmup)),
            "diverged": int(diverged.sum()),
            "nonfinite": int((~torch.isfinite(rms_track)).sum()),
            "filter_failures": failed[h],
            "seconds": seconds[h],
            "seconds_per_run": seconds[h] / tracks,
        }
    ref = cases[0.0]["rmse_pos_m"]
    for c in cases.values():
        c["abs_diff_rmse0_m"] = abs(c["rmse_pos_m"] - ref)
        c["relative_increase_pct"] = 100.0 * (c["rmse_pos_m"] - ref) / ref
    return {
        "scenario": "fitee2023_table7_altitude",
        "seed": seed,
        "mc_runs": tracks,
        "settings": {
            "tracks": tracks, "steps": steps, "warmup": warmup, "altitudes_m": alts, "seed": seed,
            "chunk_tracks": chunk_tracks, "recipe": str(RECIPE.relative_to(ROOT)), "variant": planar.variant,
            "dt_s": dt, "q_psd": q, "noise_std": {"range_m": NOISE_STD[0], "range_rate_mps": NOISE_STD[1],
                                                  "azimuth_deg": math.degrees(NOISE_STD[2])},
            "prior_sd": sd.tolist(), "diverged_threshold_m": DIVERGED_M,
            "tracker": "EKF, 2-D CA motion, planar range/range-rate/azimuth model, matched q and R",
            "truth": "3-D CA tracks drawn once at altitude 0, then z = h, vz = az = 0 (level flight)",
            "rmse_definition": ("per step: sqrt(mean over tracks of squared horizontal position error) (Eq. 31); "
                                f"rmse_pos_m = mean of that over steps {warmup}..{steps - 1}; pooled = sqrt(mean over "
                                "tracks and those steps); diverged tracks are included"),
        },
        "cases": {f"h={h:g} m": {"methods": {"EKF (2-D model)": cases[h]},
                                 **({"pcrb": {"pos_m": float(bound_pos[warmup:].mean()),
                                              "vel_mps": float(bound_vel[warmup:].mean()),
                                              "form": "per-trajectory filtering PCRB of the planar (matched) problem"}}
                                    if h == 0.0 else {})}
                  for h in alts},
        "timing": {"truth_and_prior_s": t_truth, "pcrb_s": t_bound, "ekf_by_altitude_s": {f"{h:g}": seconds[h] for h in alts}},
        "curves": {"step": list(range(K)), "rmse_pos_m": {f"{h:g}": curves[h].tolist() for h in alts},
                   "pcrb_pos_m_h0": bound_pos.tolist()},
    }


# -- reporting ----------------------------------------------------------------------------
def rows(res: dict) -> list[dict]:
    return [case["methods"]["EKF (2-D model)"] for case in res["cases"].values()]


def paper_reference() -> dict[float, float]:
    """Table 7 of the paper (a reference to print beside ours, never an input)."""
    try:
        data = json.loads(PAPER_TABLES.read_text())
        table = data[PAPER_KEY[0]][PAPER_KEY[1]]
        return {float(k): float(v) for k, v in table.items()}
    except (OSError, KeyError, ValueError, TypeError):
        return {}


def table_markdown(res: dict) -> str:
    s, paper = res["settings"], paper_reference()
    bound = res["cases"]["h=0 m"]["pcrb"]["pos_m"]
    lines = [
        "# Altitude ablation: planar EKF on targets at altitude h (MDFNN paper, Table 7)",
        "",
        f"{s['tracks']} tracks x {s['steps']} steps (T = {s['dt_s']:g} s), seed {s['seed']}, {s['variant']} variant; "
        f"noise 30 m / 2 m/s / 3 deg for every track; same horizontal tracks, noise and priors at every altitude.",
        f"RMSE: {s['rmse_definition']}.",
        "",
        "| altitude h (m) | ours RMSE (m) | \\|RMSE - RMSE_0\\| (m) | relative increase (%) | pooled RMSE (m) | diverged | "
        "paper RMSE (m, reference) |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows(res):
        p = paper.get(r["altitude_m"])
        lines.append(f"| {r['altitude_m']:g} | {r['rmse_pos_m']:.2f} | {r['abs_diff_rmse0_m']:.2f} | "
                     f"{r['relative_increase_pct']:.2f} | {r['pooled_rmse_pos_m']:.2f} | {r['diverged']} | "
                     f"{'' if p is None else f'{p:.2f}'} |")
    lines += [
        "",
        f"Per-trajectory filtering PCRB of the matched planar problem (h = 0), same averaging: {bound:.2f} m.",
        "The paper column is Table 7 of Xu, Yi et al. (FITEE 2023), copied from "
        "`evaluate/reference/paper_tables.json` for comparison only; its track length, geometry and "
        "motion parameters are not all stated, so the numbers are not expected to match.",
    ]
    return "\n".join(lines) + "\n"


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    steps = res["curves"]["step"]
    for h, curve in res["curves"]["rmse_pos_m"].items():
        ax.semilogy(steps, curve, lw=1.2, label=f"h = {h} m")
    ax.semilogy(steps, res["curves"]["pcrb_pos_m_h0"], "k--", lw=1.0, label="PCRB, h = 0 (per-trajectory)")
    ax.axvline(res["settings"]["warmup"], color="grey", lw=0.8, ls=":")
    ax.set(xlabel=f"step (T = {res['settings']['dt_s']:g} s)", ylabel="horizontal position RMSE (m)",
           title=f"Planar EKF vs target altitude, {res['mc_runs']} tracks")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_outputs(res: dict, out: Path, overwrite: bool = False) -> None:
    """Write results.json, table.md and rmse_vs_time.png into a temporary folder beside ``out``,
    then rename it to ``out`` (:func:`pmsr_nn.outputs.atomic_folder`: an existing ``out`` is
    replaced only with ``overwrite``, and only where an ablation wrote it and it holds nothing else)."""
    with atomic_folder(out, command="ablation", overwrite=overwrite, allow=("ablation",)) as tmp:
        (tmp / "results.json").write_text(json.dumps(res, indent=1, allow_nan=True) + "\n")
        (tmp / "table.md").write_text(table_markdown(res))
        plot(res, tmp / "rmse_vs_time.png")


def print_table(res: dict) -> None:
    paper = paper_reference()
    print(f"{res['mc_runs']} tracks x {res['settings']['steps']} steps; RMSE averaged over steps "
          f"{res['settings']['warmup']}..{res['settings']['steps'] - 1} (Eq. 31 per step)")
    print(f"{'h (m)':>7}{'RMSE (m)':>11}{'|RMSE-RMSE0|':>14}{'incr. %':>10}{'pooled':>9}{'ANEES':>9}"
          f"{'diverged':>10}{'EKF s':>8}{'paper RMSE (ref.)':>19}")
    for r in rows(res):
        p = paper.get(r["altitude_m"])
        print(f"{r['altitude_m']:>7g}{r['rmse_pos_m']:>11.2f}{r['abs_diff_rmse0_m']:>14.2f}{r['relative_increase_pct']:>10.2f}"
              f"{r['pooled_rmse_pos_m']:>9.2f}{r['anees']:>9.2f}{r['diverged']:>10d}{r['seconds']:>8.1f}"
              f"{'' if p is None else f'{p:.2f}':>19}")
    print(f"per-trajectory filtering PCRB (h = 0, planar): {res['cases']['h=0 m']['pcrb']['pos_m']:.2f} m")


def build_parser() -> argparse.ArgumentParser:
    p = ScriptParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output folder (required): new, or with --overwrite an earlier ablation")
    p.add_argument("--tracks", type=int, default=10_000, help="Monte Carlo tracks per altitude (default 10000)")
    p.add_argument("--steps", type=int, default=1000, help="samples per track at T = 1 s (default 1000)")
    p.add_argument("--altitudes", type=float, nargs="+", default=list(DEFAULT_ALTITUDES), help="altitudes in m, must include 0")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--warmup", type=int, default=100, help="first step of the averaged RMSE (default 100)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    p.add_argument("--no-progress", action="store_true")
    return p


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    out = Path(args.out)
    try:
        check_inputs(args.tracks, args.steps, args.altitudes, args.seed, args.warmup)
        if args.threads is not None and args.threads < 1:
            raise InputError(f"--threads must be at least 1, got {args.threads}")
        check_folder_target(out, overwrite=args.overwrite, allow=("ablation",))  # before the work, not after
        if args.threads:
            torch.set_num_threads(args.threads)
        t0 = time.perf_counter()
        res = run(args.tracks, args.steps, args.altitudes, args.seed, args.warmup, progress=not args.no_progress)
        res["environment"] = {
            "pmsr_nn": pmsr_nn.__version__, "torch": torch.__version__, "python": platform.python_version(),
            "device": "cpu", "threads": torch.get_num_threads(), "machine": platform.machine(),
            "date": datetime.datetime.now().isoformat(timespec="seconds"),
            "command": "python evaluate/ablation_altitude.py " + " ".join(argv),
            "wall_seconds": time.perf_counter() - t0,
        }
        write_outputs(res, out, overwrite=args.overwrite)
    except (InputError, PmsrError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print_table(res)
    print(f"wrote {out / 'results.json'}, {out / 'table.md'} and {out / 'rmse_vs_time.png'} "
          f"({res['environment']['wall_seconds']:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
