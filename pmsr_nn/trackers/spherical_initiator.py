"""Tentative tracks from bistatic range and range-rate (or Doppler) detections, without azimuth
(:class:`SphericalInitiator`, one of the initiators of :mod:`.initiators`): every combination
of one detection per pair is fitted and gated, the best consistent ones start tracks.

Shapes: ``B`` runs, ``S`` pairs, ``M`` detections per list, ``d`` components per pair, ``n``
state dimension, ``G`` tracks started, ``D`` spatial dimension, ``n_comb`` combinations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.gaussian import Gaussian
from ..measurements import MeasurementModel
from .gating import gate_threshold, inside_gate
from .initiators import rate_component, velocity_fit


MAX_SPHERICAL_PAIRS = 4
"""Most pairs :class:`SphericalInitiator` takes: it tries ``M^S`` combinations per run and scan
(``M`` unused detections per pair), 54^4 = 8.5 million with the Access study's clutter; a fifth
pair would make that 460 million."""

SPHERICAL_CHUNK = 1 << 16
"""Combinations (all runs together) :class:`SphericalInitiator` works on at once: bounds its
memory to a few tens of MB whatever the clutter."""

MAX_CANDIDATES = 1024
"""Most combinations a run's scan gives where the selection is not exclusive (the best first)."""

RANGE_STEPS = 3
"""Gauss-Newton steps on the ranges from the spherical-interpolation solution (on the Access
geometry at 1 km range noise the range chi-square has converged to 1e-5 after two)."""

JOINT_STEPS = 3
"""Gauss-Newton steps on ranges and rates together from the range fix and the rate fit there (on
the Access geometry the joint chi-square then agrees with ten steps' to 1e-7, the position to
0.1 m at 1 km range noise)."""


