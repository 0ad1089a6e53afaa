"""Ablation: order M of the MDFNN's FIR filter layers (Table 5 of the MDFNN paper).

Trains one MDFNN per filter order (the paper's 10 ... 50) with the same budget and window
(100) and evaluates each on the three built-in trajectories.

    python evaluate/ablation_filter_order.py --out runs/ablation_filter_order
"""

import sys
from pathlib import Path

from pmsr_nn.errors import PmsrError
from pmsr_nn.harness.ablation import ABLATION_MODEL, ablation_main

HERE = Path(__file__).resolve().parent


def settings(values, hidden):
    out = {}
    for v in values:
        if not v.isdigit() or not 1 <= int(v) <= 100:
            raise PmsrError(f"filter order must be an integer in 1..100, got {v!r}")
        out[v] = ({**ABLATION_MODEL, "hidden": hidden, "filter_order": int(v)}, 100)
    return out


def main(argv=None) -> int:
    return ablation_main(
        argv, doc=__doc__, title="Filter order M (Table 5)", parameter="M",
        values=["10", "20", "30", "40", "50"], settings=settings,
        paper_file=HERE / "reference" / "paper_tables.json", paper_key="fitee2023_mdfnn.table5_filter_order_rmse_pos_m",
        paper_note="")


if __name__ == "__main__":
    sys.exit(main())
