"""What every benchmark records beside its figures: date, command, machine, versions."""

from __future__ import annotations

import datetime
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

from pmsr_nn.environment import cpu_model


def run_info() -> dict:
    return {"date": datetime.date.today().isoformat(), "command": "python " + " ".join(sys.argv),
            "machine": f"{cpu_model()}, {os.cpu_count()} cores", "python": platform.python_version(),
            "torch": torch.__version__}


def write_figures(figures: dict, path: Path | None) -> None:
    """Add :func:`run_info` under ``"info"`` and write ``figures`` as JSON to ``path`` (if given)."""
    figures["info"] = run_info()
    if path:
        Path(path).write_text(json.dumps(figures, indent=2) + "\n")


def median_seconds(fn, repeats: int) -> float:
    """Median wall-clock seconds of ``repeats`` calls of ``fn`` after one untimed warm-up call."""
    fn()  # warm-up: plans, caches
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)
