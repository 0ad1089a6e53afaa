"""The definitions ``results.json`` records beside the figures (``res["definitions"]``).

Takes the kinds of figures a study has (designed flights or not, rows scored in a measurement
space, SMC-PHD rows, track-before-detect rows); gives the text that defines each figure, keyed
like the rows' fields: :func:`designed_definitions` for a designed scenario,
:func:`world_definitions` for a scenario with a ``world`` section (a multi-target study). Only text: no figure is computed here.
"""

from __future__ import annotations

DEFINITIONS = {
    "rmse_pos_m": "Eq. 31 of the MDFNN paper: at each step k the root of the mean over the Monte Carlo runs of the "
                  "squared Euclidean position error, then the mean of that curve over the steps after the warm-up "
                  "(with several targets: per target and step, then the mean over targets and their steps after "
                  "their own warm-up)",
    "rmse_pos_se_m": "Monte Carlo standard error of rmse_pos_m: the spread of the runs' mean squared position errors "
                     "through the square root by the delta method (rmse * se(MSE) / (2 MSE)), treating the steps' "
                     "mean of per-step RMSE like the root of the mean MSE; null with fewer than two runs",
    "rmse_pos_pooled_m": "root of the mean squared position error over runs, targets and steps after the warm-up (pooled)",
    "rmse_pos_all_scans_m": "the same as rmse_pos_m, averaged over every step each target lives (the S-MSJPDA paper)",
    "rmse_vel_per_target_mps": "per target: at each step the root of the mean over runs of the squared velocity error, "
                               "averaged over the target's steps after the warm-up (track slot i is target i's track)",
    "anees_per_target": "per target: the anees averaged over its steps after the warm-up",
    "anees": "mean over runs and steps after the warm-up of the NEES over the full state divided by its dimension "
             "(1 = consistent); null for methods without covariances",
    "pcrb": "per-trajectory posterior Cramer-Rao bound of each target's true trajectory under the recipe's CA model and "
            "q, the scenario's measurement deviations and the initiation prior P0, from the target's birth on clean "
            "(association-known) measurement streams; averaged like rmse_pos_m",
    "bound": "the bound a method is compared with: filtering for a causal method, smoothing for one that looks ahead",
    "memory_bound_pos_m": "finite-memory bound of a causal learned tracker: the filtering PCRB of only the memory_scans "
                          "scans its estimate at each step reads (an MDFNN's filter taps, a recurrent network's splice), "
                          "with the spread of its training states as prior; averaged like rmse_pos_m. No tracker of "
                          "that shape can beat it on average; below_memory_bound flags a mean per-run ratio of squared "
                          "error to the bound's mean square (mse_over_memory_bound) under 1 beyond its Monte Carlo error (the "
                          "one-sided 97.5 % Student-t bound of that mean, B - 1 degrees of freedom, stays under 1)",
    "pcrb_q0": "the same bound with q = 0: the floor for an estimator that knew the target flies without process "
               "noise (the designed trajectories have none; exact CA for trajectories with constant acceleration)",
    "seed_groups": "learned methods named 'BASE [seed k]' (one training seed each) summarised per BASE: mean, "
                   "standard deviation over seeds, min and max of rmse_pos_m and of its ratios to the bounds",
    "comparisons": "each learned tracker (a seed group: the mean over its seeds per run) against the case's best "
                   "non-learned method on the same runs: margin_m = mean over runs of (classical - learned) per-run "
                   "position RMSE after the warm-up (positive: the learned tracker is better), se_m its standard error",
    "diverged_runs": "runs whose position RMSE after the warm-up exceeds divergence_m or is not finite; "
                     "they are kept in every average",
    "seconds_per_run": "wall-clock seconds of the method per Monte Carlo run, measured in this run (whole block "
                       "calls divided by the runs; all targets); timings differ between repeats",
    "ospa_m": "OSPA (Schuhmacher et al. 2008, cut-off c_m, order p) between the existing tracks and the living targets "
              "at each scan, averaged over runs, then over the scans after the warm-up (set_scans); ospa_se_m its Monte Carlo "
              "standard error (the spread of the runs' mean OSPA over those scans)",
    "gospa_m": "GOSPA (alpha = 2, Rahmathullah et al. 2017): the p-th root of the mean over runs and scans after the "
               "warm-up (set_scans) of GOSPA^p; gospa_localisation_share, gospa_missed_share and gospa_false_share split that "
               "mean into its parts (sum of d^p over assigned pairs, c^p/2 per missed target, c^p/2 per false track), "
               "which add up to 1; gospa_se_m its Monte Carlo standard error (the spread of the runs' mean GOSPA^p, "
               "through the p-th root by the delta method); gospa_median_run_m the median over runs of each run's "
               "GOSPA (the p-th root of its mean GOSPA^p over those scans): a few runs that lose their tracks move "
               "the mean, not the median; gospa_run_quantiles_m each run's GOSPA at the 25 %, 50 %, 75 % and 90 % points "
               "and the largest over the runs (linear interpolation between order statistics): how many runs the "
               "mean's cost comes from",
    "confirmed_tracks_per_target": "reported tracks mapped to a target (the persistent mapping of "
                                   "label_switches_per_run) at some scan of its life, per target and run",
    "false_tracks_per_run": "reported tracks never matched to any target",
    "missed_target_fraction": "fraction of (run, target, scan) where the target lives and no track is matched to it",
    "scans_to_first_track": "scans from a target's birth to its first matched track, over the runs that had one",
    "track_loss_probability": "fraction of (run, target) whose matched tracks ended while the target still lived",
    "fragmentations_per_run": "interruptions of a target's matched coverage that resumed later, per run",
    "runs_without_tracks": "runs in which the row reported no track at any scan though some target lived; the "
                           "report flags a row with any (a tracker whose existence never reaches its reporting "
                           "threshold scores every target missed)",
    "initiation": "how a row's tracks start: association known (each target's own stream), oracle (handed each "
                  "target's birth: truth plus a prior draw) or detections (the tracker's own initiator, from "
                  "detections or, for the track-before-detect rows, range-Doppler maps)",
    "cardinality_mean_abs_error": "mean over runs and scans after the warm-up (set_scans) of |number of tracks - "
                                  "number of targets|",
    "set_scans": "the scans the set figures (ospa_m, gospa_m and their parts, per-run GOSPA, cardinality) average over, "
                 "in every scenario: every scan from warmup_steps on, counted from the case's first scan. Every target "
                 "living at such a scan counts, also one still inside its own warm-up (its start-up, the scans before "
                 "its first track, is part of the score), and so does a scan where no target lives (a track there is "
                 "false)",
    "rmse_pos_assigned_per_target_m": "per target: each run's track labels are assigned to targets once (the assignment "
                                      "minimising the summed capped squared distances over the run), then the RMSE of "
                                      "the assigned track, averaged over the target's scans after the warm-up",
    "label_switches_per_run": "changes, between consecutive scans, of the track mapped to a target, summed over targets, "
                              "per run; the mapping is CLEAR MOT's (Bernardin & Stiefelhagen 2008): a track stays on "
                              "the target it was mapped to at the previous scan while both exist within the cut-off c, "
                              "the others are matched by the per-scan OSPA assignment (track-level figures: confirmed "
                              "tracks per target, fragmentations, first track and track loss are counted on the same "
                              "mapping)",
    "id_switches_per_run": "identity switches (CLEAR MOT, counted as the MOTChallenge counts them: Milan et al. 2016), "
                           "summed over targets, per run: the scans at which a target's mapped track (the mapping of "
                           "label_switches_per_run) is another than the last track mapped to it, also after scans "
                           "at which it had none (a track lost and another started on the target is a switch, the "
                           "same track back is not); at least label_switches_per_run. id_switches_per_target: per "
                           "target, mean over runs",
    "tgospa_m": "trajectory GOSPA (alpha = 2, García-Fernández, Rahmathullah & Svensson, IEEE TSP 2020) of each "
                "run's tracks (one trajectory per track) against the targets' trajectories over the set scans, "
                "cut-off c_m, order p and switching cost gamma = c_m (tgospa_gamma_m: a switch costs c^p, as much "
                "as one scan with the target missed and its track false; a change from or to no track half that), "
                "divided by the number of set scans so that it reads like gospa_m: the p-th root of the mean over "
                "runs; with gamma = 0 it would equal gospa_m. Solved per run as the paper's LP relaxation (HiGHS), "
                "a metric and a lower bound of the integer programme's value, equal to it in the "
                "tgospa_integral_runs runs whose solution is integral; tgospa_se_m its Monte Carlo standard error "
                "(delta method); tgospa_localisation_share, _missed_share, _false_share and _switching_share split "
                "its p-th power; tgospa_switches_per_run the switches the optimal assignment makes (a half switch "
                "counts 1/2). Absent for rows whose estimates have no identities",
    "swap_probability": "fraction of (run, target) tracks nearer another target's truth than their own at the last scan",
    "loss_probability": "fraction of (run, target) tracks declared lost by the S-MSJPDA paper's rule (dummy most "
                        "probable at every sensor for successive_scans scans in a row, or predicted bistatic-range "
                        "deviation above gate_range_sd_m); a lost track keeps being tracked and stays in the RMSE",
    "max_duality_gap": "largest duality gap (event cost minus Lagrangian lower bound, in nats: the event found is at "
                       "least exp(-gap) times as probable as the best) of the (N+1)-D assignments of P-MSJPDA",
}
"""What each figure of a designed scenario's rows means."""

