"""The FM front end's part of a report: its table, its figures and ``maps.h5``.

Written only for cases whose detections came out of the signal chain (``front_end`` in the
case's results): a table of what the chain measured (Pd, false alarms against the CFAR's
nominal rate, errors of the detections against the deviations they report, cancellation depth,
seconds per CPI), the range-Doppler map of run 0 before and after cancellation with the CFAR's
detections on it (the seed's Fig. 3 style) and run 0's detections against the truth in bistatic
range and Doppler over time (Fig. 4 style), and an HDF5 file with the kept maps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ... import SPEED_OF_LIGHT
from ..results.typed import Results
from .figures import pyplot, save_figure


def _f(v, digits: int = 3) -> str:
    return "-" if v is None else f"{v:.{digits}g}"


def front_end_tables(res: Results | dict) -> list[str]:
    """The chain's figures per case (empty when no case has a front end)."""
    results = Results.of(res)
    rows = [(name, c.front_end) for name, c in results.cases.items() if c.front_end]
    if not rows:
        return []
    st = results.settings.sections.get("front_end", {})
    shape = st.get("map_shape", ["?", "?"])
    lines = ["## Front end: signals to detections", "",
             f"Every scan, each transmitter-receiver pair's CPI of {st.get('samples_per_cpi', '?')} complex samples is "
             f"simulated and processed: {st.get('cancellation', {}).get('method', '?')} cancellation, 2D-CCF (batches "
             f"algorithm, {st.get('window', '?')} window) to a {shape[0]} x {shape[1]} (Doppler x range) map of "
             f"{_f(st.get('doppler_bin_hz'))} Hz x {_f(st.get('range_bin_m'), 4)} m cells, 2-D OS-CFAR at Pfa "
             f"{st.get('cfar', {}).get('pfa', '?')}, centroiding. Measured in this run:", "",
             "| case | Pd measured | false alarms / map (nominal) | range RMSE (m) / reported sd | Doppler RMSE (Hz) / "
             "reported sd | cancellation (dB) | s / CPI | x real time |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, f in rows:
        lines.append(f"| {name} | {f['pd_measured']:.3f} | {f['false_alarms_per_map']:.2f} "
                     f"({f['nominal_false_alarms_per_map']:.2f}) | {_f(f['rmse_range_m'])} / {_f(f['reported_sd_range_m'])} "
                     f"| {_f(f['rmse_doppler_hz'])} / {_f(f['reported_sd_doppler_hz'])} | {f['cancellation_depth_db']:.1f} "
                     f"| {f['processing_seconds_per_cpi']:.3f} | {_f(f['faster_than_real_time'])} |")
    lines += ["", "Pd: detections labelled with a target over the (target, pair, scan)s whose true cell lies in the map; "
              "false alarms: every other (centroided) detection -- noise, sidelobes, a second peak of a split echo, "
              "an echo just beyond the map's last range bin -- per map, beside the CFAR's nominal Pfa x cells (cells "
              "over threshold; neighbouring ones merge into one detection); errors: of labelled detections from the true (range, Doppler); s / CPI: "
              "cancellation to centroids of one pair's CPI (simulation not counted), x real time = CPI length / that.",
              ""]
    for name, _ in rows:
        lines += [f"![{name}: range-Doppler map]({name}_rd_map.png)", "",
                  f"![{name}: detections vs truth]({name}_detections.png)", ""]
    lines += ["The maps shown (run 0, example scans, every pair) are in `maps.h5`.", ""]
    return lines


def write_front_end_outputs(res: Results | dict, examples: dict, out: Path) -> list[Path]:
    """Figures and ``maps.h5`` for the cases with a front end; returns the files written."""
    results = Results.of(res)
    names = [n for n, c in results.cases.items() if c.front_end and "@detections" in examples.get(n, {})]
    if not names:
        return []
    st = results.settings.sections["front_end"]
    files = []
    for name in names:
        ex = examples[name]
        title = results.cases[name].title
        if "@maps" in ex:
            files.append(plot_maps(ex, st, out / f"{name}_rd_map.png", title))
        files.append(plot_detections(ex, st, results.settings.dt_s, out / f"{name}_detections.png", title))
    files.append(write_maps_h5(examples, names, st, out / "maps.h5"))
    return files


def plot_maps(ex: dict, st: dict, path: Path, title: str) -> Path:
    """Run 0's first example scan, every pair: power (dB over the map's median) before and after
    cancellation, the CFAR detections circled on the second."""
    plt = pyplot()
    maps = np.asarray(ex["@maps"])[0]  # (S, 4, D, U): before, after, threshold, detections
    f = np.asarray(ex["@map_doppler_hz"])
    S = maps.shape[0]
    km = np.arange(maps.shape[-1]) * st["range_bin_m"] / 1e3
    extent = (km[0], km[-1], f[0], f[-1])
    fig, axes = plt.subplots(S, 2, figsize=(10, 3.2 * S), squeeze=False)
    for s in range(S):
        for j, label in enumerate(("before cancellation", "after cancellation + OS-CFAR")):
            p = maps[s, j]
            db = 10 * np.log10(np.maximum(p, 1e-30) / np.median(p))
            ax = axes[s, j]
            im = ax.imshow(db, origin="lower", aspect="auto", extent=extent, cmap="viridis", vmin=-5,
                           vmax=max(20.0, float(np.percentile(db, 99.99))))
            if j == 1:
                d, u = np.nonzero(maps[s, 3] > 0)
                ax.plot(km[u], f[d], "o", mfc="none", mec="r", ms=5, label="CFAR detection")
                ax.legend(loc="upper right", fontsize=7)
            ax.set(xlabel="excess bistatic range (km)", ylabel="Doppler (Hz)",
                   title=f"pair {s + 1}, scan {int(ex['@map_scans'][0])}: {label}")
            fig.colorbar(im, ax=ax, label="dB over median")
    fig.suptitle(f"{title}: run 0 range-Doppler maps")
    return save_figure(fig, path, rect=(0, 0, 1, 0.97))


def plot_detections(ex: dict, st: dict, dt: float, path: Path, title: str) -> Path:
    """Run 0's detections over time per pair, bistatic range and Doppler, labelled against the
    truth (Fig. 4 of the seed: the C-shapes of targets passing the baseline)."""
    plt = pyplot()
    det = np.asarray(ex["@detections"])  # (K, S, M, 3): range m, Doppler Hz, origin
    truth = np.asarray(ex["@truth_rd"])  # (K, T, S, 2)
    K, S = det.shape[:2]
    t = np.arange(K) * dt
    fig, axes = plt.subplots(2, S, figsize=(4.2 * S, 6.4), squeeze=False)
    for s in range(S):
        for row, (j, unit, scale) in enumerate(((0, "bistatic range (km)", 1e-3), (1, "Doppler (Hz)", 1.0))):
            ax = axes[row, s]
            tt = np.broadcast_to(t[:, None], det.shape[:1] + det.shape[2:3])
            z, org = det[:, s, :, j], det[:, s, :, 2]
            ok = np.isfinite(z)
            clutter = ok & (org < 0)
            target = ok & (org >= 0)
            ax.plot(tt[clutter], z[clutter] * scale, ".", color="0.6", ms=2, label="false alarm")
            ax.plot(tt[target], z[target] * scale, ".", color="C3", ms=3, label="target detection")
            for k in range(truth.shape[1]):
                ax.plot(t, truth[:, k, s, j] * scale, "k-", lw=0.8, label="truth" if k == 0 else None)
            ax.set(xlabel="time (s)", ylabel=unit, title=f"pair {s + 1}")
    axes[0, -1].legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=7)
    fig.suptitle(f"{title}: run 0 detections against the truth")
    return save_figure(fig, path, rect=(0, 0, 0.93, 0.96))


