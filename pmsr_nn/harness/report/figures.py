"""The report's figures of errors against time: position RMSE per case with its PCRB, the set
figures (OSPA, cardinality, RMSE over targets) and a study's sweep; and what every figure of the
report shares (matplotlib off-screen, one colour per method, layout and writing)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..results.typed import Case, Results
from .report_cells import SWEEP_LABELS, space_mark


def pyplot():
    """matplotlib's pyplot on the off-screen Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def lay_out(fig, rect=None) -> None:
    """Lay out a figure: its own (constrained) layout where it has one, else tight within ``rect``
    (figure fractions, where a legend sits outside)."""
    if fig.get_layout_engine() is None:
        fig.tight_layout(rect=rect)


def save_figure(fig, path: Path, dpi: int = 110, rect=None) -> Path:
    """Lay out (:func:`lay_out`), write and close a figure."""
    lay_out(fig, rect)
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path


def method_colours(names) -> dict[str, object]:
    """One colour per method, the same in every figure: matplotlib's ten-colour cycle, or tab20
    for more methods (the cycle would repeat a colour)."""
    names = list(dict.fromkeys(names))
    if len(names) <= 10:
        return {m: f"C{i}" for i, m in enumerate(names)}
    cmap = pyplot().get_cmap("tab20")
    return {m: cmap(i % 20) for i, m in enumerate(names)}


def per_target(curve) -> list:
    """A curve as a list of per-target curves (one target: ``[curve]``)."""
    return curve if curve and isinstance(curve[0], list) else [curve]


def rmse_label(case: Case) -> str:
    """The y label of a case's RMSE figure: the position, or what every row's "position" is (a
    measurement space's, e.g. bistatic range)."""
    names = {r.space.position if r.space else None for r in case.methods.values()}
    return f"{names.pop()} RMSE" if len(names) == 1 and None not in names else "position RMSE (m)"


def plot_rmse(res: Results | dict, out: Path) -> list[Path]:
    """One figure per case: position RMSE vs time of every method with the PCRB (Fig. 9 analogue);
    with several targets one panel per target (Fig. 3 of the S-MSJPDA paper), one legend below
    them. A study with a sweep has its sweep figure instead."""
    results = Results.of(res)
    st = results.settings
    if st.sweep != "none":
        return []
    plt = pyplot()
    paths = []
    dt, warmup = st.dt_s, st.warmup_steps
    for name, case in results.cases.items():
        cv = case.curves
        rmse = {m: per_target(c) for m, c in cv.rmse_pos_m.items()}
        N = len(next(iter(rmse.values())))
        cols = min(N, 5)  # more targets wrap onto more rows, so no panel is squashed
        rows = -(-N // cols)
        fig, axes = plt.subplots(rows, cols, figsize=(9.6, 4.8) if N == 1 else (3.6 * cols, 3.2 * rows + 0.6),
                                 sharey=True, squeeze=False, layout="constrained")
        for ax in axes.flat[N:]:
            ax.set_visible(False)
        names = case.targets
        colours = method_colours(rmse)
        t = np.arange(case.steps) * dt
        for i, ax in enumerate(axes.flat[:N]):
            for m, per in rmse.items():
                ax.semilogy(t, per[i], lw=1.2, label=m, color=colours[m])
            if cv.pcrb_pos_m is not None:
                ax.semilogy(t, per_target(cv.pcrb_pos_m)[i], "k--", lw=1.4, label="PCRB (filtering)")
                ax.semilogy(t, per_target(cv.pcrb_q0_pos_m)[i], "--", color="grey", lw=1.0, label="PCRB, q = 0 (floor)")
                if any(not r.causal for r in case.methods.values()):
                    ax.semilogy(t, per_target(cv.pcrb_smoothing_pos_m)[i], "k:", lw=1.4, label="PCRB (smoothing)")
            if N == 1:
                ax.axvline(warmup * dt, color="grey", lw=0.8)
            ax.set(xlabel="time (s)", title=f"{case.title}: {results.mc_runs} runs" if N == 1 else
                   (names[i] if i < len(names) else f"target {i + 1}"))
            ax.grid(True, which="both", alpha=0.3)
        for row in axes:
            row[0].set_ylabel(rmse_label(case))
        if N == 1:  # outside the data, right of the panel
            axes[0][0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        else:  # one legend for all panels, below them
            handles, labels = axes[0][0].get_legend_handles_labels()
            fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 4), fontsize=8, frameon=False)
            fig.suptitle(f"{case.title}: {results.mc_runs} runs")
        paths.append(save_figure(fig, out / f"{name}_rmse.png", dpi=110 if N == 1 else 100))
    return paths


