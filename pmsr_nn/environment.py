"""What a result records about where it was made: versions, machine, device, threads, commit."""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from . import __version__


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def git_commit() -> str | None:
    """The package checkout's commit (with ``+dirty`` for local changes), or None outside git."""
    root = Path(__file__).resolve().parents[1]
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5)
        if rev.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return rev.stdout.strip() + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def environment(device: str = "cpu") -> dict:
    """Versions, machine, device and thread count, date and command line."""
    dev = str(device)
    if dev.startswith("cuda") and torch.cuda.is_available():
        dev = f"{dev} ({torch.cuda.get_device_name(torch.device(dev))})"
    return {"pmsr_nn": __version__, "torch": torch.__version__, "numpy": np.__version__,
            "python": platform.python_version(), "device": dev, "threads": torch.get_num_threads(),
            "machine": f"{cpu_model()}, {os.cpu_count()} cores", "date": datetime.date.today().isoformat(),
            "command": " ".join([_program(), *sys.argv[1:]]), "commit": git_commit()}


def _program() -> str:
    """The command's name as a user would type it: ``python -m pmsr_nn.cli`` runs ``cli/__main__.py``."""
    path = Path(sys.argv[0])
    return "python -m pmsr_nn.cli" if path.name == "__main__.py" and path.parent.name == "cli" else path.name


def resolve_device(text: str) -> torch.device:
    """``--device`` text as a torch device that exists on this machine (one-line error otherwise)."""
    from .errors import ConfigError

    try:
        dev = torch.device(text)
    except (RuntimeError, ValueError, TypeError):
        raise ConfigError(f"--device {text!r} is not a torch device (cpu, cuda, cuda:0, mps)") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(f"--device {text}: no CUDA GPU is available on this machine (use cpu)")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"--device {text}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    elif dev.type == "mps":
        if not torch.backends.mps.is_available():
            raise ConfigError(f"--device {text}: no Apple GPU is available on this machine (use cpu)")
    elif dev.type != "cpu":
        raise ConfigError(f"--device {text}: pmsr runs on cpu, cuda or mps devices")
    return dev
