"""``report.md`` and figures of a track-before-detect study (:mod:`.tbd_study`).

Figures per case, in the seed's style where it has one: ``<case>_detected.png`` (detected-frame
rate vs frame, Figs. 11 and 13), ``<case>_rms.png`` (RMS position and velocity error vs frame,
Figs. 12 and 14), ``<case>_snr.png`` (the SNRs each update used, true ones dashed, Fig. 9),
``<case>_subarea.png`` (detected-frame rate of each sub-area, Table 2's study),
``<case>_existence.png`` (existence of the most probable component), ``<case>_ospa.png``,
``<case>_maps.png`` (run 0's maps at three frames around the target, Fig. 8 with noise) and
``<case>_track.png`` (run 0's estimates against the truth, Fig. 10).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _fmt(v, digits=1) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}"


def _curves(path: Path, frames: np.ndarray, series: dict, ylabel: str, title: str, present=None, dashed=None, log=False):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for name, y in series.items():
        ax.plot(frames, np.asarray(y, dtype=float), marker="o", ms=3, label=name)
    for name, y in (dashed or {}).items():
        ax.plot(frames, np.asarray(y, dtype=float), ls="--", color="0.4", lw=1)
    if present is not None:
        on = frames[np.asarray(present)]
        ax.axvspan(on[0] - 0.5, on[-1] + 0.5, color="0.92", zorder=0, label="target present")
    if log:
        ax.set_yscale("log")
    ax.set_xlabel("frame")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _maps_figure(path: Path, ex: dict, case: dict):
    plt = _plt()
    frames = sorted(ex["maps"])
    P = next(iter(ex["maps"].values())).shape[0]
    fig, axes = plt.subplots(P, len(frames), figsize=(3.2 * len(frames), 2.6 * P), squeeze=False)
    for j, k in enumerate(frames):
        m = ex["maps"][k]
        d, u = ex["truth_cells"][k]
        for p in range(P):
            ax = axes[p, j]
            dc, uc = int(round(float(d[p]))), int(round(float(u[p])))
            r0, r1 = max(dc - 15, 0), min(dc + 16, m.shape[1])
            c0, c1 = max(uc - 25, 0), min(uc + 26, m.shape[2])
            im = ax.imshow(10 * np.log10(m[p, r0:r1, c0:c1] + 1e-12), origin="lower", aspect="auto", cmap="viridis",
                           extent=(c0 - 0.5, c1 - 0.5, r0 - 0.5, r1 - 0.5), vmin=-10, vmax=15)
            ax.plot([float(u[p])], [float(d[p])], marker="o", mfc="none", mec="r", ms=12)
            ax.set_title(f"frame {k}, map {p + 1} (SNR {case['snr_db'][p]:g} dB)", fontsize=8)
            ax.set_xlabel(f"range cell ({case['range_cell_m']:.0f} m)", fontsize=8)
            ax.set_ylabel(f"Doppler cell ({case['doppler_cell_hz']:g} Hz)", fontsize=8)
    fig.subplots_adjust(hspace=0.55, wspace=0.35, right=0.86)
    fig.colorbar(im, ax=axes, shrink=0.6, label="|z|^2 / noise power (dB)")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _track_figure(path: Path, ex: dict, names):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 5))
    t = ex["truth"]
    ax.plot(t[:, 0] / 1e3, t[:, 2] / 1e3, "k-", lw=2, label="truth")
    for name, x in ex["tracks"].items():
        if name not in names:
            continue
        ax.plot(x[:, 0] / 1e3, x[:, 2] / 1e3, marker=".", lw=0.8, label=name)
    ax.set_xlabel("x (km, north)")
    ax.set_ylabel("y (km, west)")
    ax.set_title("run 0: estimates of the most probable component above the threshold")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table2(case: dict, ref: dict | None, frame: int) -> list[str]:
    """The sub-area study (the seed's Table 2): ours beside the reference's."""
    rows = [(n, r) for n, r in case["methods"].items() if r["power_ratio"] is not None and r["snr"] == "estimated"]
    if len(rows) < 2:
        return []
    lines = [f"Sub-area study (the seed's Table 2; detected-frame rate at frame {frame}; times per 20-frame run on "
             "this machine, the paper's in MATLAB on an i7-6820HQ)", "",
             "| method | sub-area | power ratio % | seconds / run | detected % | paper power % | paper s | paper detected % |",
             "|---|---|---|---|---|---|---|---|"]
    table = (ref or {}).get("table") or {}
    sizes = table.get("size", [])
    def size(nr):  # 1x1 .. 11x11, then the whole map
        sub = nr[1]["subarea"]
        return math.inf if sub == "full" else int(sub.split("x")[0])

    for name, r in sorted(rows, key=size):
        size = r["subarea"] if r["subarea"] != "full" else "full"
        i = sizes.index(size) if size in sizes else None
        paper = [table[k][i] if i is not None else None for k in ("power_ratio_pct", "computation_time_s",
                                                                     "detected_frame_rate_pct")]
        lines.append(f"| {name} | {size} | {100 * r['power_ratio']:.1f} | {r['seconds_per_run']:.2f} | "
                     f"{100 * r['detected_rate_table2_frame']:.1f} | {_fmt(paper[0])} | {_fmt(paper[1], 2)} | {_fmt(paper[2])} |")
    return lines + [""]


def write_tbd_report(res: dict, examples: dict, out: Path) -> None:
    lines = [f"# {res['scenario']}", "", res.get("description", "").strip(), "",
             f"{res['mc_runs']} Monte Carlo runs, seed {res['seed']}. Definitions in results.json.", ""]
    ref = res.get("reference")
    frame = res["settings"]["table2_frame"]
    for cname, case in res["cases"].items():
        frames = np.arange(1, len(case["present"]) + 1)
        present = np.asarray(case["present"])
        m = case["methods"]
        lines += [f"## {case['title']}", "", f"Map SNRs {case['snr_db']} dB; maps of {case['map_cells'][0]} Doppler x "
                  f"{case['map_cells'][1]} range cells.", "",
                  "| method | update | SNR | sub-area | detected % (present) | false alarm % (absent) | "
                  f"detected % frame {frame} | RMS pos m (last) | median pos m (last) | RMS vel m/s (last) | OSPA m | s / run |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for n, r in m.items():
            fa = r["false_alarm_rate_absent"]
            lines.append(f"| {n} | {r['update']} | {r['snr']} | {r['subarea'] if r['power_ratio'] is not None else '-'} | "
                         f"{100 * r['detected_rate_present']:.1f} | {_fmt(None if fa is None else 100 * fa)} | "
                         f"{100 * r['detected_rate_table2_frame']:.1f} | {_fmt(r['rms_pos_last_present_m'])} | "
                         f"{_fmt(r['median_pos_err_last_present_m'])} | "
                         f"{_fmt(r['rms_vel_last_present_mps'], 2)} | {r['ospa_mean_m']:.0f} | {r['seconds_per_run']:.2f} |")
        lines += [""] + table2(case, ref, frame)
        # the sub-area variants get their own figure; the others show the default sub-area's
        default = res["settings"]["filter"]["subarea_half"]
        default = "full" if default is None else f"{2 * default + 1}x{2 * default + 1}"
        sub = {n: r for n, r in m.items() if r["snr"] == "estimated" and r["power_ratio"] is not None}
        main = {n: r for n, r in m.items() if n not in sub or r["subarea"] == default}
        figs = {"detected": ("detected-frame rate", {n: r["detected_frame_rate"] for n, r in main.items()}, False),
                "existence": ("existence of the most probable component", {n: r["existence"] for n, r in main.items()}, False),
                "ospa": ("OSPA (m)", {n: r["ospa_m"] for n, r in main.items()}, False)}
        if len(sub) > 1:
            figs["subarea"] = ("detected-frame rate", {f"{r['subarea']} ({100 * r['power_ratio']:.0f}% of the energy)":
                                                       r["detected_frame_rate"] for n, r in sub.items()}, False)
        for key, (label, series, log) in figs.items():
            _curves(out / f"{cname}_{key}.png", frames, series, label, f"{case['title']}: {label}", present, log=log)
        plt = _plt()
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
        for ax, key, label in ((axes[0], "rms_pos_m", "position error (m): RMS, median dotted"),
                               (axes[1], "rms_vel_mps", "RMS velocity error (m/s)")):
            for n, r in main.items():
                line, = ax.plot(frames, np.asarray(r[key], dtype=float), marker="o", ms=3, label=n)
                if key == "rms_pos_m":
                    ax.plot(frames, np.asarray(r["median_pos_err_m"], dtype=float), ls=":", color=line.get_color())
            ax.set_yscale("log")
            ax.set_xlabel("frame")
            ax.set_ylabel(label)
        axes[1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        fig.suptitle(f"{case['title']}: errors over the runs that detect")
        fig.tight_layout()
        fig.savefig(out / f"{cname}_rms.png", dpi=110)
        plt.close(fig)
        est = {n: r for n, r in m.items() if r["snr"] == "estimated"}
        if est:
            name, r = next(iter(est.items()))
            snr = np.asarray(r["snr_db"])
            _curves(out / f"{cname}_snr.png", frames, {f"map {p + 1} estimated ({name})": snr[:, p] for p in range(snr.shape[1])},
                    "SNR (dB)", f"{case['title']}: online SNR estimate (true dashed)", present,
                    dashed={f"map {p + 1}": np.full(len(frames), case["snr_db"][p]) for p in range(snr.shape[1])})
        if cname in examples:
            _maps_figure(out / f"{cname}_maps.png", examples[cname], case)
            _track_figure(out / f"{cname}_track.png", examples[cname], set(main))
        lines += [f"![{k}]({cname}_{k}.png)" for k in ("detected", "rms", "snr", "subarea", "existence", "ospa", "maps", "track")
                  if (out / f"{cname}_{k}.png").exists()] + [""]
    lines += order_study(res, out)
    (out / "report.md").write_text("\n".join(lines) + "\n")


def order_study(res: dict, out: Path) -> list[str]:
    """The seed's Figs. 11-12 across cases: every known-SNR ICMB (ascending or descending order) of
    every case on one figure, detected-frame rate and RMS position error."""
    rows = [(f"{case['title']}: {n}", case, r) for case in res["cases"].values() for n, r in case["methods"].items()
            if r["snr"] == "true" and r["update"] in ("ascending", "descending")]
    if len({id(case) for _, case, _ in rows}) < 2:
        return []
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.4))
    for label, case, r in rows:
        frames = np.arange(1, len(case["present"]) + 1)
        axes[0].plot(frames, r["detected_frame_rate"], marker="o", ms=3, label=label)
        axes[1].plot(frames, np.asarray(r["rms_pos_m"], dtype=float), marker="o", ms=3, label=label)
    axes[0].set_ylabel("detected-frame rate")
    axes[1].set_ylabel("RMS position error (m)")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("frame")
    axes[1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    fig.suptitle("Update order with known SNRs, every case (the seed's Figs. 11-12)")
    fig.tight_layout()
    fig.savefig(out / "order_study.png", dpi=110)
    plt.close(fig)
    return ["## Update order across cases", "", "![order study](order_study.png)", ""]