def plot_set_metrics(res: Results | dict, out: Path) -> list[Path]:
    """Per multi-target case: OSPA, estimated cardinality (with the truth's) and position RMSE
    over targets vs time, every method; one legend below the panels."""
    results = Results.of(res)
    plt = pyplot()
    paths = []
    dt = results.settings.dt_s
    for name, case in results.cases.items():
        cv = case.curves
        if cv.set is None:
            continue
        t = np.arange(case.steps) * dt
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.4), layout="constrained")
        colours = method_colours(cv.set)
        for m, c in cv.set.items():
            label = m + space_mark(case.methods.get(m))
            axes[0].plot(t, c.ospa_m, lw=1.1, label=label, color=colours[m])
            axes[1].plot(t, c.cardinality, lw=1.1, label=label, color=colours[m])
            per = np.asarray(per_target(cv.rmse_pos_m[m]), dtype=float)
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # scans without a matched track: NaN, not plotted
                mean_sq = np.nanmean(per**2, axis=0) if np.isfinite(per).any() else per[0]
            axes[2].semilogy(t, np.sqrt(mean_sq), lw=1.1, label=label, color=colours[m])
        axes[1].step(t, cv.cardinality_truth, "k", where="post", lw=1.6, label="truth")
        for ax, ylabel in zip(axes, (f"OSPA (m, c = {results.settings.set_metrics.c_m:g} m)",
                                     "mean number of tracks", "position RMSE over living targets (m)")):
            ax.set(xlabel="time (s)", ylabel=ylabel)
            ax.grid(True, which="both", alpha=0.3)
        axes[1].yaxis.get_major_locator().set_params(integer=True)  # a count
        handles, labels = axes[1].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 6), fontsize=8, frameon=False)
        fig.suptitle(f"{case.title}: {results.mc_runs} runs")
        paths.append(save_figure(fig, out / f"{name}_set_metrics.png", dpi=100))
    return paths


SWEEP_FIGURES = (("rmse_pos_m", "position RMSE, converged (m)"), ("ospa_m", "OSPA, converged (m)"),
                 ("loss_probability", "loss probability (paper's rule)"),
                 ("swap_probability", "swap probability (last scan)"), ("seconds_per_run", "seconds per run (ours)"))


def plot_sweep(res: Results | dict, path: Path) -> Path:
    """Figs. 4-7 analogue: accuracy, OSPA, loss and swap probabilities and run time against the swept quantity."""
    results = Results.of(res)
    plt = pyplot()
    sweep = results.settings.sweep
    cases = list(results.cases.values())
    xs = [getattr(c.study, sweep) for c in cases]

    def value(row, key):
        v = (row.sets.ospa_m if row.sets else None) if key == "ospa_m" else getattr(row, key)
        return np.nan if v is None else v

    fig, axes = plt.subplots(1, len(SWEEP_FIGURES), figsize=(4.2 * len(SWEEP_FIGURES), 3.8), layout="constrained")
    for m in cases[0].methods:
        for ax, (key, _) in zip(axes, SWEEP_FIGURES):
            ax.plot(xs, [value(c.methods[m], key) if m in c.methods else np.nan for c in cases], "o-", ms=3, label=m)
    for ax, (_, ylabel) in zip(axes, SWEEP_FIGURES):
        ax.set(xlabel=SWEEP_LABELS[sweep], ylabel=ylabel)
        ax.grid(True, alpha=0.3)
    axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))  # outside the data
    return save_figure(fig, path, dpi=100)
