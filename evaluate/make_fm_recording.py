"""Write a simulated FM passive-radar recording that ``pmsr front-end`` reads (an example input).

The first ``--cpis`` scans of one run of a scenario with a ``front_end`` block (default
evaluate/fm_front_end.yaml), one transmitter-receiver pair (``--pair``): the reference and
surveillance channels the signal chain of ``pmsr evaluate`` would process, as an HDF5 file with
complex datasets ``ref`` and ``surv`` ``(cpis, samples)`` and the attribute ``sample_rate_hz``;
the targets' true excess range and Doppler per CPI go along as ``truth_excess_range_m`` and
``truth_doppler_hz`` ``(cpis, targets)`` (NaN where not alive).

    python evaluate/make_fm_recording.py --out iq.h5 --cpis 3
    pmsr front-end iq.h5 --settings evaluate/fm_front_end.yaml --out runs/iq
"""

from __future__ import annotations

import argparse
from pathlib import Path

import h5py
import numpy as np
import torch

from pmsr_nn import SPEED_OF_LIGHT
from pmsr_nn.frontend.chain import true_cells
from pmsr_nn.frontend.fm_signals import echo_snr_db, simulate_cpi
from pmsr_nn.harness.scenario.schema import load_scenario
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.rng import seeded_generator

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", type=Path, default=HERE / "fm_front_end.yaml")
    ap.add_argument("--out", type=Path, required=True, help="HDF5 file to write (must not exist)")
    ap.add_argument("--cpis", type=int, default=3)
    ap.add_argument("--pair", type=int, default=0, help="transmitter-receiver pair index (default 0)")
    args = ap.parse_args()
    if args.out.exists():
        raise SystemExit(f"make_fm_recording: {args.out} exists; give a new file")
    sc = load_scenario(args.scenario)
    if sc.detections is None or sc.detections.front_end is None:
        raise SystemExit(f"make_fm_recording: {args.scenario} has no detections.front_end block")
    setup = prepare(sc)
    case = setup.cases[0]
    model = case.sensing.detection_model
    g = seeded_generator(sc.seed, 0, 0)
    truth = case.truth.draw(1, g)
    s = args.pair
    r, doppler, r_tx, r_rx = (v[0, :, :, s] for v in true_cells(model, truth.x[:, : args.cpis]))  # (K, T)
    baseline = model.geometry.baselines_m()[s]
    spec = sc.detections.front_end.signal
    excess = r - baseline
    alive = case.alive[: args.cpis]
    cpi = simulate_cpi(spec, excess / SPEED_OF_LIGHT, doppler, echo_snr_db(spec, r_tx, r_rx), alive, g)
    with h5py.File(args.out, "x") as f:
        f.create_dataset("ref", data=cpi.ref.numpy())
        f.create_dataset("surv", data=cpi.surv.numpy())
        f.attrs["sample_rate_hz"] = spec.sample_rate_hz
        f.create_dataset("truth_excess_range_m", data=torch.where(alive, excess, np.nan).numpy())
        f.create_dataset("truth_doppler_hz", data=torch.where(alive, doppler, np.nan).numpy())
    print(f"{args.out}: {args.cpis} CPIs of {spec.samples:,} samples at {spec.sample_rate_hz:g} Hz, pair {s}")


if __name__ == "__main__":
    main()
