"""Tentative tracks from position fixes of (bistatic range, azimuth) detections
(:class:`FixInitiator`, one of the initiators of :mod:`.initiators`).

Shapes: ``B`` runs, ``S`` pairs, ``M`` detections per list, ``d`` components per pair, ``n``
state dimension, ``G`` tracks started.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.gaussian import Gaussian
from ..measurements import MeasurementModel, wrap_angle
from .gating import gate_threshold, inside_gate, mahalanobis
from .initiators import velocity_fit


def range_azimuth_fix(z: torch.Tensor, model: MeasurementModel) -> tuple[torch.Tensor, torch.Tensor]:
    """Closed-form position fixes ``(..., S, M, 2)`` of detections ``z (..., S, M, d)`` (pair ``s``
    measured by ``model``'s pair ``s``; planar) and ``ok (..., S, M)``: the receiver's ray at the
    measured azimuth meets the pair's ellipse (range beyond the baseline, finite); 0 where not."""
    comps = model.components
    r, az = z[..., comps.index("range")], z[..., comps.index("azimuth")]
    tx = model.geometry.pair_tx_positions(z.dtype, z.device)[:, None, :]  # (S, 1, 2)
    rx = model.geometry.pair_rx_positions(z.dtype, z.device)[:, None, :]
    base = rx - tx
    u = torch.stack([torch.sin(az), torch.cos(az)], -1)  # azimuth clockwise from north
    L2 = (base * base).sum(-1)
    denom = 2 * (r + (base * u).sum(-1))
    rho = (r * r - L2) / denom
    pos = rx + rho.unsqueeze(-1) * u
    ok = torch.isfinite(rho) & (rho > 0) & (r * r > L2)
    return torch.where(ok.unsqueeze(-1), pos, torch.zeros((), dtype=z.dtype, device=z.device)), ok


FIX_COVARIANCES = ("linearised", "unscented")
"""How a fix's covariance is computed (:attr:`FixInitiator.covariance`)."""


def fix_spread(z: torch.Tensor, model: MeasurementModel, pos: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The unscented covariance of the fixes ``pos (..., 2)`` of detections ``z (..., d)``:
    ``spread (..., 2, 2)``, the spread of the fixes of (range, azimuth) sigma points about ``pos``
    (points ``z +- sqrt(3) sd`` along each of the two, weights 1/6; the centre's 1/3 adds nothing
    about itself; the unscented transform's kappa = 1, which matches a Gaussian's moments to the
    fourth), and ``fine (...)``: every sigma point has a fix. Unlike the linearised ``H^-1 R
    H^-T`` it follows the iso-range ellipse's curvature over the azimuth error's reach (the fix
    moves along the ellipse, not its tangent): tens of metres across the range where the azimuth
    spreads a fix over hundreds. In the linear regime the two agree."""
    comps = model.components
    rows = [comps.index("range"), comps.index("azimuth")]
    steps = math.sqrt(3.0) * torch.tensor([model.noise_std[i] for i in rows], dtype=z.dtype, device=z.device)
    moves = [(c, sign * step) for c, step in zip(rows, steps) for sign in (1.0, -1.0)]
    moved = z.expand(len(moves), *z.shape).clone()  # the sigma points, fixed in one call
    for i, (c, step) in enumerate(moves):
        moved[i, ..., c] = moved[i, ..., c] + step
    p, fine = range_azimuth_fix(moved, model)
    spread = torch.zeros(*pos.shape, 2, dtype=z.dtype, device=z.device)
    every = torch.ones(pos.shape[:-1], dtype=torch.bool, device=z.device)
    for i in range(len(moves)):
        dp = p[i] - pos
        spread = spread + dp.unsqueeze(-1) * dp.unsqueeze(-2) / 6.0
        every = every & fine[i]
    return spread, every


@dataclass(frozen=True)
class FixInitiator:
    """Tentative tracks from the detections no track gated, one per group of detections of
    ``>= min_pairs`` different pairs whose position fixes agree.

    Each pair's (bistatic range, azimuth) fixes a position in the plane: the receiver's ray at
    that azimuth meets the ellipse with the pair's foci. Its covariance is the linearised
    ``H^-1 R H^-T`` (``H`` the model's Jacobian of range and azimuth by position). Two fixes of
    different pairs agree when their squared Mahalanobis distance under the sum of their
    covariances is within the chi-square gate ``gate_probability`` (2 degrees of freedom;
    ``covariance: unscented`` gives each fix the spread of its sigma points' fixes instead,
    :func:`fix_spread`). A
    group's position is the information-weighted mean of its fixes; its velocity the linear
    least-squares fit of the group's range-rates (or Dopplers, linear in velocity at a known
    position) under a prior ``N(0, velocity_sd_mps^2)`` per axis; other state entries (e.g.
    acceleration) start at 0 with deviations ``other_sd`` (the scenario's initiation prior).
    """

    velocity_sd_mps: float = 20.0
    min_pairs: int = 2
    gate_probability: float = 0.999
    covariance: str = "linearised"

    def __post_init__(self) -> None:
        require(self.covariance in FIX_COVARIANCES,
                f"fix_covariance must be one of {', '.join(FIX_COVARIANCES)}, got {self.covariance!r}")
        require(self.velocity_sd_mps > 0 and math.isfinite(self.velocity_sd_mps),
                f"the initiator's velocity deviation must be positive, got {self.velocity_sd_mps}")
        require(self.min_pairs >= 1, f"min_pairs must be at least 1, got {self.min_pairs}")
        require(0.5 <= self.gate_probability < 1.0, f"gate probability must be in [0.5, 1), got {self.gate_probability}")

    def begin(self, B: int, F: torch.Tensor | None = None, Q: torch.Tensor | None = None) -> None:
        """A single-scan initiator keeps nothing across scans."""

    def check(self, model: MeasurementModel, what: str = "initiation from detections") -> None:
        """One-line refusal of a model this initiator can not fix positions from."""
        if "azimuth" not in model.components or "range" not in model.components or model.geometry.dim != 2:
            raise ConfigError(f"{what} fixes positions from (bistatic range, azimuth) in 2-D; the detections measure "
                              f"{list(model.components)} in {model.geometry.dim}-D (use initiation: oracle)")
        require(self.min_pairs <= model.n_pairs, f"min_pairs ({self.min_pairs}) is more than the {model.n_pairs} pairs: "
                                                 "no track could ever start")

    def fixes(self, z: torch.Tensor, model: MeasurementModel, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Position fixes of detections ``z (B, S, M, d)`` (pair ``s`` measured by ``model``'s pair
        ``s``; states of dimension ``n``): positions ``(B, S, M, 2)``, covariances
        ``(B, S, M, 2, 2)`` and ``ok (B, S, M)`` (a fix exists: range beyond the baseline,
        finite, ``H`` invertible)."""
        comps = model.components
        pos, ok = range_azimuth_fix(z, model)
        # H = d(range, azimuth)/d(position) of each pair from the model's own Jacobian: every
        # pair's rows at every fix in one call, then pair s's rows at pair s's fixes
        pi = list(model.pos_idx)
        S = model.n_pairs
        state = pos.new_zeros(*pos.shape[:-1], n)
        state[..., pi] = pos
        J = model.jacobian(state).unflatten(-2, (S, len(comps)))  # (B, S, M, S, d, n)
        J = torch.diagonal(J, dim1=1, dim2=3).movedim(-1, 1)  # (B, S, M, d, n)
        H = J[..., [comps.index("range"), comps.index("azimuth")], :][..., pi]  # (B, S, M, 2, 2)
        sd = torch.tensor([model.noise_std[comps.index(c)] for c in ("range", "azimuth")], dtype=z.dtype, device=z.device)
        det = H[..., 0, 0] * H[..., 1, 1] - H[..., 0, 1] * H[..., 1, 0]
        # the two gradients nearly parallel (the sine of their angle below 1e-6): no fix along it
        ok = ok & (det.abs() > 1e-6 * H[..., 0, :].norm(dim=-1) * H[..., 1, :].norm(dim=-1))
        H = torch.where(ok[..., None, None], H, torch.eye(2, dtype=z.dtype, device=z.device))
        Hinv = torch.linalg.inv(H)
        cov = Hinv @ torch.diag(sd**2) @ Hinv.transpose(-1, -2)
        if self.covariance == "unscented":  # where a sigma point has no fix, the linearised one
            spread, fine = fix_spread(z, model, pos)
            cov = torch.where((ok & fine)[..., None, None], spread, cov)
        return pos, cov, ok

    def groups(self, pos: torch.Tensor, cov: torch.Tensor, ok: torch.Tensor,
               lists: torch.Tensor | None = None) -> torch.Tensor:
        """Groups of agreeing fixes ``(B, G, S)`` int64: the detection of each pair in the group
        (-1: none), ``G`` groups of ``>= min_pairs`` pairs, padded with all -1 rows.

        Anchored greedily, batched over runs: for each pair ``a`` in turn, every unused fix of
        ``a`` takes, from each later pair, the nearest unused fix it agrees with; where two anchors
        want the same fix the nearer keeps it (the other goes without). A detection is used once.

        ``lists (S,)``: the list each pair's fixes were computed from (None: a list per pair).
        Where pairs share a list (a receiver's pooled detections, every pair of it a hypothesis
        for each), every detection is also fixed under the wrong transmitters: those ghost fixes
        lie on the same receiver ray as the true one, where one anchor fix (long across the ray)
        often agrees with them. So there a later pair's fix must agree with every member so far
        and the nearest is the one with the smallest summed distance to them (a fused fix would
        be tighter still, but the fixes' linearised covariances ignore the ellipses' curvature,
        hundreds of metres over a fix's length, and it would turn true members away); a group
        takes a detection under one pair only, and anchored groups that share a detection under
        different pairs keep the one with more pairs (then the smaller summed distance, then the
        lower anchor): the others start nothing this scan, their detections stay free for the
        later anchors.
        """
        B, S, M = ok.shape
        dev = ok.device
        src = torch.arange(S, device=dev) if lists is None else lists
        shared = len(set(src.tolist())) < S
        gamma = gate_threshold(self.gate_probability, 2)
        free = torch.ones(B, int(src.max()) + 1, M, dtype=torch.bool, device=dev)  # per list: not in an accepted group
        rows = []
        ar = torch.arange(M, device=dev)
        dist = {}  # (c, b): squared distances (B, M, M) of pair c's fixes to pair b's

        def d2_of(c: int, b: int) -> torch.Tensor:
            if (c, b) not in dist:
                diff = pos[:, c, :, None] - pos[:, b, None, :]  # (B, M, M, 2)
                both = cov[:, c, :, None] + cov[:, b, None, :]
                dist[c, b] = mahalanobis(diff, both)
            return dist[c, b]

        for a in range(S):
            usable = ok & free[:, src]  # (B, S, M)
            members = torch.full((B, M, S), -1, dtype=torch.int64, device=dev)
            members[..., a] = torch.where(usable[:, a], ar, torch.full_like(ar, -1))
            spread = torch.zeros(B, M, dtype=pos.dtype, device=dev)  # summed distance of the members to the group
            for b in range(a + 1, S):
                d2 = d2_of(a, b)
                agree = inside_gate(d2, gamma) & usable[:, a, :, None] & usable[:, b, None, :]
                if shared:
                    for c in range(a + 1, b):  # every member so far, not the anchor alone
                        m_c = members[..., c]
                        row = d2_of(c, b).gather(1, m_c.clamp(min=0)[..., None].expand(B, M, M))
                        has_c = (m_c >= 0)[..., None]
                        agree &= ~has_c | inside_gate(row, gamma)
                        d2 = d2 + torch.where(has_c, row, torch.zeros((), dtype=d2.dtype, device=dev))
                    for c in range(a, b):  # a detection of b's list already in the group under another pair
                        if src[c] == src[b]:
                            agree &= members[..., c, None] != ar
                d2 = torch.where(agree, d2, torch.full_like(d2, math.inf))
                best_d, best = d2.min(-1)  # (B, M): each anchor's nearest agreeing fix of pair b
                has = torch.isfinite(best_d)
                # one anchor per fix of pair b: the nearest of those that chose it
                claim = torch.full((B, M), math.inf, dtype=d2.dtype, device=dev).scatter_reduce(
                    1, best, torch.where(has, best_d, torch.full_like(best_d, math.inf)), "amin")
                keep = has & (best_d <= claim.gather(1, best))
                # exact ties: the lowest anchor index keeps the fix
                first = torch.full((B, M), M, dtype=torch.int64, device=dev).scatter_reduce(
                    1, best, torch.where(keep, ar.expand(B, M), torch.full_like(best, M)), "amin")
                keep = keep & (first.gather(1, best) == ar)
                members[..., b] = torch.where(keep, best, torch.full_like(best, -1))
                spread = spread + torch.where(keep, best_d, torch.zeros_like(best_d))
            good = (members >= 0).sum(-1) >= self.min_pairs
            if shared:
                good = good & ~_outranked(members, good, spread, src, free.shape[1])
            members = torch.where(good[..., None], members, torch.full_like(members, -1))
            for b in range(a, S):  # mark what the accepted groups used
                idx = members[..., b]
                used = torch.zeros(B, M + 1, dtype=torch.bool, device=dev).scatter(
                    1, torch.where(idx >= 0, idx, M), True)[:, :M]
                free[:, src[b]] &= ~used
            rows.append(members)
        out = torch.cat(rows, 1)  # (B, S*M, S)
        real = (out >= 0).any(-1)
        G = int(real.sum(-1).max()) if real.numel() else 0
        order = torch.argsort((~real).to(torch.int8), dim=1, stable=True)[:, :G]
        return out.gather(1, order[..., None].expand(B, G, S))

    def states(self, z: torch.Tensor, groups: torch.Tensor, pos: torch.Tensor, cov: torch.Tensor, model: MeasurementModel,
               n: int, other_sd: torch.Tensor) -> tuple[Gaussian, torch.Tensor]:
        """Initial Gaussians ``(B, G, n)`` of ``groups (B, G, S)`` (see the class docstring) and
        which groups are real ``(B, G)``."""
        B, G, S = groups.shape
        real = (groups >= 0).any(-1)
        has = groups >= 0  # (B, G, S)
        idx = groups.clamp(min=0)
        take = lambda t: t.gather(2, idx.transpose(1, 2)[(...,) + (None,) * (t.dim() - 3)].expand(
            B, S, G, *t.shape[3:])).transpose(1, 2)  # (B, S, M, ...) -> (B, G, S, ...)
        p_i, P_i, z_i = take(pos), take(cov), take(z)
        eye2 = torch.eye(2, dtype=z.dtype, device=z.device)
        info = torch.where(has[..., None, None], torch.linalg.inv(torch.where(has[..., None, None], P_i, eye2)),
                           torch.zeros((), dtype=z.dtype, device=z.device))
        Pp = torch.linalg.inv(info.sum(2) + torch.where(real, 0.0, 1.0)[..., None, None] * eye2)
        p = (Pp @ (info @ p_i.unsqueeze(-1)).sum(2)).squeeze(-1)  # (B, G, 2)
        x = z.new_zeros(B, G, n)
        pi, vi = list(model.pos_idx), list(model.vel_idx)
        x[..., pi] = p
        prec = torch.eye(2, dtype=z.dtype, device=z.device) / self.velocity_sd_mps**2
        x[..., vi], Pv = velocity_fit(model, x, z_i, has, prec)
        P = torch.diag_embed(other_sd.to(z.dtype) ** 2).expand(B, G, n, n).clone()
        P[..., pi, :] = 0.0
        P[..., :, pi] = 0.0
        P[..., vi, :] = 0.0
        P[..., :, vi] = 0.0
        ti, tv = torch.tensor(pi, device=z.device), torch.tensor(vi, device=z.device)
        P[..., ti[:, None], ti] = Pp
        P[..., tv[:, None], tv] = Pv
        return Gaussian(x, P), real

    def initiate(self, z: torch.Tensor, unused: torch.Tensor, model: MeasurementModel, n: int,
                 other_sd: torch.Tensor, routes: torch.Tensor | None = None) -> tuple[Gaussian, torch.Tensor]:
        """Tentative tracks ``(B, G, n)`` and which are real ``(B, G)`` from the detections
        ``z (B, L, M, d)`` marked ``unused (B, L, M)``. ``routes (L, S)`` bool: list ``l`` holds
        pair ``s``'s detections (None: one list per pair, ``L = S``); a receiver's pooled list
        (a single-frequency network: the illuminator of a detection unknown) is read under
        every pair ending there, each detection fixed once per illuminator hypothesis, and a
        track takes a detection under one hypothesis only (:meth:`groups`)."""
        src = None if routes is None else list_of_pairs(routes)
        if src is not None and torch.equal(src, torch.arange(len(src), device=src.device)):
            src = None  # one list per pair
        zp = z if src is None else z[:, src]
        pos, cov, ok = self.fixes(zp, model, n)
        groups = self.groups(pos, cov, ok & (unused if src is None else unused[:, src]), src)
        if src is not None:
            groups = self.consistent(groups, zp, pos, cov, model, n)
        return self.states(zp, groups, pos, cov, model, n, other_sd)

    def consistent(self, groups: torch.Tensor, z: torch.Tensor, pos: torch.Tensor, cov: torch.Tensor,
                   model: MeasurementModel, n: int, iterations: int = 3) -> torch.Tensor:
        """``groups (B, G, S)`` without the members whose (bistatic range, azimuth) the group's
        position does not explain: the position that best explains every member (``iterations``
        Gauss-Newton steps from the fixes' information-weighted mean, weighted by ``R``) must
        leave a sum of squared normalised residuals within the chi-square gate
        ``gate_probability`` (``2 k - 2`` degrees of freedom for ``k`` members); otherwise the
        member with the largest residual leaves and the rest is fitted again. A group left with
        fewer than ``min_pairs`` members starts nothing.

        Pooled lists need it: two drones 300 m apart in formation give fixes long enough across
        the ray to agree (:meth:`groups`), and a group of one drone's detections at five pairs and
        the other's at the sixth is 300 m wrong in one range, ten deviations. ``z (B, S, M, d)``,
        ``pos``, ``cov``: as :meth:`fixes` gives them."""
        B, G, S = groups.shape
        if G == 0:
            return groups
        comps = model.components
        rows = [comps.index("range"), comps.index("azimuth")]
        sd = torch.tensor([model.noise_std[i] for i in rows], dtype=z.dtype, device=z.device)
        has = groups >= 0
        idx = groups.clamp(min=0)
        take = lambda t: t.gather(2, idx.transpose(1, 2)[(...,) + (None,) * (t.dim() - 3)].expand(
            B, S, G, *t.shape[3:])).transpose(1, 2)  # (B, S, M, ...) -> (B, G, S, ...)
        zm, pm, Pm = take(z)[..., rows], take(pos), take(cov)
        gates = torch.tensor([math.inf] + [gate_threshold(self.gate_probability, 2 * k - 2) for k in range(2, S + 1)],
                             dtype=z.dtype, device=z.device)  # by member count; one member: nothing to test
        pi = list(model.pos_idx)
        eye = torch.eye(2, dtype=z.dtype, device=z.device)
        for _ in range(S):  # at most one member leaves per round
            info = torch.where(has[..., None, None], torch.linalg.inv(torch.where(has[..., None, None], Pm, eye)), 0.0)
            p = torch.linalg.solve(info.sum(2) + eye * 1e-12, (info @ pm.unsqueeze(-1)).sum(2)).squeeze(-1)  # (B, G, 2)
            for _ in range(iterations):
                x = z.new_zeros(B, G, n)
                x[..., pi] = p
                r, J = _residuals(model, x, zm, sd, rows, pi)  # (B, G, S, 2), (B, G, S, 2, 2)
                w = has[..., None, None].to(z.dtype)
                A = (w * J.transpose(-1, -2) @ J).sum(2) + eye * 1e-12
                p = p + torch.linalg.solve(A, (w * J.transpose(-1, -2) @ r.unsqueeze(-1)).sum(2)).squeeze(-1)
            x = z.new_zeros(B, G, n)
            x[..., pi] = p
            e = (_residuals(model, x, zm, sd, rows, pi)[0] ** 2).sum(-1)  # (B, G, S)
            count = has.sum(-1)
            bad = (torch.where(has, e, 0.0).sum(-1) > gates[(count - 1).clamp(min=0)]) & (count > 1)
            if not bool(bad.any()):
                break
            worst = torch.where(has, e, -math.inf).argmax(-1, keepdim=True)  # (B, G, 1)
            has = has & ~(bad[..., None] & (torch.arange(S, device=worst.device) == worst))
        has = has & (has.sum(-1, keepdim=True) >= self.min_pairs)
        return torch.where(has, groups, torch.full_like(groups, -1))


def _residuals(model: MeasurementModel, x: torch.Tensor, z: torch.Tensor, sd: torch.Tensor, rows: list[int],
               pi: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised residuals ``(B, G, S, 2)`` of (range, azimuth) ``z (B, G, S, 2)`` at states
    ``x (B, G, n)`` under every pair of ``model`` (pair layout; deviations ``sd (2,)``) and their
    Jacobians by position ``(B, G, S, 2, 2)``; azimuth residuals wrapped to (-pi, pi]."""
    S = model.n_pairs
    h = model.h(x).unflatten(-1, (S, -1))[..., rows]  # (B, G, S, 2)
    J = model.jacobian(x).unflatten(-2, (S, -1))[..., rows, :][..., pi]  # (B, G, S, 2, 2)
    d = z - h
    d = torch.stack([d[..., 0], wrap_angle(d[..., 1])], -1)
    return d / sd, J / sd[:, None]


def list_of_pairs(routes: torch.Tensor) -> torch.Tensor:
    """``(S,)`` int64: the list of each pair, from ``routes (L, S)`` bool (exactly one list per pair)."""
    if routes.dim() != 2 or not bool((routes.sum(0) == 1).all()):
        raise ConfigError(f"routes must name exactly one list per pair; got shape {tuple(routes.shape)} with "
                          f"{routes.sum(0).tolist()} lists per pair")
    return routes.to(torch.int64).argmax(0)


def _outranked(members: torch.Tensor, good: torch.Tensor, spread: torch.Tensor, src: torch.Tensor,
               L: int) -> torch.Tensor:
    """``(B, R)`` bool: group rows ``members (B, R, S)`` (detection per pair, -1 none; ``good``
    rows compete) that share a detection of some list (pair ``s`` reads list ``src[s]``) with a
    good row ranked above them: more pairs, then a smaller ``spread``, then a lower row."""
    B, R, S = members.shape
    M = R
    slot = torch.where(members >= 0, src * M + members, L * M)  # the detection's place over all lists
    used = torch.zeros(B, R, L * M + 1, device=members.device).scatter_(2, slot, 1.0)[..., :L * M] * good[..., None]
    clash = (used @ used.transpose(1, 2)) > 0  # (B, R, R)
    size = (members >= 0).sum(-1)
    r = torch.arange(R, device=members.device)
    above = ((size[:, :, None] > size[:, None, :])
             | ((size[:, :, None] == size[:, None, :]) & (spread[:, :, None] < spread[:, None, :]))
             | ((size[:, :, None] == size[:, None, :]) & (spread[:, :, None] == spread[:, None, :])
                & (r[:, None] < r[None, :])))  # (B, i, j): row i ranks above row j
    return (clash & above & ~torch.eye(R, dtype=torch.bool, device=members.device)).any(1)
