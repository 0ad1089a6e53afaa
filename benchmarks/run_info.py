"""What every benchmark records beside its figures: date, command, machine, versions."""

from __future__ import annotations

import datetime
import json
import os
import platform
import sys
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
