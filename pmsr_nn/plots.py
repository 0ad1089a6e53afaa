"""Figures (matplotlib, Agg backend, PNG files)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_dataset_tracks(path: str | Path, out_png: str | Path, max_tracks: int = 40) -> Path:
    """Sensors, the Table 1 envelope and the first ``max_tracks`` truth tracks of a dataset."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .data.store import open_dataset

    ds = open_dataset(path)
    try:
        man = ds.manifest
        states = ds.file["states"][:max_tracks].astype(np.float64)
    finally:
        ds.close()
    env = man["recipe"]["envelope"]
    geo = man["geometry"]
    fig, ax = plt.subplots(figsize=(7, 6.5))
    for track in states:
        ax.plot(track[:, 0] / 1e3, track[:, 3] / 1e3, lw=0.8, alpha=0.8)
        ax.plot(track[0, 0] / 1e3, track[0, 3] / 1e3, "k.", ms=3)
    tx0 = np.asarray(geo["transmitters"][0]["position_m"][:2]) / 1e3
    az = np.radians(np.linspace(env["azimuth_deg"][0], env["azimuth_deg"][1], 100))
    r_lo, r_hi = (v / 1e3 for v in env["range_m"])
    outline = np.concatenate([
        np.stack([r_hi * np.sin(az), r_hi * np.cos(az)], -1),
        np.stack([r_lo * np.sin(az[::-1]), r_lo * np.cos(az[::-1])], -1),
    ]) + tx0
    ax.fill(outline[:, 0], outline[:, 1], color="tab:green", alpha=0.08, label="Table 1 envelope")
    for t in geo["transmitters"]:
        ax.plot(t["position_m"][0] / 1e3, t["position_m"][1] / 1e3, "r^", ms=10)
    for j, r in enumerate(geo["receivers"]):
        ax.plot(r["position_m"][0] / 1e3, r["position_m"][1] / 1e3, "bs", ms=8)
        ax.annotate(f"Rx{j + 1}", (r["position_m"][0] / 1e3, r["position_m"][1] / 1e3), xytext=(5, 5), textcoords="offset points")
    ax.plot([], [], "r^", label="transmitter")
    ax.plot([], [], "bs", label="receivers")
    ax.plot([], [], "k.", label="track starts")
    leaving = man["envelope"]["fraction_left"]
    ax.set_title(f"{man['name']}, variant '{man['variant']}': first {len(states)} of {man['shapes']['states'][0]} tracks\n"
                 f"{leaving:.0%} of all tracks leave the envelope")
    ax.set_xlabel("east (km)")
    ax.set_ylabel("north (km)")
    ax.set_aspect("equal", adjustable="datalim")
    if man["variant"] == "literal":  # tracks go far away: keep the sensors in view
        span = max(12.0, float(np.percentile(np.abs(states[..., [0, 3]]), 50)) / 1e3)
        ax.set_xlim(-span, span)
        ax.set_ylim(-span, span)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    out_png = Path(out_png)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110, format="png")  # format given: the path may be a temporary name
    plt.close(fig)
    return out_png

