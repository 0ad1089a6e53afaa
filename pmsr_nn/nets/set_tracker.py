"""An end-to-end learned multi-target tracker on detections: set prediction over a window.

After the design of MT3v2 (Pinto et al., "Can deep learning be applied to model-based
multi-object tracking?", 2022; our own code, smaller): a transformer encoder reads every
detection of the last ``window`` scans as one token; the ``queries`` tokens it scores most likely
to be a target's detection (its *objectness*) seed the decoder's queries (MT3v2's two-stage
selection), and the decoder answers with a set of states at the window's last scan, each with an
existence probability. Training matches that set to the truth with the Hungarian algorithm
(:func:`set_loss`).

What a token is given (:func:`detection_tokens`), per detection: its measurement (bistatic range
over ``range_scale_m``, range-rate over ``rate_scale_mps``, the sine and cosine of its azimuth),
the position where its pair's range ellipse meets its azimuth ray
(:func:`~pmsr_nn.trackers.fix_initiator.range_azimuth_fix`, over ``position_scale_m``; a
geometric transform of the detection alone, no tracking) and whether that fix exists, and, as
learned embeddings, its pair and its age in scans. Nothing else: no association, no origin, no
track (origins are used only by the training loss).

Where the state comes from: each query scores every token (an association logit, learned plus a
prior that favours fixes near its seed's), takes its ``top_k`` tokens with their probabilities,
starts at their weighted mean fix plus a learned offset, and fits them with ``refine_iterations``
Gauss-Newton steps of the measurement model (:mod:`.set_refine`): the network associates, the
model does the geometry. Outputs are positions (m) and velocities (m/s) in the plane.

Shapes: ``W`` windows, ``L`` scans per window, ``S`` pairs, ``M`` detections per list, ``Q``
queries, ``T = L S M`` tokens.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from torch import nn

from ..config import require
from ..measurements import MeasurementModel
from ..trackers.fix_initiator import range_azimuth_fix
from .set_refine import gauss_newton, token_residuals

TOKEN_FEATURES = 7
OFFSET_SCALE_M = 500.0
"""Scale of the learned offset a query adds to its weighted mean of the fixes (m)."""
REASSOCIATION_SCALE = 3.0
"""Whitened residual norm at which the model's evidence costs a token half a logit (re-association)."""
SEED_SPREAD_M = 1000.0
"""Initial spread (m) of the association's geometric prior about a query's seed fix (learned)."""


@dataclass(frozen=True)
class SetTrackerConfig:
    """Network size, the scales of its inputs and outputs, and its refinement: ``top_k`` tokens a
    query may choose, ``refine_iterations`` Gauss-Newton steps (:mod:`.set_refine`; 0: none)
    under a prior of ``prior_position_m`` / ``prior_velocity_mps`` about the network's guess, then
    ``reassociate`` rounds of choosing again (the network's logits plus the model's evidence under
    the refined state) and refitting."""

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
    top_k: int = 36
    refine_iterations: int = 4
    reassociate: int = 0
    prior_position_m: float = 1000.0
    prior_velocity_mps: float = 30.0

    def __post_init__(self) -> None:
        require(self.window >= 1 and self.queries >= 1 and self.encoder_layers >= 1 and self.decoder_layers >= 1,
                "set tracker: window, queries and layer counts must be positive")
        require(self.d_model % self.heads == 0, f"set tracker: d_model ({self.d_model}) must be a multiple of heads "
                                                f"({self.heads})")
        require(min(self.position_scale_m, self.range_scale_m, self.rate_scale_mps, self.velocity_scale_mps,
                    self.prior_position_m, self.prior_velocity_mps) > 0, "set tracker: scales must be positive")
        require(self.top_k >= 1 and self.refine_iterations >= 0 and self.reassociate >= 0,
                "set tracker: top_k must be positive, refine_iterations and reassociate non-negative")


