"""Game-theoretic data association (GTDA): regret matching with a forgetting factor (Daniyan et
al., seed 003, Eqs. 5-8, after Hart & Mas-Colell 2000), batched over runs.

At one scan the *players* are the living tracks and the *strategies* the scan's unlabelled
estimates plus a null strategy (take none). The seed defers the utility to its earlier paper;
ours is stated here: a statistical distance and a feasibility term,

    u_p(n, s_-p) = -d2(p, n)  if estimate n is inside player p's gate, else -gate (1 + conflict);
    u_p(null)    = -gate;
    less conflict x gate when a player with a better claim on n (smaller d2) also plays it,

with ``d2`` the Mahalanobis distance of estimate ``n`` from track ``p``'s prediction. The
feasibility term falls on the farther claimant only: were both penalised, the game would be a
pure coordination game whose equilibria include giving an estimate to the farther of two tracks
(we measured such label switches between well-separated targets); with it, the pure equilibria
are the stable matchings of tracks and estimates (no track and estimate both prefer each other
to what they hold), which the regret dynamics reach. Players
start on their own best strategy and play ``iterations`` rounds of regret matching: the
conditional regret ``R_{p,l->n}`` of having played ``l`` instead of ``n`` is the average over
rounds (Eq. 6, weights ``lambda_f^(i - j)`` of round ``j``) of ``u_p(n, s_-p) - u_p(l, s_-p)``
over the rounds in which ``p`` played ``l``; a player switches from ``l`` to ``n`` with
probability ``max(R, 0) / alpha`` (Eq. 8) and decides by Eq. 7 at the end. The seed asks only
that ``alpha`` be large enough for every ``beta`` to stay positive; ours is ``alpha_scale`` (> 1)
times the player's summed positive regret in that round, so a player with any regret stays with
probability ``1 - 1 / alpha_scale`` (0.5 by default) and otherwise moves in proportion to its
regrets. (With a constant ``alpha`` bounding every possible regret sum, about 200 here, a
contested player moved with a few per cent per round: in evaluate/daniyan_smcphd.yaml's
baseline case 7.9 conflicts per run were still open after 50 rounds and had to be repaired.) Rounds stop early once no player of any run has a positive regret (a pure
equilibrium). The equilibrium is correlated, not always conflict-free: a conflict left after the
last round (the round limit reached first) is resolved for the player nearer the estimate, the
others take null (counted in ``GameResult.repaired``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import require
from .gating import inside_gate


@dataclass(frozen=True)
class GameSpec:
    """``forgetting`` ``lambda_f`` in (0, 1]; ``iterations`` rounds per scan at most; ``conflict``:
    the feasibility penalty in units of the gate; ``alpha_scale`` (> 1) of Eq. 8's ``alpha``."""

    forgetting: float = 0.9
    iterations: int = 50
    conflict: float = 1.0
    alpha_scale: float = 2.0

    def __post_init__(self) -> None:
        require(0 < self.forgetting <= 1 and math.isfinite(self.forgetting),
                f"the forgetting factor must be in (0, 1], got {self.forgetting}")
        require(self.iterations >= 1, f"iterations must be at least 1, got {self.iterations}")
        require(self.conflict > 0, f"conflict must be positive, got {self.conflict}")
        require(self.alpha_scale > 1 and math.isfinite(self.alpha_scale),
                f"alpha_scale must be a finite number above 1, got {self.alpha_scale}")


@dataclass
class GameResult:
    """``choice (B, P)``: the estimate each player takes (-1: none); ``rounds``: rounds played;
    ``repaired (B,)``: conflicts resolved after the last round."""

    choice: torch.Tensor
    rounds: int
    repaired: torch.Tensor


def utilities(d2: torch.Tensor, strategy_ok: torch.Tensor, gate: float, spec: GameSpec) -> torch.Tensor:
    """Own-distance utilities ``U (B, P, T + 1)`` (last column: null), before the conflict term."""
    B, P, T = d2.shape
    bad = -gate * (1 + spec.conflict)
    U = torch.where(strategy_ok[:, None, :] & inside_gate(d2, gate), -d2, d2.new_full((), bad))
    return torch.cat([U, d2.new_full((B, P, 1), -gate)], -1)