def _solve(A: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``A^-1 y`` ``(n_comb, a)`` for ``A (n_comb, a, a)``, and where that is a finite solve
    ``(n_comb,)``."""
    x, info = torch.linalg.solve_ex(A, y.unsqueeze(-1))
    x = x.squeeze(-1)
    ok = (info == 0) & torch.isfinite(x).all(-1)
    return torch.where(ok.unsqueeze(-1), x, x.new_zeros(())), ok


def _range_fix(rho: torch.Tensor, w: torch.Tensor, o: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The range-only ML fixes of ``n_comb`` combinations, in a working frame: the shared sensor
    at the origin, lengths in units of the longest baseline (numbers near 1). ``rho (n_comb, S)``
    bistatic ranges and ``w (n_comb, S)`` 1 where the pair takes part (else 0), ``o (S, 2)``
    each pair's other sensor. Returns positions ``(n_comb, 2)``, the sum of squared range
    residuals ``(n_comb,)`` (working units) and ``ok (n_comb,)`` (finite: the linear systems were
    regular).

    Spherical interpolation (:class:`SphericalInitiator`, step 1; with the shared sensor at the
    origin the rows are ``(-o_s, rho_s) . (p, D) = (rho_s^2 - |o_s|^2) / 2``), then
    :data:`RANGE_STEPS` Gauss-Newton steps on ``rho_s = |p - o_s| + |p|``. Written out on the
    coordinates, with explicit 3x3 and 2x2 solves, not through the model's ``h`` and
    ``jacobian`` nor :mod:`pmsr_nn.filters.spherical` (whose conditioning checks are batched
    eigen-decompositions): this runs on every combination, millions per scan, and this way costs
    a fifth of the model's general code. The model's own ``h`` and ``jacobian`` take over from the survivors on.
    """
    # pairs first, (S, n_comb): the sums over pairs are then sums of contiguous rows (fast), not
    # reductions over a trailing axis of 3 or 4
    rho, w = rho.T.contiguous(), w.T.contiguous()
    ox, oy = o[:, 0, None], o[:, 1, None]  # (S, 1)
    rhs = 0.5 * (rho * rho - (ox * ox + oy * oy))
    s = lambda a: (w * a).sum(0)  # noqa: E731
    # normal equations of the rows (-ox, -oy, rho) . (p, D) = rhs, solved by the adjugate
    n00, n01, n11 = s(ox * ox), s(ox * oy), s(oy * oy)
    n02, n12, n22 = -s(ox * rho), -s(oy * rho), s(rho * rho)
    y0, y1, y2 = -s(ox * rhs), -s(oy * rhs), s(rho * rhs)
    c00, c01, c02 = n11 * n22 - n12 * n12, n02 * n12 - n01 * n22, n01 * n12 - n02 * n11
    c11, c12 = n00 * n22 - n02 * n02, n01 * n02 - n00 * n12
    det = n00 * c00 + n01 * c01 + n02 * c02
    px = (c00 * y0 + c01 * y1 + c02 * y2) / det
    py = (c01 * y0 + c11 * y1 + c12 * y2) / det
    for step in range(RANGE_STEPS + 1):
        dx, dy = px - ox, py - oy  # (S, n_comb)
        d_o = (dx * dx + dy * dy).sqrt()
        d_c = (px * px + py * py).sqrt()
        res = rho - d_o - d_c
        if step == RANGE_STEPS:
            break
        jx, jy = dx / d_o + px / d_c, dy / d_o + py / d_c  # the gradient u_o + u_c
        a, b, c = s(jx * jx), s(jx * jy), s(jy * jy)
        gx, gy = s(jx * res), s(jy * res)
        det = a * c - b * b
        px, py = px + (c * gx - b * gy) / det, py + (a * gy - b * gx) / det
    chi2 = s(res * res)
    ok = torch.isfinite(px) & torch.isfinite(py) & torch.isfinite(chi2)
    return torch.stack([px, py], -1), chi2, ok


@dataclass(frozen=True)
class SphericalInitiator:
    """Tentative tracks from detections of bistatic range and range-rate (or Doppler), without
    azimuth, in 2-D, at ``S`` pairs that share one receiver (several transmitters: the IEEE
    Access 2019 study) or one transmitter (several receivers). No single detection fixes a
    position, so every combination of one unused detection per pair (from ``min_pairs`` of the
    pairs, default every pair; at least 3) is tried as a target.

    A combination of ``k`` pairs, with the shared sensor ``c`` and pair ``s``'s other sensor
    ``o_s`` (the bistatic range is symmetric in transmitter and receiver, so
    ``rho_s = |p - o_s| + |p - c|`` either way):

    1. spherical interpolation (as :mod:`pmsr_nn.filters.spherical`, roles swapped where the
       receiver is shared): with ``D = |p - c|``, ``|p - o_s| = rho_s - D``; squaring and
       subtracting ``D^2 = |p - c|^2`` leaves ``(c - o_s) . p + rho_s D = (rho_s^2 + |c|^2 - |o_s|^2) / 2``,
       linear in ``(p, D)`` with ``D`` left free: solved exactly for ``k = 3``, by least squares
       beyond;
    2. :data:`RANGE_STEPS` Gauss-Newton steps on the ranges (written out on the coordinates,
       see :func:`_range_fix`): the range-only maximum-likelihood fix. Its range chi-square (``k - 2`` degrees of freedom)
       is a lower bound of the joint chi-square of step 4 (which minimises the same range terms
       plus the rate terms), so a combination whose range chi-square is already beyond the gate
       is dropped here: most clutter combinations stop after this cheap part;
    3. the rates' velocity fit at that position (:func:`~.initiators.velocity_fit`, as
       :class:`~.fix_initiator.FixInitiator`), then :data:`JOINT_STEPS` Gauss-Newton steps on
       ranges and rates together in (position, velocity): the joint maximum-likelihood
       estimate. Joint because a rate depends on the position as well (by about
       ``|v| / |p - s|``, 0.01 (m/s)/m at 300 m/s and 30 km): on the Access geometry the
       range-only fix is ~600 m off per axis, and a rate fit there leaves rate residuals of
       several deviations (of true combinations, 0.82 passed a 0.9 gate and 0.992 a 0.999 one);
    4. consistency: the chi-square of the range and rate residuals at the joint estimate
       (``k - 2`` degrees of freedom each, ``2 k - 4`` in all) within
       ``gate_threshold(gate_probability, 2 k - 4)``;
    5. greedy selection, per run: of the consistent combinations, one with the most pairs and
       among those the smallest chi-square tail probability (the smallest chi-square when all
       have ``k`` pairs) starts a track, every combination that shares a detection with it is
       dropped, and so on until none is left: each detection starts at most one track. With
       ``exclusive=False`` (what the multi-scan initiator reads, :mod:`.multi_scan_initiator`)
       every consistent combination is kept instead, the best :data:`MAX_CANDIDATES` a run, in
       that order.

    A track's Gaussian: the joint estimate and the inverse of its Fisher information
    ``J^T R^-1 J`` (``J`` the model's Jacobian of the ranges and rates by position and
    velocity, at the estimate: the Cramer-Rao bound), combined with the prior
    ``N(0, velocity_sd_mps^2)`` per velocity axis as :class:`~.fix_initiator.FixInitiator`'s; other state
    entries (e.g. acceleration) start at 0 with deviations ``other_sd``.

    Cost: ``M^S`` combinations per run and scan (``(M + 1)^S`` where ``min_pairs < S``), in
    chunks of :data:`SPHERICAL_CHUNK`; :meth:`check` refuses more than
    :data:`MAX_SPHERICAL_PAIRS` pairs.
    """

    velocity_sd_mps: float = 20.0
    min_pairs: int | None = None
    gate_probability: float = 0.999
    exclusive: bool = True

    def __post_init__(self) -> None:
        require(self.velocity_sd_mps > 0 and math.isfinite(self.velocity_sd_mps),
                f"the initiator's velocity deviation must be positive, got {self.velocity_sd_mps}")
        require(self.min_pairs is None or self.min_pairs >= 3,
                f"initiation from range and range-rate needs min_pairs >= 3 (two ranges fix a position with nothing "
                f"left to check it), got {self.min_pairs}")
        require(0.5 <= self.gate_probability < 1.0, f"gate probability must be in [0.5, 1), got {self.gate_probability}")

    def check(self, model: MeasurementModel, what: str = "initiation from detections") -> None:
        """One-line refusal of a model this initiator can not start tracks from."""
        comps, g, S = model.components, model.geometry, model.n_pairs
        if "range" not in comps or rate_component(model) is None or g.dim != 2:
            raise ConfigError(f"{what} fixes positions from (bistatic range, azimuth) in 2-D, or from bistatic range and "
                              f"range-rate (or Doppler) at 3 to {MAX_SPHERICAL_PAIRS} pairs in 2-D; the detections "
                              f"measure {list(comps)} in {g.dim}-D (use initiation: oracle)")
        n_tx, n_rx = len({i for i, _ in g.pairs}), len({j for _, j in g.pairs})
        if n_tx > 1 and n_rx > 1:
            raise ConfigError(f"{what} from range and range-rate needs pairs that share one transmitter or one receiver "
                              f"(spherical interpolation); the {S} pairs use {n_tx} transmitters and {n_rx} receivers "
                              "(use initiation: oracle)")
        if not 3 <= S <= MAX_SPHERICAL_PAIRS:
            raise ConfigError(f"{what} from range and range-rate tries every combination of one detection per pair "
                              f"(M^S per scan), which needs 3 to {MAX_SPHERICAL_PAIRS} pairs; the geometry has {S} "
                              "(use initiation: oracle)")
        require(self.pairs_needed(model) <= S, f"min_pairs ({self.min_pairs}) is more than the {S} pairs: no track "
                                               "could ever start")
        c, others = self._sensors(model, torch.float64, torch.device("cpu"))  # device: the geometry's rank, a check
        if int(torch.linalg.matrix_rank(others - c)) < 2:
            raise ConfigError(f"{what} from range and range-rate: the pairs' other sensors lie on one line through the "
                              "shared one, so a position and its mirror image give the same ranges (use initiation: "
                              "oracle)")

    def begin(self, B: int, F: torch.Tensor | None = None, Q: torch.Tensor | None = None) -> None:
        """A single-scan initiator keeps nothing across scans."""

    def pairs_needed(self, model: MeasurementModel) -> int:
        """The fewest pairs of a combination: ``min_pairs``, or every pair."""
        return model.n_pairs if self.min_pairs is None else self.min_pairs

    @staticmethod
    def _sensors(model: MeasurementModel, dtype, device=None) -> tuple[torch.Tensor, torch.Tensor]:
        """The shared sensor ``(2,)`` and each pair's other one ``(S, 2)``, in m, on ``device``."""
        tx, rx = model.geometry.pair_tx_positions(dtype, device), model.geometry.pair_rx_positions(dtype, device)
        if bool((tx == tx[0]).all()):
            return tx[0], rx
        return rx[0], tx

    def _fit(self, zq: torch.Tensor, has: torch.Tensor, model: MeasurementModel, n: int):
        """Steps 1-4 of the class docstring on ``n_comb`` combinations: detections
        ``zq (n_comb, S, d)`` (pair ``s``'s used where ``has (n_comb, S)``). Returns
        ``passed (n_comb,)``, the chi-square ``(n_comb,)``, the joint estimates
        ``theta (n_comb, 2D)`` (position m, velocity m/s) and their Fisher information
        ``(n_comb, 2D, 2D)``."""
        comps = model.components
        cr, cv = comps.index("range"), rate_component(model)
        sd_r, sd_v = model.noise_std[cr], model.noise_std[cv]
        dtype, dev = zq.dtype, zq.device
        n_comb, S = has.shape
        k = has.sum(-1)
        gamma = torch.tensor([math.inf] * 3 + [gate_threshold(self.gate_probability, 2 * j - 4)
                                               for j in range(3, S + 1)], dtype=dtype, device=dev)[k]
        w = has.to(dtype)
        rho = torch.where(has, zq[..., cr], zq.new_zeros(()))
        rates = torch.where(has, zq[..., cv], zq.new_zeros(()))
        pi, vi = list(model.pos_idx), list(model.vel_idx)
        # 1-2. the range-only ML fix (working frame: see _range_fix); its range chi-square
        # bounds the joint one from below, so most clutter combinations stop here
        c, others = self._sensors(model, dtype, dev)
        scale = float((others - c).norm(dim=-1).max())
        p, chi2_r, ok = _range_fix(rho / scale, w, (others - c) / scale)
        chi2_r = chi2_r * (scale / sd_r) ** 2
        keep = torch.nonzero(ok & inside_gate(chi2_r, gamma)).squeeze(-1)
        x = zq.new_zeros(len(keep), n)
        x[:, pi] = c + scale * p[keep]
        # 3. the joint ML estimate of the survivors, from the rates' velocity fit at the range fix
        w, rho, rates, gamma, has, zq = (t[keep] for t in (w, rho, rates, gamma, has, zq))
        prec = torch.eye(len(vi), dtype=dtype, device=dev) / self.velocity_sd_mps**2
        x[:, vi] = velocity_fit(model, x, zq, has, prec)[0]
        labels = model.labels
        rows = [labels.index(f"range_{s + 1}") for s in range(S)] + [labels.index(f"{comps[cv]}_{s + 1}")
                                                                       for s in range(S)]
        idx = pi + vi
        zr = torch.cat([rho, rates], -1)  # (q, 2S)
        wr = torch.cat([w / sd_r**2, w / sd_v**2], -1)
        ok = torch.ones(len(keep), dtype=torch.bool, device=dev)
        for _ in range(JOINT_STEPS):
            J = model.jacobian(x)[:, rows][..., idx]  # (q, 2S, 2D)
            step, good = _solve(torch.einsum("qra,qr,qrb->qab", J, wr, J),
                                torch.einsum("qra,qr->qa", J, wr * (zr - model.h(x)[:, rows])))
            x[:, idx] = x[:, idx] + step
            ok = ok & good
        # 4. the joint chi-square and the Fisher information at the estimate
        chi2 = (wr * (zr - model.h(x)[:, rows]) ** 2).sum(-1)
        J = model.jacobian(x)[:, rows][..., idx]
        info = torch.einsum("qra,qr,qrb->qab", J, wr, J)
        ok = ok & torch.isfinite(chi2) & (torch.linalg.cholesky_ex(info).info == 0) & inside_gate(chi2, gamma)
        passed = torch.zeros(n_comb, dtype=torch.bool, device=dev)
        passed[keep] = ok
        full = lambda t, fill: torch.full((n_comb, *t.shape[1:]), fill, dtype=t.dtype, device=dev).index_copy_(0, keep, t)
        return passed, full(chi2, math.nan), full(x[:, idx], math.nan), full(info, 0.0)

    def select(self, z: torch.Tensor, unused: torch.Tensor, model: MeasurementModel, n: int):
        """The combinations that start tracks from detections ``z (B, S, M, d)`` marked
        ``unused (B, S, M)`` (states of dimension ``n``): ``combos (B, G, S)`` int64, the
        detection of each pair (-1: none; padding rows all -1), their chi-square ``(B, G)``, the
        joint estimates ``theta (B, G, 2D)`` (position m, velocity m/s) and Fisher information
        ``(B, G, 2D, 2D)`` (class docstring), in the order the greedy selection took them."""
        B, S, M, d = z.shape
        work, dev = torch.float64, z.device
        D = len(model.pos_idx)
        kmin = self.pairs_needed(model)
        ok = unused & torch.isfinite(z).all(-1)
        count = ok.sum(-1)  # (B, S)
        # the unused detections first in each list: combinations of list entries below the counts
        order = torch.argsort((~ok).to(torch.int8), dim=-1, stable=True)
        Mu = int(count.max()) if count.numel() else 0
        L = Mu + (1 if kmin < S else 0)  # entry Mu: the pair takes no part
        zz = z.gather(2, order[..., None].expand(B, S, M, d))[:, :, :Mu].to(work)
        per = max(1, SPHERICAL_CHUNK // max(B, 1))
        radix = L ** torch.arange(S - 1, -1, -1, device=dev)
        pairs = torch.arange(S, device=dev)
        found = []
        for f0 in range(0, L**S if Mu else 0, per):
            digit = (torch.arange(f0, min(L**S, f0 + per), device=dev)[:, None] // radix) % L  # (C, S)
            has = digit < count[:, None, :]  # (B, C, S)
            real = (has | (digit == Mu)).all(-1) & (has.sum(-1) >= kmin)
            b, ci = torch.nonzero(real, as_tuple=True)
            if not len(b):
                continue
            dq, hq = digit[ci], has[b, ci]
            zq = zz[b[:, None], pairs, dq.clamp(max=Mu - 1)]  # (n_comb, S, d)
            passed, chi2, theta, info = self._fit(zq, hq, model, n)
            det = torch.where(hq, order[b[:, None], pairs, dq.clamp(max=Mu - 1)], -1)
            found.append((b[passed], det[passed], hq[passed].sum(-1), chi2[passed], theta[passed], info[passed]))
        if found:
            b, det, k, chi2, theta, info = (torch.cat(t) for t in zip(*found))
        else:
            b, det, k = (torch.zeros(0, *shape, dtype=torch.int64, device=dev) for shape in ((), (S,), ()))
            chi2, theta, info = (torch.zeros(0, *shape, dtype=work, device=dev) for shape in ((), (2 * D,), (2 * D, 2 * D)))
        # per run, padded to (B, n_found): key +inf on padding
        per_run = torch.bincount(b, minlength=B)
        n_found = int(per_run.max()) if len(b) else 0
        srt = torch.argsort(b, stable=True)
        b, det, k, chi2, theta, info = b[srt], det[srt], k[srt], chi2[srt], theta[srt], info[srt]
        slot = torch.arange(len(b), device=dev) - (per_run.cumsum(0) - per_run)[b]
        key = torch.full((B, n_found), math.inf, dtype=work, device=dev)
        # more pairs first, then the chi-square tail probability (in [0, 1): the dof may differ)
        key[b, slot] = (S - k).to(work) + torch.special.gammainc(k.to(work) - 2.0, chi2 / 2.0)
        combos = torch.full((B, n_found, S), -1, dtype=torch.int64, device=dev)
        combos[b, slot] = det
        chi2_p = torch.full((B, n_found), math.nan, dtype=work, device=dev)
        chi2_p[b, slot] = chi2
        theta_p = torch.zeros(B, n_found, 2 * D, dtype=work, device=dev)
        theta_p[b, slot] = theta
        info_p = torch.eye(2 * D, dtype=work, device=dev).repeat(B, n_found, 1, 1)
        info_p[b, slot] = info
        # 5. greedy, batched over runs: each round every run takes its best combination left and
        # drops every combination that shares a detection with it (that one included); or, not
        # exclusive, every consistent combination, the best MAX_CANDIDATES a run
        taken = []
        if not self.exclusive and n_found:
            G = min(n_found, MAX_CANDIDATES)
            best_key, best = key.topk(G, 1, largest=False)  # (B, G), ascending
            taken = list(torch.where(torch.isfinite(best_key), best, n_found).unbind(1))
        while n_found and self.exclusive:
            best_key, best = key.min(1)
            go = torch.isfinite(best_key)
            if not bool(go.any()):
                break
            pick = combos.gather(1, best[:, None, None].expand(B, 1, S))  # (B, 1, S)
            clash = ((combos == pick) & (pick >= 0)).any(-1) & go[:, None]
            key = torch.where(clash, math.inf, key)
            taken.append(torch.where(go, best, n_found))
        G = len(taken)
        # column n_found: an all -1 padding row
        t = torch.stack(taken, 1) if G else torch.zeros(B, 0, dtype=torch.int64, device=dev)  # (B, G)
        pad = lambda x, fill: torch.cat([x, torch.full((B, 1, *x.shape[2:]), fill, dtype=x.dtype, device=dev)], 1)
        take = lambda x: x.gather(1, t[(...,) + (None,) * (x.dim() - 2)].expand(B, G, *x.shape[2:]))
        return (take(pad(combos, -1)), take(pad(chi2_p, math.nan)), take(pad(theta_p, 0.0)),
                take(torch.cat([info_p, torch.eye(2 * D, dtype=work, device=dev).expand(B, 1, 2 * D, 2 * D)], 1)))

    def initiate(self, z: torch.Tensor, unused: torch.Tensor, model: MeasurementModel, n: int,
                 other_sd: torch.Tensor) -> tuple[Gaussian, torch.Tensor]:
        """Tentative tracks ``(B, G, n)`` and which are real ``(B, G)`` from the detections
        ``z (B, S, M, d)`` marked ``unused (B, S, M)`` (class docstring)."""
        combos, _, theta, info = self.select(z, unused, model, n)
        B, G, S = combos.shape
        real = (combos >= 0).any(-1)
        D = len(model.pos_idx)
        # the Gaussian likelihood N(theta; ., info^-1) times the velocity prior N(0, sd^2 I)
        prior = torch.zeros(2 * D, 2 * D, dtype=info.dtype, device=info.device)
        prior[D:, D:] = torch.eye(D, dtype=info.dtype, device=info.device) / self.velocity_sd_mps**2
        P4 = torch.linalg.inv(info + prior)
        m4 = (P4 @ (info @ theta.unsqueeze(-1))).squeeze(-1)
        idx = torch.tensor(list(model.pos_idx) + list(model.vel_idx), device=z.device)
        x = z.new_zeros(B, G, n)
        x[..., idx] = m4.to(z.dtype)
        P = torch.diag_embed(other_sd.to(z.dtype) ** 2).expand(B, G, n, n).clone()
        P[..., idx, :] = 0.0
        P[..., :, idx] = 0.0
        P[..., idx[:, None], idx] = P4.to(z.dtype)
        return Gaussian(x, P), real
