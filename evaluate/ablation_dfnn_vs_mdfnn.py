"""Ablation: the MDFNN against the same network without its filter layers, the DFNN (Table 3
of the MDFNN paper).

Trains both with the same budget and window (100) and evaluates each on the three built-in
trajectories. (The released, longer-trained DFNN and MDFNN are compared in the main study,
`pmsr evaluate evaluate/fitee2023_three_trajectories.yaml`.)

    python evaluate/ablation_dfnn_vs_mdfnn.py --out runs/ablation_dfnn_vs_mdfnn
"""

import sys
from pathlib import Path

from pmsr_nn.errors import PmsrError
from pmsr_nn.harness.ablation import ABLATION_MODEL, ablation_main

HERE = Path(__file__).resolve().parent


def settings(values, hidden):
    known = {"MDFNN": {**ABLATION_MODEL, "hidden": hidden}, "DFNN": {**ABLATION_MODEL, "kind": "dfnn", "hidden": hidden}}
    bad = [v for v in values if v not in known]
    if bad:
        raise PmsrError(f"unknown network(s) {bad}; choose from {sorted(known)}")
    return {v: (known[v], 100) for v in values}


def main(argv=None) -> int:
    return ablation_main(
        argv, doc=__doc__, title="DFNN vs MDFNN (Table 3)", parameter="network",
        values=["DFNN", "MDFNN"], settings=settings,
        paper_file=HERE / "reference" / "paper_tables.json", paper_key="fitee2023_mdfnn.table3_ablation_rmse_pos_m",
        paper_note="The paper's Table 3 is on its own test data, not on these trajectories.")


if __name__ == "__main__":
    sys.exit(main())
