"""An end-to-end learned multi-target tracker on detections: set prediction over a window.

After the design of MT3v2 (Pinto et al., "Can deep learning be applied to model-based
multi-object tracking?", 2022; our own code, smaller): a transformer encoder reads every
detection of the last ``window`` scans as one token, a decoder of ``queries`` learned queries
answers with a set of states at the window's last scan, each with an existence probability, and
training matches that set to the truth with the Hungarian algorithm (:func:`set_loss`).

What a token is given (:func:`detection_tokens`), per detection: its measurement (bistatic range
over ``range_scale_m``, range-rate over ``rate_scale_mps``, the sine and cosine of its azimuth),
the position where its pair's range ellipse meets its azimuth ray
(:func:`~pmsr_nn.trackers.fix_initiator.range_azimuth_fix`, over ``position_scale_m``; a
geometric transform of the detection alone, no tracking) and whether that fix exists, and, as
learned embeddings, its pair and its age in scans. Nothing else: no association, no origin, no
track. Outputs are positions (m) and velocities (m/s) in the plane; a query's position is an
attention-weighted mean of the tokens' fixes plus a learned offset (a soft association of
detections to the query, the part MT3v2 learns by iterative refinement instead).

Shapes: ``W`` windows, ``L`` scans per window, ``S`` pairs, ``M`` detections per list, ``Q``
queries, ``T = L S M`` tokens.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from torch import nn

from ..config import require
from ..measurements import MeasurementModel
from ..trackers.fix_initiator import range_azimuth_fix

TOKEN_FEATURES = 7
OFFSET_SCALE_M = 500.0
"""Scale of the learned offset a query adds to its attention-weighted mean of the fixes (m)."""


@dataclass(frozen=True)
class SetTrackerConfig:
    """Network size and the scales of its inputs and outputs."""

    window: int = 6
    d_model: int = 128
    heads: int = 4
    encoder_layers: int = 3
    decoder_layers: int = 3
    queries: int = 16
    position_scale_m: float = 10000.0
    range_scale_m: float = 20000.0
    rate_scale_mps: float = 40.0
    velocity_scale_mps: float = 20.0

    def __post_init__(self) -> None:
        require(self.window >= 1 and self.queries >= 1 and self.encoder_layers >= 1 and self.decoder_layers >= 1,
                "set tracker: window, queries and layer counts must be positive")
        require(self.d_model % self.heads == 0, f"set tracker: d_model ({self.d_model}) must be a multiple of heads "
                                                f"({self.heads})")
        require(min(self.position_scale_m, self.range_scale_m, self.rate_scale_mps, self.velocity_scale_mps) > 0,
                "set tracker: scales must be positive")


def detection_tokens(z: torch.Tensor, valid: torch.Tensor, model: MeasurementModel, cfg: SetTrackerConfig
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Tokens of windows of detections ``z (W, L, S, M, d)``, ``valid (W, L, S, M)`` (the last scan
    last): ``features (W, T, 7)`` (float32), ``pair (W, T)``, ``age (W, T)`` (scans before the
    window's last) and ``mask (W, T)`` (True: padding, ignored)."""
    W, L, S, M, _ = z.shape
    comps = model.components
    zz = torch.where(valid.unsqueeze(-1), z, torch.zeros((), dtype=z.dtype))
    pos, ok = range_azimuth_fix(zz.reshape(W * L, S, M, -1), model)
    pos, ok = pos.reshape(W, L, S, M, 2), ok.reshape(W, L, S, M) & valid
    az = zz[..., comps.index("azimuth")]
    feats = torch.stack([pos[..., 0] / cfg.position_scale_m, pos[..., 1] / cfg.position_scale_m, ok.to(z.dtype),
                         zz[..., comps.index("range")] / cfg.range_scale_m,
                         zz[..., comps.index("range_rate")] / cfg.rate_scale_mps, torch.sin(az), torch.cos(az)], -1)
    pair = torch.arange(S, device=z.device)[None, None, :, None].expand(W, L, S, M)
    age = (L - 1 - torch.arange(L, device=z.device))[None, :, None, None].expand(W, L, S, M)
    return (feats.reshape(W, L * S * M, TOKEN_FEATURES).float(), pair.reshape(W, -1), age.reshape(W, -1),
            ~valid.reshape(W, -1))