class Tokens(NamedTuple):
    """Windows of detections as tokens (``W`` windows, ``T`` tokens): ``features (W, T, 7)``
    (float32), ``pair (W, T)``, ``age (W, T)`` (scans before the window's last), ``mask (W, T)``
    (True: padding, ignored) and the raw measurements ``z (W, T, d)`` (0 where padded)."""

    features: torch.Tensor
    pair: torch.Tensor
    age: torch.Tensor
    mask: torch.Tensor
    z: torch.Tensor

    def to(self, device) -> "Tokens":
        return Tokens(*(t.to(device) for t in self))


class SetOutput(NamedTuple):
    """The network's answer: refined ``pos (W, Q, 2)`` m and ``vel (W, Q, 2)`` m/s, existence
    ``logit (W, Q)``, association logits ``assoc (W, Q, T)`` (-inf where a token can not be
    chosen), the unrefined position ``pos0 (W, Q, 2)`` and each token's ``objectness (W, T)``
    logit (that it is a target's detection; -inf where unusable)."""

    pos: torch.Tensor
    vel: torch.Tensor
    logit: torch.Tensor
    assoc: torch.Tensor
    pos0: torch.Tensor
    objectness: torch.Tensor


def detection_tokens(z: torch.Tensor, valid: torch.Tensor, model: MeasurementModel, cfg: SetTrackerConfig) -> Tokens:
    """Tokens (:class:`Tokens`) of windows of detections ``z (W, L, S, M, d)``, ``valid (W, L, S, M)``
    (the last scan last)."""
    W, L, S, M, d = z.shape
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
    return Tokens(feats.reshape(W, L * S * M, TOKEN_FEATURES).float(), pair.reshape(W, -1), age.reshape(W, -1),
                  ~valid.reshape(W, -1), zz.reshape(W, L * S * M, d))