def _payoffs(U: torch.Tensor, s: torch.Tensor, player: torch.Tensor, penalty: float) -> torch.Tensor:
    """``u_p(n, s_-p) (B, P, T + 1)`` for every strategy ``n`` with the others' plays ``s (B, P)``:
    ``U`` less ``penalty`` where a player with a better claim (a larger ``U``, ties to the lower
    index) plays ``n`` (never for null)."""
    B, P, S = U.shape
    on = torch.nn.functional.one_hot(s, S).bool() & player[..., None]  # (B, Q, S): q plays n
    idx = torch.arange(P, device=U.device)
    better = (U[:, None, :, :] > U[:, :, None, :]) | ((U[:, None, :, :] == U[:, :, None, :])
                                                        & (idx[None, :, None] < idx[:, None, None]))  # (B, P, Q, S)
    blocked = (on[:, None, :, :] & better & (idx[:, None] != idx[None, :])[None, :, :, None]).any(2)
    blocked[..., -1] = False  # null is never contested
    return U - penalty * blocked

def play(d2: torch.Tensor, player: torch.Tensor, strategy_ok: torch.Tensor, gate: float, spec: GameSpec,
         g: torch.Generator) -> GameResult:
    """The game of one scan (module docstring) for ``d2 (B, P, T)`` (Mahalanobis distances of the
    estimates from the players' predictions), ``player (B, P)`` (a living track) and
    ``strategy_ok (B, T)`` (an estimate exists)."""
    B, P, T = d2.shape
    S = T + 1
    U = utilities(d2, strategy_ok, gate, spec)
    penalty = spec.conflict * gate
    s = U.argmax(-1)  # each player starts on its own best strategy
    regret = d2.new_zeros(B, P, S, S)  # (from l, to n), discounted sums
    rows = torch.arange(B, device=d2.device)[:, None], torch.arange(P, device=d2.device)[None, :]
    rounds = 0
    for i in range(1, spec.iterations + 1):
        rounds = i
        u = _payoffs(U, s, player, penalty)
        gain = u - u.gather(-1, s[..., None])  # u_p(n, s_-p) - u_p(s_p, s_-p)
        regret.mul_(spec.forgetting)
        regret[rows[0], rows[1], s] += gain
        r = (regret[rows[0], rows[1], s] / i).clamp(min=0)  # (B, P, S): Eq. 5 from the current strategy
        r = torch.where(player[..., None], r, r.new_zeros(()))
        if not bool((r > 0).any()):
            break
        alpha = spec.alpha_scale * r.sum(-1, keepdim=True).clamp(min=1e-300)  # Eq. 8's alpha, per player
        beta = r / alpha
        beta.scatter_(-1, s[..., None], (1 - beta.sum(-1, keepdim=True)))  # Eq. 8: stay with the rest
        if i == spec.iterations:
            s = beta.argmax(-1)  # Eq. 7
            break
        s = torch.multinomial(beta.reshape(B * P, S), 1, generator=g).reshape(B, P)
    choice = torch.where(player & (s < T), s, torch.full_like(s, -1))
    choice, repaired = resolve_conflicts(choice, d2)
    return GameResult(choice, rounds, repaired)


def resolve_conflicts(choice: torch.Tensor, d2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Where several players hold one estimate, the nearest keeps it and the others take none:
    ``(choice (B, P), repaired (B,))``."""
    B, P, T = d2.shape
    if T == 0:
        return choice, torch.zeros(B, dtype=torch.int64, device=choice.device)
    on = torch.nn.functional.one_hot(choice.clamp(min=0), T).bool() & (choice >= 0)[..., None]  # (B, P, T)
    dist = torch.where(on, d2, d2.new_full((), math.inf))
    winner = dist.argmin(1)  # (B, T)
    keep = on & (torch.arange(P, device=d2.device)[None, :, None] == winner[:, None, :])
    lost = (choice >= 0) & ~keep.any(-1)
    return torch.where(lost, torch.full_like(choice, -1), choice), lost.sum(1)