class SetTracker(nn.Module):
    """``(features, pair, age, mask) -> (position (W, Q, 2) m, velocity (W, Q, 2) m/s, existence logit (W, Q))``."""

    def __init__(self, cfg: SetTrackerConfig, n_pairs: int):
        super().__init__()
        self.cfg, self.n_pairs = cfg, n_pairs
        d = cfg.d_model
        self.embed = nn.Linear(TOKEN_FEATURES, d)
        self.pair = nn.Embedding(n_pairs, d)
        self.age = nn.Embedding(cfg.window, d)
        layer = lambda: nn.TransformerEncoderLayer(d, cfg.heads, 4 * d, dropout=0.0, batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer(), cfg.encoder_layers, enable_nested_tensor=False)
        self.queries = nn.Parameter(torch.randn(cfg.queries, d) * 0.1)
        dec = nn.TransformerDecoderLayer(d, cfg.heads, 4 * d, dropout=0.0, batch_first=True, norm_first=True)
        self.decoder = nn.TransformerDecoder(dec, cfg.decoder_layers)
        self.point = nn.Linear(d, d)
        self.state = nn.Sequential(nn.Linear(d, d), nn.ReLU(), nn.Linear(d, 4))
        self.exist = nn.Linear(d, 1)

    def forward(self, feats: torch.Tensor, pair: torch.Tensor, age: torch.Tensor, mask: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        W = feats.shape[0]
        mask = mask.clone()
        mask[:, 0] = False  # a window with no detection at all still attends to one (zero) token
        feats = feats.to(self.embed.weight.dtype)
        h = self.encoder(self.embed(feats) + self.pair(pair) + self.age(age), src_key_padding_mask=mask)
        q = self.decoder(self.queries.expand(W, -1, -1), h, memory_key_padding_mask=mask)
        # position: an attention-weighted mean of the tokens' fixes (a soft association of detections
        # to the query) plus a learned offset; a window without any fix falls back to the offset alone
        fix = feats[..., :2] * self.cfg.position_scale_m
        usable = (feats[..., 2] > 0.5) & ~mask
        scores = torch.einsum("wqd,wtd->wqt", self.point(q), h) / h.shape[-1] ** 0.5
        scores = scores.masked_fill(~usable[:, None, :], float("-inf"))
        weights = torch.softmax(scores, -1).nan_to_num(0.0)
        s = self.state(q)
        pos = weights @ fix + s[..., :2] * OFFSET_SCALE_M
        return pos, s[..., 2:] * self.cfg.velocity_scale_mps, self.exist(q).squeeze(-1)


def match(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The assignment of ``Q`` predictions to ``N <= Q`` truths of least total ``cost (Q, N)``:
    ``(rows, cols)`` (scipy's Hungarian solver)."""
    return linear_sum_assignment(cost)


def set_loss(pos: torch.Tensor, vel: torch.Tensor, logit: torch.Tensor, true_pos: torch.Tensor,
             true_vel: torch.Tensor, alive: torch.Tensor, cutoff_m: float, position_unit_m: float = 30.0,
             velocity_unit_mps: float = 2.0) -> tuple[torch.Tensor, dict]:
    """The set-prediction loss of a batch, and its parts.

    Predictions ``pos (W, Q, 2)``, ``vel (W, Q, 2)``, ``logit (W, Q)``; truths ``true_pos (W, N, 2)``,
    ``true_vel (W, N, 2)`` of which ``alive (W, N)`` exist. Per window the predictions are matched
    to the living truths minimising ``min(distance, cutoff) / cutoff - p_exist`` (:func:`match`).
    Loss: the smooth-L1 state error of the matched pairs (positions in ``position_unit_m``,
    velocities in ``velocity_unit_mps``), averaged over the living truths, plus the binary
    cross-entropy of the existence of every prediction (1 where matched to a truth nearer than
    ``cutoff_m``, else 0): a GOSPA-like split into localisation, missed (a truth matched to a
    prediction that says it is absent or is too far) and false (an unmatched prediction that says
    it exists) terms.
    """
    W, Q, _ = pos.shape
    dist = torch.cdist(pos.detach().double(), true_pos.double())  # (W, Q, N)
    p = torch.sigmoid(logit.detach()).double()
    cost = (dist.clamp(max=cutoff_m) / cutoff_m - p.unsqueeze(-1)).cpu().numpy()
    target = torch.zeros(W, Q, device=pos.device)
    rows_w, rows_q, cols = [], [], []
    for w in range(W):
        live = np.flatnonzero(alive[w].cpu().numpy())
        if live.size == 0:
            continue
        r, c = match(cost[w][:, live])
        rows_w += [w] * len(r)
        rows_q += r.tolist()
        cols += live[c].tolist()
    state = pos.new_zeros(())
    if rows_w:
        iw, iq, jn = (torch.tensor(v, device=pos.device) for v in (rows_w, rows_q, cols))
        dp = (pos[iw, iq] - true_pos[iw, jn].to(pos.dtype)) / position_unit_m
        dv = (vel[iw, iq] - true_vel[iw, jn].to(vel.dtype)) / velocity_unit_mps
        state = (nn.functional.smooth_l1_loss(dp, torch.zeros_like(dp), reduction="sum")
                 + nn.functional.smooth_l1_loss(dv, torch.zeros_like(dv), reduction="sum")) / len(rows_w)
        near = dist[iw, iq, jn] < cutoff_m
        target[iw[near], iq[near]] = 1.0
    exist = nn.functional.binary_cross_entropy_with_logits(logit, target)
    return state + exist, {"state": float(state.detach()), "existence": float(exist.detach()), "matched": len(rows_w)}