MT_LEFT_OUT = ("rmse_pos_pooled_m", "pcrb", "bound", "memory_bound_pos_m", "pcrb_q0", "seed_groups", "comparisons",
               "diverged_runs")
"""Definitions of figures a multi-target study has not (no designed flights, no learned methods)."""

MT_DEFINITIONS = {
    "rmse_pos_m": "Eq. 22 of the S-MSJPDA paper per target and scan (root of the mean over runs of the squared "
                  "position error), averaged over targets and over scans warmup_steps..K-1",
    "rmse_pos_all_scans_m": "the paper's position accuracy: the same, averaged over all scans",
    "anees": "mean over runs, targets and scans >= warmup_steps of the NEES / 4",
}
"""A multi-target study's own definitions of the figures it shares with a designed scenario."""

SPACE_DEFINITIONS = {
    "space": "rows with a space are scored in it, not in the Cartesian state: their estimates are one pair's bistatic "
             "range and range-rate [r, rdot], scored against the truth projected into that pair's measurement space "
             "(the noise-free range and range-rate of each living target). Their OSPA, GOSPA, position RMSE and "
             "per-target errors are on bistatic range alone (one axis, m), their velocity figures on range-rate "
             "(m/s): compare them with each other, never with a Cartesian row's",
    "rmse_vel_pooled_mps": "root mean square range-rate error pooled over the (run, scan, target) entries where the "
                           "per-scan OSPA assignment matches a track to a target (inside the cut-off); "
                           "rmse_pos_pooled_m is the same for the range",
    "ospa_m / gospa_m / cardinality_mean_abs_error (averaging)": "averaged over every scan from warmup_steps "
                                                                  "on, also scans where no target lives (an estimate "
                                                                  "there is false)",
    "label_switches_per_target / fragmentations_per_target": "per target: label switches and fragmentations (as "
                                                             "label_switches_per_run and fragmentations_per_run), "
                                                             "mean over runs",
}
"""Definitions of the figures of rows scored in a measurement space (:class:`~pmsr_nn.methods.EstimateSpace`)."""

