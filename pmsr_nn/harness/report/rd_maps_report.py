"""The track-before-detect part of a scenario's report: the Remote Sensing 2020 seed's figures
of every method that reads range-Doppler maps (:mod:`pmsr_nn.methods.tbd`).

It reads the ``tbd`` part of those rows (:class:`pmsr_nn.methods.kind_metrics.TBDFrames`);
:func:`report_lines` writes the report's section and figures for every case whose rows have one
(nothing otherwise); :func:`summary_lines` is the terminal's table.

Figures per case, in the seed's style where it has one: ``<case>_detected.png`` (detected-frame
rate vs frame, Figs. 11 and 13), ``<case>_tbd_rms.png`` (RMS position and velocity error of the
most probable component vs frame, Figs. 12 and 14), ``<case>_snr.png`` (the SNRs the first
estimating method's updates used, true ones dashed, Fig. 9), ``<case>_subarea.png``
(detected-frame rate of each sub-area, Table 2's study), ``<case>_existence.png`` (existence of the
most probable component), ``<case>_ospa.png`` (OSPA per frame) and ``<case>_maps.png`` (run 0's
maps at three frames around the target, Fig. 8 with noise); ``order_study.png`` (every known-SNR
ICMB of every case, Figs. 11-12).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..results.result_rows import MethodRow
from ..results.typed import Case, Results
from .figures import pyplot


def _fmt(v, digits=1) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}"


def _curves(path: Path, frames: np.ndarray, series: dict, ylabel: str, title: str, present=None, dashed=None, log=False):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for name, y in series.items():
        ax.plot(frames, np.asarray(y, dtype=float), marker="o", ms=3, label=name)
    for name, y in (dashed or {}).items():
        ax.plot(frames, np.asarray(y, dtype=float), ls="--", color="0.4", lw=1)
    if present is not None and np.asarray(present).any():
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


def _maps_figure(path: Path, ex: dict, maps: dict) -> bool:
    """Run 0's maps around the target (``@rd_maps_*`` examples of the product); False without them."""
    frames = sorted(int(k.rsplit("_f", 1)[1]) for k in ex if k.startswith("@rd_maps_power_f"))
    if not frames:
        return False
    plt = pyplot()
    P = np.asarray(ex[f"@rd_maps_power_f{frames[0]}"]).shape[0]
    fig, axes = plt.subplots(P, len(frames), figsize=(3.2 * len(frames), 2.6 * P), squeeze=False)
    im = None
    for j, k in enumerate(frames):
        power = np.asarray(ex[f"@rd_maps_power_f{k}"])
        origin = np.asarray(ex[f"@rd_maps_origin_f{k}"])
        cells = np.asarray(ex[f"@rd_maps_cells_f{k}"])
        for p in range(P):
            ax = axes[p, j]
            r0, c0 = origin[p]
            h, w = power.shape[1], power.shape[2]
            im = ax.imshow(10 * np.log10(power[p] + 1e-12), origin="lower", aspect="auto", cmap="viridis",
                           extent=(c0 - 0.5, c0 + w - 0.5, r0 - 0.5, r0 + h - 0.5), vmin=-10, vmax=15)
            ax.plot([cells[p, 1]], [cells[p, 0]], marker="o", mfc="none", mec="r", ms=12)
            ax.set_title(f"frame {k}, {maps['maps'][p]} (SNR {maps['snr_db'][p]:g} dB)", fontsize=8)
            ax.set_xlabel(f"range cell ({maps['range_cell_m']:.0f} m)", fontsize=8)
            ax.set_ylabel(f"Doppler cell ({maps['doppler_cell_hz']:g} Hz)", fontsize=8)
    fig.subplots_adjust(hspace=0.55, wspace=0.35, right=0.86)
    fig.colorbar(im, ax=axes, shrink=0.6, label="|z|^2 / noise power (dB)")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def _subarea_rows(rows: dict[str, MethodRow]) -> dict[str, MethodRow]:
    """The rows of the sub-area study: map likelihoods with an estimated SNR, estimated as the
    first such row estimates it (the others, e.g. the seed's estimate beside ours, are rows of
    the case's table only)."""
    est = [r.tbd.snr for r in rows.values() if r.tbd.snr.startswith("estimated") and r.tbd.power_ratio is not None]
    return {n: r for n, r in rows.items() if est and r.tbd.snr == est[0] and r.tbd.power_ratio is not None}


