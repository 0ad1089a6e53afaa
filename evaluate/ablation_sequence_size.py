"""Ablation: sequence size epsilon of the MDFNN input (Table 4 of the MDFNN paper).

Trains one MDFNN per window length epsilon (the paper's 10 ... 700) with the same budget and
evaluates each on the three built-in trajectories (Monte Carlo runs of the FITEE 2023 study).

    python evaluate/ablation_sequence_size.py --out runs/ablation_sequence_size
    python evaluate/ablation_sequence_size.py --values 50 100 200 --epochs 5 --out /tmp/eps
"""

import sys
from pathlib import Path

from pmsr_nn.errors import PmsrError
from pmsr_nn.harness.ablation import ABLATION_MODEL, ablation_main

HERE = Path(__file__).resolve().parent


def settings(values, hidden):
    out = {}
    for v in values:
        if not v.isdigit() or int(v) < 2 or int(v) > 1000:
            raise PmsrError(f"sequence size must be an integer in 2..1000 (the tracks are 1000 scans), got {v!r}")
        out[v] = ({**ABLATION_MODEL, "hidden": hidden}, int(v))
    return out


def main(argv=None) -> int:
    return ablation_main(
        argv, doc=__doc__, title="Sequence size epsilon (Table 4)", parameter="epsilon",
        values=["10", "50", "100", "150", "200", "300", "400", "500", "600", "700"], settings=settings,
        paper_file=HERE / "reference" / "paper_tables.json", paper_key="fitee2023_mdfnn.table4_sequence_size_rmse_pos_m",
        paper_note="The paper gives one trajectory (its caption says the first, its text the second).")


if __name__ == "__main__":
    sys.exit(main())