PHD_DEFINITIONS = {
    "phd_expected": "per scan: the PHD's integral (sum of the particle weights) after the update, mean over runs "
                    "(curves.set.<method>.phd_expected)",
    "labels_per_run": "labels (tracks) a labelling confirmed in a run; the ideal is the number of targets",
    "conflicts_repaired_per_run": "GTDA: estimates two tracks still wanted after the game's last round, given to the "
                                  "nearer, per run",
    "game_rounds_mean": "GTDA: rounds of the game per scan, mean over scans and blocks",
    "phd_seconds_per_run": "the PHD filter's own seconds per run; rows of one pair's PHD with the same settings read "
                           "one PHD run per block, and each counts its seconds in full in seconds_per_run (PHD plus "
                           "its own labelling)",
    "known_association_kf_pair": "the floor of what association can reach with the same motion model: an exact Kalman "
                                 "filter per target on exactly its own detections (their true origins), started at its "
                                 "first detection",
}
"""Definitions of the SMC-PHD rows' own figures."""


TBD_DEFINITIONS = {
    "tbd.detected_frame_rate": "per frame: fraction of runs with some Bernoulli component's existence above the "
                               "method's threshold (the most probable one's), the seed's N_d,k / N_mc; while no "
                               "target lives it is a false-alarm rate",
    "tbd.detected_rate_table_frame": "detected_frame_rate at the case's table frame (rd_maps.table_frame; the seed's "
                                     "Table 2 uses frame 15)",
    "tbd.rms_pos_m": "per frame: root mean square position error of the most probable component (against the nearest "
                     "living target) over the runs that detect at that frame (NaN where none does)",
    "tbd.median_pos_err_m": "per frame: median over the runs that detect of that position error (robust to the few "
                            "runs locked onto a ghost, which dominate rms_pos_m)",
    "tbd.ospa_frame_m": "per frame: OSPA (set_metrics' order and cut-off) between the components above the threshold "
                        "and the living targets (empty set while none lives), mean over runs; ospa_mean_m its mean "
                        "over every frame",
    "tbd.snr_db": "per frame and map: the SNR the update used, mean over runs (the modified ICMB's online estimate: "
                  "the largest ML amplitude over the predicted particles, Eq. 25)",
    "tbd.power_ratio": "expected share of the target's map energy inside the sub-area, for the triangle x sinc "
                       "response with uniform sub-cell offsets (pmsr_nn.tbd.maps.power_ratio)",
    "tbd.targets_held_rate": "share of the living targets' frames (frames with a target) at which a reported track "
                             "is assigned to the target by the set metrics' per-scan assignment within the cut-off "
                             "c_m: the same tracks and assignment as the set-metric table",
    "tbd.unassigned_tracks_per_frame": "reported tracks per frame that no living target is assigned within c_m "
                                       "(every frame, mean over runs)",
    "rd_maps.bound_pos_m": "per frame (a case's): the filtering PCRB of each target seen through every map alone "
                           "(pmsr_nn.tbd.bound: the Fisher information of the cell response at the map's SNR, phase "
                           "unknown, amplitude known; the scenario's motion model and q; prior the birth box's uniform "
                           "spread from the target's birth), position RMSE over the living targets (NaN while none "
                           "lives)",
}
"""Definitions of the track-before-detect rows' own figures (``tbd`` in their results)."""