def table2(rows: dict[str, MethodRow], ref: dict | None, frame: int, label: str) -> list[str]:
    """The sub-area study (the seed's Table 2): the methods with an estimated SNR and map
    likelihoods, by sub-area, beside the reference's rows (``ref``: its ``size``,
    ``power_ratio_pct``, ``computation_time_s`` and ``detected_frame_rate_pct`` lists)."""
    sub = list(_subarea_rows(rows).items())
    if len(sub) < 2:
        return []
    lines = [f"Sub-area study (the seed's Table 2; detected-frame rate at frame {frame}; times per run on this machine"
             + (f", {label}'s in MATLAB on an i7-6820HQ" if ref else "") + ")", "",
             "| method | sub-area | power ratio % | seconds / run | detected % |"
             + (f" {label} power % | {label} s | {label} detected % |" if ref else ""),
             "|---|---|---|---|---|" + ("---|---|---|" if ref else "")]
    table = ref or {}
    sizes = table.get("size", [])

    def size(nr):  # 1x1 .. 11x11, then the whole map
        s = nr[1].tbd.subarea
        return math.inf if s == "full" else int(s.split("x")[0])

    for name, r in sorted(sub, key=size):
        t = r.tbd
        line = (f"| {name} | {t.subarea} | {100 * t.power_ratio:.1f} | {r.seconds_per_run:.2f} | "
                f"{100 * t.detected_rate_table_frame:.1f} |")
        if ref:
            i = sizes.index(t.subarea) if t.subarea in sizes else None
            paper = [table[k][i] if i is not None else None for k in ("power_ratio_pct", "computation_time_s",
                                                                         "detected_frame_rate_pct")]
            line += f" {_fmt(paper[0])} | {_fmt(paper[1], 2)} | {_fmt(paper[2])} |"
        lines.append(line)
    return lines + [""]


def last_bound(maps: dict) -> float | None:
    """The maps' bound (``bound_pos_m``, RMS over the living targets) at the last frame with a
    target, the frame of the table's "last" columns; None in a record made before it existed."""
    bound = maps.get("bound_pos_m")
    if bound is None:
        return None
    return float(bound[int(np.nonzero(np.asarray(maps["present"], dtype=bool))[0][-1])])


def _case_table(rows: dict[str, MethodRow], frame: int, bound: float | None) -> list[str]:
    over = " RMS pos / map bound (last) |" if bound is not None else ""
    lines = ["| method | kind | update | SNR | sub-area | detected % (present) | targets held % | unassigned tracks "
             f"/ frame | false alarm % (absent) | detected % frame {frame} | RMS pos m (last) | median pos m (last) |"
             f"{over} RMS vel m/s (last) | OSPA m (every frame) | s / run |",
             "|---" * (15 + bool(over)) + "|"]
    for n, r in rows.items():
        t = r.tbd
        fa = t.false_alarm_rate_absent
        ratio = f" {_fmt(t.rms_pos_last_present_m / bound)} |" if bound is not None else ""
        held = None if t.targets_held_rate is None else 100 * t.targets_held_rate
        lines.append(f"| {n} | {r.kind} | {t.update} | {t.snr} | {t.subarea or '-'} | "
                     f"{100 * t.detected_rate_present:.1f} | {_fmt(held)} | {_fmt(t.unassigned_tracks_per_frame, 2)} | "
                     f"{_fmt(None if fa is None else 100 * fa)} | "
                     f"{100 * t.detected_rate_table_frame:.1f} | {_fmt(t.rms_pos_last_present_m)} | "
                     f"{_fmt(t.median_pos_err_last_present_m)} |{ratio} {_fmt(t.rms_vel_last_present_mps, 2)} | "
                     f"{t.ospa_mean_m:.0f} | {r.seconds_per_run:.2f} |")
    return lines + [""]


