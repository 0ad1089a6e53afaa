"""The ``tbd`` part of a track-before-detect row in ``results.json``: the Remote Sensing 2020
seed's per-frame figures of a method that reads range-Doppler maps (:mod:`pmsr_nn.methods.tbd`).

Takes a method's per-frame sums over every block (:func:`~pmsr_nn.harness.run.scoring.tbd_sums`,
plus the runner's OSPA and estimate counts); gives the figures the report's track-before-detect
section (:mod:`pmsr_nn.harness.report.rd_maps_report`) reads.
"""

from __future__ import annotations

import numpy as np


def tbd_row(s: dict, R: int, case, spec) -> dict:
    """The ``tbd`` part of a method's row from its sums over every block (``s``: summed over
    blocks, per-run quantities concatenated) of a case with maps (``case.info["rd_maps"]``)."""
    from ...methods.tbd import describe

    info = case.info["rd_maps"]
    present = np.asarray(info["present"], dtype=bool)
    hits = np.where(s["tbd_hits"] > 0, s["tbd_hits"], np.nan)
    det = s["tbd_detected"] / R
    rms_p, rms_v = np.sqrt(s["tbd_pos"] / hits), np.sqrt(s["tbd_vel"] / hits)
    err = s["tbd_run_pos_err"]  # (R, K), NaN where the run does not detect
    med = np.array([np.median(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in err.T])
    last = int(np.nonzero(present)[0][-1])
    ospa = s["ospa"] / R
    return {**describe(spec, case.sensing.rd_maps),
            "detected_frame_rate": det.tolist(),
            "detected_rate_present": float(det[present].mean()),
            "false_alarm_rate_absent": float(det[~present].mean()) if (~present).any() else None,
            "detected_rate_table_frame": float(det[info["table_frame"] - 1]),
            "rms_pos_m": rms_p.tolist(), "rms_vel_mps": rms_v.tolist(),
            "rms_pos_last_present_m": float(rms_p[last]), "rms_vel_last_present_mps": float(rms_v[last]),
            "median_pos_err_m": med.tolist(), "median_pos_err_last_present_m": float(med[last]),
            "existence": (s["tbd_existence"] / R).tolist(), "ospa_frame_m": ospa.tolist(),
            "ospa_mean_m": float(ospa.mean()), "snr_db": (s["tbd_snr_db"] / R).tolist(),
            "particles": (s["tbd_particles"] / R).tolist(), "estimates_per_frame": (s["n_est"] / R).tolist()}