class SetTracker(nn.Module):
    """``Tokens -> SetOutput`` for detections of ``model`` scanned every ``dt`` s (module docstring)."""

    def __init__(self, cfg: SetTrackerConfig, model: MeasurementModel, dt: float, dim_x: int = 6):
        super().__init__()
        self.cfg, self.model, self.dt, self.dim_x = cfg, model, float(dt), int(dim_x)
        self.n_pairs = model.n_pairs
        d = cfg.d_model
        self.embed = nn.Linear(TOKEN_FEATURES, d)
        self.pair = nn.Embedding(self.n_pairs, d)
        self.age = nn.Embedding(cfg.window, d)
        layer = lambda: nn.TransformerEncoderLayer(d, cfg.heads, 4 * d, dropout=0.0, batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer(), cfg.encoder_layers, enable_nested_tensor=False)
        self.queries = nn.Parameter(torch.randn(cfg.queries, d) * 0.1)
        dec = nn.TransformerDecoderLayer(d, cfg.heads, 4 * d, dropout=0.0, batch_first=True, norm_first=True)
        self.decoder = nn.TransformerDecoder(dec, cfg.decoder_layers)
        self.objectness = nn.Linear(d, 1)
        self.point = nn.Linear(d, d)
        self.log_spread = nn.Parameter(torch.tensor(math.log(SEED_SPREAD_M)))
        self.state = nn.Sequential(nn.Linear(d, d), nn.ReLU(), nn.Linear(d, 4))
        self.exist = nn.Linear(d, 1)
        self.support = nn.Linear(2, 1)  # existence from the refinement's soft count of consistent detections

    def forward(self, tokens: Tokens) -> SetOutput:
        feats, pair, age, mask, z = tokens
        W, T = mask.shape
        mask = mask.clone()
        mask[:, 0] = False  # a window with no detection at all still attends to one (zero) token
        feats = feats.to(self.embed.weight.dtype)
        h = self.encoder(self.embed(feats) + self.pair(pair) + self.age(age), src_key_padding_mask=mask)
        usable = (feats[..., 2] > 0.5) & ~tokens.mask
        fixes = feats[..., :2] * self.cfg.position_scale_m  # (W, T, 2) m
        # queries seeded by the tokens most likely to be a target's detection (two-stage, as MT3v2)
        objectness = self.objectness(h).squeeze(-1).masked_fill(~usable, float("-inf"))
        Q = min(self.cfg.queries, T)
        seed = objectness.detach().topk(Q, -1).indices  # (W, Q)
        seed_h = h.gather(1, seed.unsqueeze(-1).expand(-1, -1, h.shape[-1]))
        seed_fix = fixes.gather(1, seed.unsqueeze(-1).expand(-1, -1, 2))
        q = self.decoder(seed_h + self.queries[:Q], h, memory_key_padding_mask=mask)
        # association: a logit per query and token, learned plus a geometric prior (fixes near the
        # seed's); the top_k tokens of each query with their probabilities start (weighted mean of
        # their fixes plus a learned offset) and weigh the refinement
        near = ((fixes[:, None] - seed_fix[:, :, None]) ** 2).sum(-1) / (2 * torch.exp(2 * self.log_spread))
        assoc = torch.einsum("wqd,wtd->wqt", self.point(q), h) / h.shape[-1] ** 0.5 - near
        assoc = assoc.masked_fill(~usable[:, None, :], float("-inf"))
        k = min(self.cfg.top_k, T)
        top, idx = assoc.topk(k, -1)  # (W, Q, k)
        wk = torch.sigmoid(top)  # 0 where -inf (an unusable token)
        fix = chosen(fixes, idx)  # (W, Q, k, 2)
        s = self.state(q)
        mean = (wk.unsqueeze(-1) * fix).sum(-2) / wk.sum(-1, keepdim=True).clamp_min(1e-6)
        pos0 = mean + s[..., :2] * OFFSET_SCALE_M
        vel0 = s[..., 2:] * self.cfg.velocity_scale_mps
        support = wk.sum(-1)
        pos, vel = pos0, vel0
        prior = (self.cfg.prior_position_m, self.cfg.prior_velocity_mps)
        if self.cfg.refine_iterations:
            pos, vel, support = gauss_newton(pos0, vel0, chosen(z, idx), chosen(pair, idx), chosen(age, idx), wk,
                                             self.model, self.dt, self.dim_x, self.cfg.refine_iterations, prior)
        for _ in range(self.cfg.reassociate):
            # choose again among all tokens, the network's logits plus the measurement model's evidence
            # under the refined state, and refit from there
            e2 = token_residuals(pos, vel, z, pair, age, self.model, self.dt, self.dim_x)
            top, idx = (assoc - e2.to(assoc.dtype) / (2 * REASSOCIATION_SCALE**2)).topk(k, -1)
            pos, vel, support = gauss_newton(pos, vel, chosen(z, idx), chosen(pair, idx), chosen(age, idx),
                                             torch.sigmoid(top), self.model, self.dt, self.dim_x,
                                             max(self.cfg.refine_iterations, 1), prior)
        support = support.to(s.dtype).unsqueeze(-1)
        logit = (self.exist(q) + self.support(torch.cat([torch.log1p(support), support / (self.cfg.window * self.n_pairs)],
                                                          -1))).squeeze(-1)
        return SetOutput(pos, vel, logit, assoc, pos0, objectness)


