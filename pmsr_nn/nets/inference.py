"""Tracking with a trained network: sequences of any length by sliding windows and splicing.

A network is trained on windows of ``window`` samples. To track a longer sequence the
measurements are cut into windows (stride ``stride``), every window is run through the network
in one batch, and each output sample is taken from the window in which it has the most context
(``Tracker.context``: samples behind and ahead the estimate can read). For a network with
finite context (MDFNN: ``(M - 1)`` per causal filter layer) the default stride keeps every
estimate's full context inside its window, so the spliced result equals one pass of the network
over the whole sequence. A recurrent network has unbounded memory: it sees at least
``window - stride`` samples of history (default: half a window) and never more than ``window``.
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..data.normalise import MinMaxScaler
from ..errors import CheckpointError, MeasurementError
from ..filters.fixes import hold_last_valid
from ..geometry import Geometry
from .checkpoint import read_checkpoint
from .config import ModelConfig
from .networks import build_network
from .representation import Representation


def splice_plan(steps: int, window: int, stride: int, context: tuple[int | None, int], device=None):
    """Window starts ``(W,)`` and, per sample, the window ``(K,)`` and offset ``(K,)`` it comes from,
    on ``device``.

    Each sample goes to the window where the context it is missing (behind and ahead, clipped
    at the sequence ends where every window misses the same) is smallest; ties go to the
    earliest window.
    """
    if steps < window:
        raise MeasurementError(f"sequence of {steps} samples is shorter than the network's window of {window}")
    starts = list(range(0, steps - window + 1, stride))
    if starts[-1] != steps - window:
        starts.append(steps - window)
    a = torch.tensor(starts, device=device)
    t = torch.arange(steps, device=device)
    off = t[:, None] - a[None, :]  # (K, W)
    inside = (off >= 0) & (off < window)
    behind = window - 1 if context[0] is None else context[0]
    ahead = context[1]
    missing = (behind - off).clamp_min(0) + (ahead - (window - 1 - off)).clamp_min(0)
    missing = torch.where(inside, missing, torch.full_like(missing, 10 * window + steps))
    w = missing.argmin(dim=1)
    return a, w, off.gather(1, w[:, None]).squeeze(1)


def fill_missing(z: torch.Tensor, policy: str) -> torch.Tensor:
    """Rows of ``z (B, K, D)`` holding a NaN: an error (``'error'``) or the last valid row
    carried forward (``'hold'``, a stop-gap: the network never saw repeated scans in training)."""
    bad = torch.isnan(z).any(-1)
    if not bad.any():
        return z
    b, k = (int(v) for v in bad.nonzero()[0])
    if policy == "error":
        raise MeasurementError(f"measurement row {k} of sequence {b} holds NaN; the network needs every "
                               "scan (use --nan hold to repeat the last valid scan instead)")
    if policy != "hold":
        raise ValueError(f"unknown NaN policy {policy!r}")
    if bad[:, 0].any():
        b = int(bad[:, 0].nonzero()[0])
        raise MeasurementError(f"sequence {b} starts with a NaN row; there is no earlier scan to hold")
    return hold_last_valid(z, bad)


def column_layout(columns: list[str]) -> str:
    """``columns`` in words: ``"4 pairs (12 columns: range, range_rate, azimuth)"`` for the
    ``COMPONENT_PAIR`` names of :attr:`pmsr_nn.measurements.MeasurementModel.labels`, else the count."""
    parts = [str(c).rpartition("_") for c in columns]
    if not columns or not all(sep and n.isdigit() for _, sep, n in parts):
        return f"{len(columns)} columns"
    components = list(dict.fromkeys(c for c, _, _ in parts))
    pairs = len({n for _, _, n in parts})
    return f"{pairs} pair{'s' * (pairs != 1)} ({len(columns)} columns: {', '.join(components)})"


class Tracker:
    """A trained network with its normalisation, window and geometry: measurements in, states out."""

    def __init__(self, net: torch.nn.Module, meta: dict, model: ModelConfig, source: str = "<memory>"):
        self.net = net.eval()
        self.meta = meta
        self.model = model
        self.source = source
        self.window = int(meta["window"])
        norm = meta["normalisation"]
        self.measurement_scaler = MinMaxScaler.from_dict(norm["measurements"])
        self.state_scaler = MinMaxScaler.from_dict(norm["states"])
        self.representation = Representation.from_meta(meta, model, where=source)

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> "Tracker":
        """Load a ``tracker.pt`` or any Lightning checkpoint of a run (never unpickles objects)."""
        meta, cfg, state = read_checkpoint(path)
        rep = Representation.from_meta(meta, cfg, where=str(path))
        net = build_network(cfg, meta["dim_z"], meta["dim_x"], rep, meta["dt_s"]).float()
        try:
            net.load_state_dict(state)
        except RuntimeError as exc:
            raise CheckpointError(f"{path}: weights do not fit the model config "
                                  f"({str(exc).splitlines()[0][:160]})") from None
        return cls(net.to(device), meta, cfg, str(path))

    @property
    def context(self) -> tuple[int | None, int]:
        """(behind, ahead): scans either side of ``k`` the estimate at ``k`` reads (inputs included)."""
        behind, ahead = self.net.context
        return (None if behind is None else behind + self.representation.extra_context), ahead

    @property
    def looks_ahead(self) -> bool:
        return self.context[1] > 0

    @property
    def measurement_columns(self) -> list[str]:
        return list(self.meta["measurement_columns"])

    @property
    def state_columns(self) -> list[str]:
        return list(self.meta["state_columns"])

    @property
    def geometry(self) -> Geometry:
        return Geometry.from_dict(self.meta["geometry"])

    def memory(self, stride: int | None = None) -> int:
        """Fewest past scans (the current one included) any estimate reads when tracking with
        ``stride`` (default :meth:`default_stride`): for a recurrent network the splice guarantees
        ``window - stride`` scans of history."""
        behind, _ = self.context
        if behind is None:
            return self.window - (stride or self.default_stride()) + 1
        return behind + 1

    def training_spread(self) -> torch.Tensor:
        """Covariance ``(n, n)`` (float64, SI) of a uniform spread over the training states' ranges:
        what the network knows of a state before it reads any scan (the prior of its
        finite-memory bound, :func:`pmsr_nn.bounds.finite_memory_pcrb`)."""
        s = self.state_scaler
        return torch.diag((s.hi - s.lo).clamp_min(1e-6) ** 2 / 12.0).to(torch.float64)

    def default_stride(self) -> int:
        behind, ahead = self.context
        if behind is None:
            return max(1, self.window // 2)
        return max(1, self.window - behind - ahead)

    def check_compatible(self, geometry: dict, columns: list[str], dt_s: float | None = None, where: str = "input",
                         row: str | None = None) -> None:
        """Refuse measurements from another geometry, column layout or sampling interval (``dt_s``, s):
        one line naming the input (``where``, e.g. ``scenario 'x'``), the row that reads it (``row``,
        a method label, if any) and this checkpoint, and saying what differs."""
        at = f"{where}, row {row!r}: " if row else ""
        if list(columns) != self.measurement_columns:
            raise CheckpointError(f"{at}the checkpoint {self.source} expects {column_layout(self.measurement_columns)}; "
                                  f"the {where.split()[0]} gives {column_layout(columns)}")
        mine, theirs = self.geometry, Geometry.from_dict(geometry)
        same = (mine.pairs == theirs.pairs and len(mine.transmitters) == len(theirs.transmitters)
                and len(mine.receivers) == len(theirs.receivers)
                and all(_close(a.position_m, b.position_m) for a, b in zip(mine.transmitters, theirs.transmitters))
                and all(_close(a.position_m, b.position_m) for a, b in zip(mine.receivers, theirs.receivers)))
        if not same:
            raise CheckpointError(f"{at}the checkpoint {self.source} was trained for another sensor geometry than the "
                                  f"{where}'s (receivers {[list(r.position_m) for r in mine.receivers]} vs "
                                  f"{[list(r.position_m) for r in theirs.receivers]}); retrain for this geometry")
        if dt_s is not None and abs(dt_s - self.meta["dt_s"]) > 1e-9:
            raise CheckpointError(f"{at}the checkpoint {self.source} was trained at dt = {self.meta['dt_s']} s; the "
                                  f"{where} is sampled at {dt_s} s")

    @torch.no_grad()
    def track(self, z: torch.Tensor, *, stride: int | None = None, nan: str = "error",
              windows_per_batch: int = 2048, whole: bool = False) -> torch.Tensor:
        """State estimates ``(B, K, dim_x)`` (float64, SI) for measurements ``z (B, K, dim_z)``
        (or one sequence ``(K, dim_z)``) in SI units, any ``K >= window``. ``whole``: one pass of a
        recurrent network (unbounded memory) over each whole sequence instead of spliced windows."""
        z = torch.as_tensor(z, dtype=torch.float64)
        single = z.ndim == 2
        if single:
            z = z[None]
        if z.ndim != 3:
            raise MeasurementError(f"measurements must be (tracks, steps, {self.meta['dim_z']}), got shape {tuple(z.shape)}")
        if z.shape[-1] != self.meta["dim_z"]:
            raise MeasurementError(f"measurements have {z.shape[-1]} columns; the checkpoint expects "
                                   f"{self.meta['dim_z']} ({', '.join(self.measurement_columns)})")
        if torch.isinf(z).any():
            raise MeasurementError("measurements hold infinite values")
        z = fill_missing(z, nan)
        B, K, _ = z.shape
        stride = stride or self.default_stride()
        if stride < 1:
            raise MeasurementError(f"stride must be at least 1, got {stride}")
        window = self.window
        if whole:
            if self.net.context[0] is not None:
                raise MeasurementError(f"whole-sequence inference is for recurrent networks; this "
                                       f"{self.model.kind} reads {self.net.context[0] + 1} scans")
            if K < window:
                raise MeasurementError(f"sequence of {K} samples is shorter than the network's window of {window}")
            dev = z.device
            window, starts, which, offset = K, torch.zeros(1, dtype=torch.long, device=dev), \
                torch.zeros(K, dtype=torch.long, device=dev), torch.arange(K, device=dev)
        else:
            starts, which, offset = splice_plan(K, window, stride, self.net.context, z.device)
        p = next(self.net.parameters())
        device = p.device
        rep = self.representation
        fixes = rep.fixes(z) if rep.needs_fixes else None
        zn = rep.features(z, fixes).to(p.dtype)  # whole sequences: a window's first inputs read the scan before it
        t = starts[:, None] + torch.arange(window, device=z.device)  # (W, window)
        windows = zn[:, t]  # (B, W, window, dim_z)
        flat = windows.reshape(-1, window, zn.shape[-1])
        out = torch.cat([self.net(flat[i : i + windows_per_batch].to(device)).to(z.device)
                         for i in range(0, len(flat), windows_per_batch)])
        out = out.reshape(B, len(starts), window, -1)
        est = out[:, which, offset]  # (B, K, dim_x)
        est = rep.states(est, rep.base(z, fixes))
        return est[0] if single else est


def _close(a, b, tol_m: float = 1e-3) -> bool:
    return len(a) == len(b) and all(abs(x - y) <= tol_m for x, y in zip(a, b))