STRAIGHT_PCRB = ("per-trajectory posterior Cramer-Rao bound of each target's straight flight under the trackers' "
                 "motion model and q, the measurement deviations and the initiation prior P0, on clean "
                 "(association-known) measurements of every pair; averaged like rmse_pos_m")
"""The PCRB of a multi-target study whose targets fly straight lines (``world.motion.truth: straight``)."""


def designed_definitions(rd_maps: bool) -> dict:
    """The definitions of a designed scenario; ``rd_maps``: it has range-Doppler maps (the
    track-before-detect rows' figures are added)."""
    if not rd_maps:
        return DEFINITIONS
    return {**DEFINITIONS, **TBD_DEFINITIONS}


def world_definitions(kinds, straight: bool, n: int) -> dict:
    """The definitions of a multi-target study whose methods are of ``kinds`` (the registered
    :class:`~pmsr_nn.methods.MethodKind` of each); ``straight``: every run flies the same straight
    lines (a PCRB per case); ``n``: the state dimension (the ANEES divides the NEES by it)."""
    left_out = MT_LEFT_OUT if not straight else tuple(k for k in MT_LEFT_OUT if k not in ("pcrb", "bound", "pcrb_q0"))
    out = {k: v for k, v in DEFINITIONS.items() if k not in left_out}
    out.update(MT_DEFINITIONS)
    out["anees"] = out["anees"].replace("/ 4", f"/ {n}")
    if straight:
        out["pcrb"] = STRAIGHT_PCRB
    if any(k.space is not None for k in kinds):
        out.update(SPACE_DEFINITIONS)
    if any(k.name in ("smc_phd", "smc_phd_pair") for k in kinds):
        out.update(PHD_DEFINITIONS)
    return out