def _map_rows(case: Case) -> dict[str, MethodRow]:
    """The case's rows that read range-Doppler maps."""
    return {n: r for n, r in case.methods.items() if r.tbd is not None}


def report_lines(res: Results | dict, out: Path, examples: dict) -> list[str]:
    """The report's track-before-detect section (and its figures in ``out``): per case with maps,
    the table of its map-reading methods, the sub-area study and the figures; then the update
    order across cases. Empty where no row reads maps."""
    results = Results.of(res)
    cases = {n: c for n, c in results.cases.items() if _map_rows(c)}
    if not cases:
        return []
    sub_ref = results.reference.get("subarea") or {}
    label = results.reference.get("label", "paper")
    lines = ["## Track-before-detect on range-Doppler maps", "",
             "Every method below reads the case's range-Doppler maps. Per frame: the detected-frame rate (some "
             "component above the threshold: some track reported), the error of the most probable component over "
             "the runs that detect, OSPA over every frame (a track while no target lives is a false alarm). From "
             "the same tracks as the set-metric table: the targets held (the living targets' frames a track is "
             "assigned to within the cut-off) and the unassigned tracks per frame, so a frame 'detected' by a track "
             "far from every target shows there. Definitions (`tbd.*`) in results.json.", ""]
    for cname, case in cases.items():
        maps = case.rd_maps
        rows = _map_rows(case)
        frames = np.arange(1, len(maps["present"]) + 1)
        present = np.asarray(maps["present"], dtype=bool)
        frame = maps["table_frame"]
        lines += [f"### {case.title} (`{cname}`)", "",
                  f"Maps {', '.join(maps['maps'])}: SNR {maps['snr_db']} dB, {maps['map_cells'][0]} Doppler x "
                  f"{maps['map_cells'][1]} range cells of {maps['doppler_cell_hz']:g} Hz x {maps['range_cell_m']:.0f} m.",
                  ""]
        bound = last_bound(maps)
        if bound is not None:
            lines += [f"Map bound: {bound:.1f} m at the last frame with a target (the PCRB of each target seen "
                      "through every map's cells, phase unknown, SNR known, from the birth box; RMS over the living "
                      "targets; `rd_maps.bound_pos_m` in results.json). A row's RMS error is held to it.", ""]
        lines += _case_table(rows, frame, bound)
        lines += table2(rows, sub_ref.get("table"), frame, label)
        # the sub-area variants get their own figure; the others show the one sub-area most of them use
        sub = _subarea_rows(rows)
        areas = [r.tbd.subarea for n, r in rows.items() if r.tbd.subarea]
        default = max(set(areas), key=areas.count) if areas else None
        main = {n: r for n, r in rows.items() if n not in sub or r.tbd.subarea == default}
        figs = {"detected": ("detected-frame rate", {n: r.tbd.detected_frame_rate for n, r in main.items()}),
                "existence": ("existence of the most probable component", {n: r.tbd.existence for n, r in main.items()}),
                "ospa": ("OSPA (m)", {n: r.tbd.ospa_frame_m for n, r in main.items()})}
        if len(sub) > 1:
            figs["subarea"] = ("detected-frame rate", {f"{r.tbd.subarea} ({100 * r.tbd.power_ratio:.0f}% of "
                                                       "the energy)": r.tbd.detected_frame_rate for r in sub.values()})
        for key, (ylabel, series) in figs.items():
            _curves(out / f"{cname}_{key}.png", frames, series, ylabel, f"{case.title}: {ylabel}", present)
        plt = pyplot()
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
        for ax, key, ylabel in ((axes[0], "rms_pos_m", "position error (m): RMS, median dotted"),
                                (axes[1], "rms_vel_mps", "RMS velocity error (m/s)")):
            for n, r in main.items():
                line, = ax.plot(frames, np.asarray(getattr(r.tbd, key), dtype=float), marker="o", ms=3, label=n)
                if key == "rms_pos_m":
                    ax.plot(frames, np.asarray(r.tbd.median_pos_err_m, dtype=float), ls=":", color=line.get_color())
            if key == "rms_pos_m" and maps.get("bound_pos_m") is not None:
                ax.plot(frames, np.asarray(maps["bound_pos_m"], dtype=float), ls="--", color="0.3", label="map bound")
            ax.set_yscale("log")
            ax.set_xlabel("frame")
            ax.set_ylabel(ylabel)
        axes[1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        fig.suptitle(f"{case.title}: errors of the most probable component over the runs that detect")
        fig.tight_layout()
        fig.savefig(out / f"{cname}_tbd_rms.png", dpi=110)
        plt.close(fig)
        est = {}  # the first row of each way of estimating the SNR
        for n, r in rows.items():
            if r.tbd.snr.startswith("estimated") and r.tbd.snr not in {e.tbd.snr for e in est.values()}:
                est[n] = r
        if est:
            series = {f"{maps['maps'][p]} ({name})": np.asarray(r.tbd.snr_db)[:, p]
                      for name, r in est.items() for p in range(np.asarray(r.tbd.snr_db).shape[1])}
            _curves(out / f"{cname}_snr.png", frames, series,
                    "SNR (dB)", f"{case.title}: online SNR estimate (true dashed)", present,
                    dashed={f"map {p + 1}": np.full(len(frames), v) for p, v in enumerate(maps["snr_db"])})
        _maps_figure(out / f"{cname}_maps.png", examples.get(cname, {}), maps)
        lines += [f"![{k}]({cname}_{k}.png)" for k in ("detected", "tbd_rms", "snr", "subarea", "existence", "ospa", "maps")
                  if (out / f"{cname}_{k}.png").exists()] + [""]
    return lines + order_study(cases, out)


def order_study(cases: dict[str, Case], out: Path) -> list[str]:
    """The seed's Figs. 11-12 across cases: every known-SNR ICMB (ascending or descending order) of
    every case on one figure, detected-frame rate and RMS position error."""
    rows = [(f"{case.title}: {n}", case, r) for case in cases.values() for n, r in _map_rows(case).items()
            if r.tbd.snr == "true" and r.tbd.update in ("ascending", "descending")]
    if len({id(case) for _, case, _ in rows}) < 2:
        return []
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.4))
    for label, case, r in rows:
        frames = np.arange(1, len(case.rd_maps["present"]) + 1)
        axes[0].plot(frames, r.tbd.detected_frame_rate, marker="o", ms=3, label=label)
        axes[1].plot(frames, np.asarray(r.tbd.rms_pos_m, dtype=float), marker="o", ms=3, label=label)
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
    return ["### Update order across cases", "", "![order study](order_study.png)", ""]