def chosen(t: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Per query the chosen tokens' rows of ``t (W, T, ...)``: ``(W, Q, k, ...)`` for ``idx (W, Q, k)``."""
    rest = t.shape[2:]
    src = t.unsqueeze(1).expand(-1, idx.shape[1], *t.shape[1:])
    return src.gather(2, idx.reshape(*idx.shape, *(1 for _ in rest)).expand(*idx.shape, *rest))


def match(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The assignment of ``Q`` predictions to ``N <= Q`` truths of least total ``cost (Q, N)``:
    ``(rows, cols)`` (scipy's Hungarian solver)."""
    return linear_sum_assignment(cost)


def set_loss(out: SetOutput, true_pos: torch.Tensor, true_vel: torch.Tensor, alive: torch.Tensor, cutoff_m: float,
             origin: torch.Tensor | None = None, position_unit_m: float = 30.0, velocity_unit_mps: float = 2.0,
             start_weight: float = 0.2, existence: str = "matched") -> tuple[torch.Tensor, dict]:
    """The set-prediction loss of a batch, and its parts.

    Predictions ``out`` (:class:`SetOutput`, ``Q`` per window); truths ``true_pos (W, N, 2)``,
    ``true_vel (W, N, 2)`` of which ``alive (W, N)`` exist. Per window the predictions are matched
    to the living truths minimising ``min(distance, cutoff) / cutoff - p_exist`` (:func:`match`).
    Loss, summed:

    * *state*: the smooth-L1 error of the matched pairs' refined states (positions in
      ``position_unit_m``, velocities in ``velocity_unit_mps``) plus ``start_weight`` times that
      of their unrefined positions, averaged over the matched pairs;
    * *existence*: the binary cross-entropy of every prediction's existence, 1 for the matched
      (``existence="matched"``: however far; the matching, not a distance, says which query answers
      for a target) or for the matched nearer than ``cutoff_m`` (``"near"``: what GOSPA counts as
      found), 0 for the others;
    * *association* (where ``origin (W, T)``, the index of the truth behind each token or < 0 for
      clutter and padding, is given): per matched pair the binary cross-entropy of the query's
      association logits, the mean over the target's own detections plus the mean over the other
      usable tokens; and *objectness*: the binary cross-entropy of every usable token's
      objectness against whether it is a target's detection.
    """
    require(existence in ("matched", "near"), f"set loss: existence must be 'matched' or 'near', got {existence!r}")
    pos, vel, logit = out.pos, out.vel, out.logit
    W, Q, _ = pos.shape
    dist = torch.cdist(pos.detach().double(), true_pos.double())  # (W, Q, N)
    p = torch.sigmoid(logit.detach()).double()
    cost = (dist.clamp(max=cutoff_m) / cutoff_m - p.unsqueeze(-1)).cpu().numpy()
    alive_np = alive.cpu().numpy()
    rows_w, rows_q, cols = [], [], []
    for w in range(W):
        live = np.flatnonzero(alive_np[w])
        if live.size == 0:
            continue
        r, c = match(cost[w][:, live])
        rows_w += [w] * len(r)
        rows_q += r.tolist()
        cols += live[c].tolist()
    target = torch.zeros(W, Q, device=pos.device, dtype=logit.dtype)
    state = assoc = pos.new_zeros((), dtype=torch.float32)
    if rows_w:
        iw, iq, jn = (torch.tensor(v, device=pos.device) for v in (rows_w, rows_q, cols))
        tp, tv = true_pos[iw, jn], true_vel[iw, jn]
        huber = lambda e: nn.functional.smooth_l1_loss(e, torch.zeros_like(e), reduction="sum")
        state = (huber((pos[iw, iq] - tp.to(pos.dtype)) / position_unit_m)
                 + huber((vel[iw, iq] - tv.to(vel.dtype)) / velocity_unit_mps)
                 + start_weight * huber((out.pos0[iw, iq] - tp.to(out.pos0.dtype)) / position_unit_m)) / len(rows_w)
        if existence == "near":
            near = (pos.detach()[iw, iq] - tp.to(pos.dtype)).norm(dim=-1) < cutoff_m
            target[iw[near], iq[near]] = 1.0
        else:
            target[iw, iq] = 1.0
        if origin is not None:
            a = out.assoc[iw, iq]  # (P, T)
            usable = torch.isfinite(a)
            own = (origin[iw] == jn[:, None]) & usable
            other = ~own & usable
            a = a.masked_fill(~usable, 0.0)
            pos_term = (nn.functional.softplus(-a) * own).sum(-1) / own.sum(-1).clamp_min(1)
            neg_term = (nn.functional.softplus(a) * other).sum(-1) / other.sum(-1).clamp_min(1)
            assoc = (pos_term + neg_term).mean()
    exist = nn.functional.binary_cross_entropy_with_logits(logit, target)
    objectness = pos.new_zeros((), dtype=torch.float32)
    if origin is not None:
        usable = torch.isfinite(out.objectness)
        if bool(usable.any()):
            objectness = nn.functional.binary_cross_entropy_with_logits(out.objectness[usable],
                                                                        (origin[usable] >= 0).to(out.objectness.dtype))
    total = state.float() + exist + assoc.float() + objectness.float()
    return total, {"state": float(state.detach()), "existence": float(exist.detach()),
                   "association": float(assoc.detach()), "objectness": float(objectness.detach()),
                   "matched": len(rows_w)}