def write_maps_h5(examples: dict, names: list[str], st: dict, path: Path) -> Path:
    """``maps.h5``: per case group the kept maps ``(scans, pairs, D, U)`` (power before and after
    cancellation, CFAR threshold, detections), their axes and run 0's detections ``(K, S, M, 3)``."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["format"] = "pmsr_nn.front_end_maps/1"
        f.attrs["speed_of_light_mps"] = SPEED_OF_LIGHT
        for name in names:
            ex = examples[name]
            g = f.create_group(name)
            if "@maps" in ex:
                maps = np.asarray(ex["@maps"])
                for j, key in enumerate(("power_before", "power_after", "cfar_threshold")):
                    g.create_dataset(key, data=maps[:, :, j], compression="gzip")
                g.create_dataset("cfar_detections", data=maps[:, :, 3] > 0, compression="gzip")
                g.create_dataset("scans", data=np.asarray(ex["@map_scans"]))
                g.create_dataset("doppler_hz", data=np.asarray(ex["@map_doppler_hz"]))
                g.create_dataset("excess_range_m", data=np.arange(maps.shape[-1]) * st["range_bin_m"])
            g.create_dataset("detections_run0", data=np.asarray(ex["@detections"]), compression="gzip")
            g["detections_run0"].attrs["columns"] = "bistatic range (m), Doppler (Hz), truth origin (target, -1 clutter, -2 padding)"
    return path