def summary_lines(res: Results | dict) -> list[str]:
    """The terminal's table per case with maps (position errors at the last frame a target lives)."""
    lines = []
    for case in Results.of(res).cases.values():
        rows = _map_rows(case)
        if not rows:
            continue
        bound = last_bound(case.rd_maps)
        lines += [f"\n{case.title} (map SNRs {case.rd_maps['snr_db']} dB; position errors at the last frame "
                  "with a target" + ("" if bound is None else f", where the map bound is {bound:.1f} m") + ")",
                  f"  {'method':<34} {'detected %':>10} {'false al. %':>11} {'RMS pos m':>10} {'median m':>9} "
                  f"{'OSPA m':>7} {'s/run':>6}"]
        for n, r in rows.items():
            t = r.tbd
            fa = t.false_alarm_rate_absent
            pos, med = t.rms_pos_last_present_m, t.median_pos_err_last_present_m
            lines.append(f"  {n:<34} {100 * t.detected_rate_present:>10.1f} "
                         f"{'-' if fa is None else f'{100 * fa:.1f}':>11} {'-' if pos != pos else f'{pos:.0f}':>10} "
                         f"{'-' if med != med else f'{med:.0f}':>9} {t.ospa_mean_m:>7.0f} {r.seconds_per_run:>6.2f}")
    return lines
