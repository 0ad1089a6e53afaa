"""Model configuration: every size of DFNN, MDFNN and the RNN baseline is a config value."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..config import require

Activation = Literal["tanh", "sigmoid", "relu", "gelu", "identity"]


MAX_WIDTH = 16_384
"""Widest layer accepted (a 16k x 16k layer already holds 268 M weights, 1 GB)."""

MAX_HIDDEN_LAYERS = 64
"""Most hidden layers accepted (the papers' networks have 3; 20,000 took 850 MB and a minute
before anything was said)."""

MAX_HIDDEN_WEIGHTS = 100_000_000
"""Most weights between consecutive hidden layers (400 MB in float32; Table 2's network has 0.2 M)."""


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of a learned tracker (``models/*.yaml``).

    ``kind``: ``mdfnn`` (hidden layers with FIR filter layers between them, Eqs. 21-27),
    ``dfnn`` (the same hidden layers without filter layers: the ablation of Table 3) or ``rnn``
    (a recurrent baseline, Gao et al. 2018) or ``kalmannet`` (the EKF's structure with a gain
    from a GRU of ``rnn_hidden`` units, :mod:`pmsr_nn.nets.kalmannet`). Defaults are Table 2 of the MDFNN paper: hidden
    layers of 384, 225 and 540 nodes, filter layers of 384 and 225 (the width of the hidden
    layer each one filters), filter order M = 20.

    ``filter_window``: ``causal`` reads the last M hidden outputs (Fig. 4b) and gives a
    filter; ``centred`` reads M/2 either side and gives a *smoother* (compare it with the
    smoothing bound, never the filtering one).

    ``output_activation``: the paper's Eq. 27 applies ``f_h`` (tanh) to the output. Targets are
    normalised to [-1, 1] on the training split, so a test state at the edge of that range sits
    where tanh saturates; ``identity`` is the default and ``tanh`` the paper's choice.

    ``inputs`` / ``output``: what the network reads and what its output means
    (:mod:`pmsr_nn.nets.representation`): ``measurements`` / ``state`` are the paper's
    (min-max normalised rows in, normalised state out); ``local_fixes`` reads per-scan state
    fixes in a translation-invariant, standardised form and ``residual`` predicts the correction
    to the scan's state fix (the output layer then starts at zero, so an untrained network
    returns the fixes).

    ``gain_scale`` and ``innovation_clip`` (KalmanNet only): the network's gain output is multiplied
    by ``gain_scale`` (a smaller first step of the optimiser on the gain, so the filter stays stable
    while it learns), and each innovation row is clipped to ``innovation_clip`` deviations before
    the update (bounded influence of range outliers; null: no clipping).

    ``restart_gate`` (KalmanNet only): where the normalised innovation exceeds it in as many
    measurement rows as there are pairs, the filter has lost the target and re-starts at the scan's
    state fix (if that fix agrees with its own scan within the gate in every row); null: never
    (:meth:`~pmsr_nn.nets.kalmannet.KalmanNetTracker.restarts`). The default, 10, holds for
    checkpoints saved before the option existed: on the studies' KalmanNet checkpoints (mismatch,
    three trajectories, shared drones, one sky) it fires only in the two mismatch runs whose
    window started on a wrong-branch fix.
    """

    kind: Literal["mdfnn", "dfnn", "rnn", "kalmannet"] = "mdfnn"
    hidden: tuple[int, ...] = (384, 225, 540)
    filter_order: int = 20
    filter_window: Literal["causal", "centred"] = "causal"
    filter_taps: Literal["shared", "per_channel"] = "shared"
    activation: Activation = "tanh"
    output_activation: Activation = "identity"
    rnn_cell: Literal["rnn", "lstm", "gru"] = "lstm"
    rnn_hidden: int = 256
    rnn_layers: int = 1
    dropout: float = 0.0
    inputs: Literal["measurements", "local_fixes", "measurements_and_fixes"] = "measurements"
    output: Literal["state", "residual"] = "state"
    gain_scale: float = 1.0
    innovation_clip: float | None = None
    restart_gate: float | None = 10.0

    def __post_init__(self) -> None:
        require(len(self.hidden) >= 1 and all(1 <= h <= MAX_WIDTH for h in self.hidden),
                f"model.hidden must list at least one layer width in [1, {MAX_WIDTH}], got {list(self.hidden)[:8]}")
        require(len(self.hidden) <= MAX_HIDDEN_LAYERS,
                f"model.hidden lists {len(self.hidden):,} layers; at most {MAX_HIDDEN_LAYERS} are accepted")
        weights = sum(a * b for a, b in zip(self.hidden[:-1], self.hidden[1:]))
        require(weights <= MAX_HIDDEN_WEIGHTS, f"model.hidden: {weights:,} weights between the hidden layers; at most "
                                               f"{MAX_HIDDEN_WEIGHTS:,} are accepted (narrower or fewer layers)")
        require(1 <= self.filter_order <= 10_000, f"model.filter_order must be in [1, 10000], got {self.filter_order}")
        require(self.kind != "mdfnn" or len(self.hidden) >= 2,
                "model.hidden: an MDFNN needs at least two hidden layers (a filter layer sits between two)")
        require(1 <= self.rnn_hidden <= MAX_WIDTH and 1 <= self.rnn_layers <= 64,
                f"model.rnn_hidden must be in [1, {MAX_WIDTH}] and model.rnn_layers in [1, 64]")
        require(0.0 <= self.dropout < 1.0, f"model.dropout must be in [0, 1), got {self.dropout}")
        require(0 < self.gain_scale <= 1e3, f"model.gain_scale must be in (0, 1000], got {self.gain_scale}")
        require(self.innovation_clip is None or self.innovation_clip > 0,
                f"model.innovation_clip must be positive (or null), got {self.innovation_clip}")
        require(self.restart_gate is None or self.restart_gate > 0,
                f"model.restart_gate must be positive (or null), got {self.restart_gate}")
        kalmannet = self.kind == "kalmannet"
        require(kalmannet == (self.inputs == "measurements_and_fixes") and (not kalmannet or self.output == "residual"),
                "model: kind kalmannet goes with inputs: measurements_and_fixes and output: residual (and only it "
                f"reads measurements_and_fixes); got kind {self.kind}, inputs {self.inputs}, output {self.output}")

    def input_dim(self, dim_z: int, dim_x: int) -> int:
        """Width of the network's input: the measurement rows, 3 features per axis of local fixes,
        or the measurement rows followed by the state fix (KalmanNet)."""
        return {"local_fixes": 3 * (dim_x // 3), "measurements_and_fixes": dim_z + dim_x}.get(self.inputs, dim_z)

    @property
    def looks_ahead(self) -> bool:
        """True for a smoother (an estimate at k uses measurements after k)."""
        return self.kind == "mdfnn" and self.filter_window == "centred"
