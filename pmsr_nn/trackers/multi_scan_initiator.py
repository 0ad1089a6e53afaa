"""Multi-scan initiation (:class:`MultiScanInitiator`, an :class:`~.roles.Initiator`): a tentative
track starts only from single-scan candidates that agree over ``scans`` consecutive scans.

A single-scan initiator (:class:`~.spherical_initiator.SphericalInitiator` or
:class:`~.fix_initiator.FixInitiator`) gives each scan's *candidates*: Gaussians of the state
from that scan's unused detections alone, each with the initiator's prior ``N(0, v^2)`` per
velocity axis (``v`` its ``velocity_sd_mps``) and ``N(0, other_sd^2)`` on the entries it does not
fix. A *chain* of length ``j`` ending at scan ``k`` is a candidate of each of the scans
``k - j + 1 .. k`` with its fused Gaussian (a Kalman filter over the chain: the first candidate,
prior included, predicted scan by scan with the motion model's ``F``, ``Q`` and updated with each
later candidate's likelihood, its information less the prior's, so the prior counts once).

Every scan, each chain ending at the scan before, predicted to this scan, is gated against this
scan's candidates by the chi-square of the position and velocity difference under the sum of the
covariances (``2 D`` degrees of freedom, ``gate_probability``); each pair that passes is a chain
one longer. Chains of length ``scans`` start tracks, greedily by the smallest summed chi-square
and exclusively (a candidate starts at most one track); the started track is the chain's fused
Gaussian. Chains that share a candidate with a started one are dropped; at most
:data:`MAX_CHAINS` of each length are kept per run (smallest summed chi-square).

A clutter candidate that meets a random other one inside the gate: with candidates spread
uniformly over a volume ``V`` of position-velocity space, the chance is the gate's volume
``V_4 gamma^2 sqrt(det S) / V`` (in 2-D, ``V_4 = pi^2 / 2``) per pair of candidates, and a
chain of three must pass two such gates.

Shapes: ``B`` runs, ``G`` candidates of a scan, ``H`` chains kept, ``j`` chain length, ``n``
state dimension, ``D`` spatial dimension.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from ..config import require
from ..filters.gaussian import Gaussian
from ..measurements import MeasurementModel
from .gating import gate_threshold, inside_gate
from .roles import Initiator

MAX_CHAINS = 256
"""Most chains of one length kept per run between scans (smallest summed chi-square first)."""

CHUNK = 1 << 18
"""Chain-candidate pairs gated at once (all runs together): bounds the memory of the gate."""


@dataclass
class Chains:
    """Chains of one length ``j`` ending at the current scan, padded per run: fused Gaussians
    ``g (B, H, n)``, ``real (B, H)``, summed gate chi-square ``chi2 (B, H)`` and ``members
    (B, H, j)`` the candidate of each scan of the chain (index into that scan's candidates,
    oldest first)."""

    g: Gaussian
    real: torch.Tensor
    chi2: torch.Tensor
    members: torch.Tensor


@dataclass
class MultiScanInitiator:
    """Tracks from candidates of ``base`` consistent over ``scans`` (2 or more) consecutive
    scans (module docstring); ``gate_probability`` the scan-to-scan gate's. :meth:`begin`
    before the first scan of a batch of runs; :meth:`initiate` must then hear every scan."""

    base: Initiator
    scans: int = 3
    gate_probability: float = 0.999
    F: torch.Tensor | None = field(default=None, repr=False)
    Q: torch.Tensor | None = field(default=None, repr=False)
    chains: list = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        require(self.scans >= 2, f"multi-scan initiation needs scans >= 2, got {self.scans}")
        require(0.0 < self.gate_probability < 1.0, f"gate probability must be in (0, 1), got {self.gate_probability}")

    def check(self, model: MeasurementModel, what: str = "initiation from detections") -> None:
        self.base.check(model, what)

    def begin(self, B: int, F: torch.Tensor, Q: torch.Tensor) -> None:
        """A new batch of ``B`` runs: forget earlier candidates; ``F``, ``Q`` ``(n, n)`` one scan's
        motion."""
        self.F, self.Q, self.chains = F, Q, []

    def prior_information(self, model: MeasurementModel, n: int, other_sd: torch.Tensor, dtype) -> torch.Tensor:
        """``(n, n)``: the information of the base's prior in a candidate, ``1 / v^2`` per velocity
        entry, ``1 / other_sd^2`` on the entries it does not fix, 0 on position."""
        d = other_sd.to(dtype) ** -2
        d[list(model.pos_idx)] = 0.0
        d[list(model.vel_idx)] = self.base.velocity_sd_mps ** -2
        return torch.diag(d)

    def initiate(self, z: torch.Tensor, unused: torch.Tensor, model: MeasurementModel, n: int,
                 other_sd: torch.Tensor, **where) -> tuple[Gaussian, torch.Tensor]:
        """Tracks ``(B, G', n)`` and which are real ``(B, G')`` started at this scan from the base's
        candidates of detections ``z`` marked ``unused`` (as the base's ``initiate``)."""
        require(self.F is not None, "MultiScanInitiator.begin must be called before initiate")
        cand, real = self.base.initiate(z, unused, model, n, other_sd, **where)
        B, G = real.shape
        dtype, dev = cand.x.dtype, cand.x.device
        eye = torch.eye(n, dtype=dtype, device=dev)
        P = torch.where(real[..., None, None], cand.P, eye)
        info = torch.linalg.inv(P)
        Y = info - self.prior_information(model, n, other_sd, dtype)
        Y = 0.5 * (Y + Y.transpose(-1, -2))
        y = (info @ torch.where(real[..., None], cand.x, 0.0).unsqueeze(-1)).squeeze(-1)
        pv = list(model.pos_idx) + list(model.vel_idx)
        new = [Chains(Gaussian(cand.x, P), real, torch.zeros(B, G, dtype=dtype, device=dev),
                      torch.arange(G, device=dev).expand(B, G).unsqueeze(-1))]
        for prev in self.chains[: self.scans - 1]:
            new.append(self._extend(prev, Gaussian(cand.x, P), real, Y, y, pv))
        started = torch.zeros(B, 0, dtype=torch.int64, device=dev)
        if len(new) == self.scans:
            started = exclusive(new[-1])
        done = new[-1] if len(new) == self.scans else None
        if done is not None and started.shape[1]:
            picked = take_members(done, started)  # (B, T, scans), -1 padding
            for c in new[:-1]:
                c.real &= ~clashes(c.members, picked)
        self.chains = new[: self.scans - 1]
        if done is None or not started.shape[1]:
            return Gaussian(z.new_zeros(B, 0, n), z.new_zeros(B, 0, n, n)), torch.zeros(B, 0, dtype=torch.bool,
                                                                                        device=z.device)
        ok = started >= 0
        i = started.clamp(min=0)
        x = done.g.x.gather(1, i[..., None].expand(-1, -1, n))
        Pg = done.g.P.gather(1, i[..., None, None].expand(-1, -1, n, n))
        return Gaussian(torch.where(ok[..., None], x, 0.0), torch.where(ok[..., None, None], Pg, eye)), ok

    def _extend(self, prev: Chains, cand: Gaussian, real: torch.Tensor, Y: torch.Tensor, y: torch.Tensor,
                pv: list[int]) -> Chains:
        """The chains one longer: ``prev`` (ending at the scan before) predicted and gated against
        this scan's candidates ``cand (B, G, n)`` (``real``; likelihood information ``Y (B, G, n,
        n)`` and ``y (B, G, n)``), each passing pair fused."""
        F, Q = self.F.to(cand.x.dtype), self.Q.to(cand.x.dtype)
        B, H, n = prev.g.x.shape
        G = real.shape[1]
        j = prev.members.shape[-1] + 1
        xp = prev.g.x @ F.T
        Pp = F @ prev.g.P @ F.T + Q
        gamma = gate_threshold(self.gate_probability, len(pv))
        idx = torch.tensor(pv, device=cand.x.device)
        hits = []
        if H and G:
            # a necessary condition first, cheap on every pair: each entry within its own
            # deviation's gate (d_i^2 / S_ii <= d^T S^-1 d)
            dp, dc = xp[..., idx], cand.x[..., idx]  # (B, H, p), (B, G, p)
            vp, vc = Pp[..., idx, idx], cand.P[..., idx, idx]
            rows = max(1, CHUNK // max(B * G, 1))
            found = []
            for h0 in range(0, H, rows):
                h1 = min(H, h0 + rows)
                d = dc[:, None] - dp[:, h0:h1, None]  # (B, h, G, p)
                near = (d * d <= gamma * (vc[:, None] + vp[:, h0:h1, None])).all(-1)
                near &= prev.real[:, h0:h1, None] & real[:, None, :]
                nz = torch.nonzero(near)
                nz[:, 1] += h0
                found.append(nz)
            pairs = torch.cat(found)  # (P, 3): b, h, g
            for c0 in range(0, len(pairs), CHUNK):
                b, h, g = pairs[c0:c0 + CHUNK].unbind(-1)
                d = cand.x[b, g][:, idx] - xp[b, h][:, idx]
                S = Pp[b, h][:, idx[:, None], idx] + cand.P[b, g][:, idx[:, None], idx]
                L, bad = torch.linalg.cholesky_ex(S)
                w = torch.linalg.solve_triangular(L, d.unsqueeze(-1), upper=False).squeeze(-1)
                d2 = torch.where(bad == 0, (w * w).sum(-1), torch.inf)
                keep = inside_gate(d2, gamma)
                hits.append((b[keep], h[keep], g[keep], d2[keep]))
        if hits:
            b, h, g, d2 = (torch.cat(t) for t in zip(*hits))
        else:
            b, h, g = (torch.zeros(0, dtype=torch.int64, device=cand.x.device) for _ in range(3))
            d2 = cand.x.new_zeros(0)
        # the fusion, in information form: the predicted chain updated with the candidate's likelihood
        Lp = torch.linalg.inv(Pp[b, h])
        Pf = torch.linalg.inv(Lp + Y[b, g])
        Pf = 0.5 * (Pf + Pf.transpose(-1, -2))
        xf = (Pf @ ((Lp @ xp[b, h].unsqueeze(-1)).squeeze(-1) + y[b, g]).unsqueeze(-1)).squeeze(-1)
        chi2 = prev.chi2[b, h] + d2
        members = torch.cat([prev.members[b, h], g[:, None]], -1)
        return padded(b, chi2, xf, Pf, members, B, n, j)


def padded(b: torch.Tensor, chi2: torch.Tensor, x: torch.Tensor, P: torch.Tensor, members: torch.Tensor, B: int,
           n: int, j: int) -> Chains:
    """Chains listed flat (run ``b``, ``chi2``, ``x``, ``P``, ``members``) padded per run, at most
    :data:`MAX_CHAINS` a run, the smallest ``chi2`` first."""
    order = torch.argsort(chi2, stable=True)
    order = order[torch.argsort(b[order], stable=True)]  # by run, then chi-square
    b, chi2, x, P, members = b[order], chi2[order], x[order], P[order], members[order]
    per = torch.bincount(b, minlength=B)
    slot = torch.arange(len(b), device=b.device) - (per.cumsum(0) - per)[b]
    keep = slot < MAX_CHAINS
    b, slot, chi2, x, P, members = b[keep], slot[keep], chi2[keep], x[keep], P[keep], members[keep]
    H = int(slot.max()) + 1 if len(slot) else 0
    dtype, dev = x.dtype, x.device
    out = Chains(Gaussian(torch.zeros(B, H, n, dtype=dtype, device=dev),
                          torch.eye(n, dtype=dtype, device=dev).repeat(B, H, 1, 1)),
                 torch.zeros(B, H, dtype=torch.bool, device=dev), torch.full((B, H), torch.inf, dtype=dtype, device=dev),
                 torch.full((B, H, j), -1, dtype=torch.int64, device=dev))
    out.g.x[b, slot], out.g.P[b, slot] = x, P
    out.real[b, slot], out.chi2[b, slot], out.members[b, slot] = True, chi2, members
    return out


def clashes(members: torch.Tensor, picked: torch.Tensor) -> torch.Tensor:
    """``(B, H)``: chains ``members (B, H, j)`` that share a candidate of the same scan with one of
    ``picked (B, T, J)`` (``J >= j`` scans, both ending at the current scan; -1 padding)."""
    j = members.shape[-1]
    tail = picked[..., -j:]  # (B, T, j): the same scans
    same = (members[:, :, None, :] == tail[:, None, :, :]) & (tail[:, None, :, :] >= 0)
    return same.any(-1).any(-1)


def take_members(chains: Chains, which: torch.Tensor) -> torch.Tensor:
    """``(B, T, j)`` the members of the chains at ``which (B, T)`` (-1: none)."""
    j = chains.members.shape[-1]
    m = chains.members.gather(1, which.clamp(min=0)[..., None].expand(-1, -1, j))
    return torch.where((which >= 0)[..., None], m, -1)


def exclusive(chains: Chains) -> torch.Tensor:
    """``(B, T)``: the chains that start tracks, greedily per run (batched over runs): the smallest
    summed chi-square left, then every chain sharing a candidate with it is dropped (-1 padding)."""
    B, H = chains.real.shape
    key = torch.where(chains.real, chains.chi2, torch.inf)
    taken = []
    while H:
        best_key, best = key.min(1)
        go = torch.isfinite(best_key)
        if not bool(go.any()):
            break
        pick = chains.members.gather(1, best[:, None, None].expand(B, 1, chains.members.shape[-1]))  # (B, 1, j)
        clash = ((chains.members == pick) & (pick >= 0)).any(-1) & go[:, None]
        key = torch.where(clash, torch.inf, key)
        taken.append(torch.where(go, best, -1))
    return torch.stack(taken, 1) if taken else torch.zeros(B, 0, dtype=torch.int64, device=chains.real.device)
