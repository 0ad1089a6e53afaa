"""``pmsr train`` for neural-enhanced BP (a config with ``kind: nebp``, ``train/nebp.yaml``).

The graph network of :mod:`.nebp` is trained inside the BP tracker it serves
(:func:`~pmsr_nn.trackers.bp_tracker.bp_tracker`, the method kind ``bp``'s defaults), which starts,
confirms and deletes its own tracks, on scenes drawn on the fly
(:class:`~.scene_data.SceneSampler`: formations, crossings, independent tracks of the config's
recipe, detections with a Pd and clutter count drawn per batch). Step ``i`` draws from the seed
``(seed, i)``; validation reads fixed scenes of ``(seed, 1_000_000, j)``: never the draws of a
recorded study.

Labels, at every pair's list of every scan:

* each track (a node at the scan's first pair with existence above 0) is the target it
  describes, or none: a one-to-one assignment of tracks to the living targets by the likelihood
  of the target's position under the track's predicted position Gaussian, kept inside the gate of
  ``label_gate_probability`` (2 degrees of freedom; :func:`node_labels`). A ghost beside a
  formation, a duplicate, or a track on clutter has no target;
* each new potential target that an earlier pair of the scan seeded is its seeding detection's
  target, unless a track or an earlier new potential target holds that target (a duplicate: none;
  :class:`Supervisor`);
* each detection's origin is the simulator's (a target, or clutter).

Loss (:func:`association_loss`, :func:`existence_loss`), summed over the lists and scans of a
batch and divided by the number of terms, each term weighted by ``optim.*_weight``: the binary
cross-entropy of each gated edge's association probability ``p(a_i = m)`` against "detection
``m`` is node ``i``'s target"; the cross-entropy of each detection's three beliefs (clutter, a
track's, a new target's) against its truth (clutter; a target some node describes; a target no
node describes), a new target's detection weighted by ``optim.new_weight`` (its miss is a late
start, which GOSPA scores as a missed target); and the binary cross-entropy of each node's updated existence against "the node
describes a target". The best checkpoint is the one with the lowest validation GOSPA
(``optim.monitor: gospa_m``; ``loss`` for the loss): the loss is a proxy, GOSPA what is scored. The beliefs come from
``grad_passes`` message passes with gradients, started at BP's converged messages (computed
without gradients): the tracker itself runs on detached corrected inputs, so the gradient reaches
the network through one list's association at a time, never through the tracks' history.

Run folder: ``config.yaml``, ``tb/`` (TensorBoard), ``checkpoints/`` (Lightning's),
``tracker.pt`` (the best weights as an :mod:`.nebp` checkpoint, what ``kind: nebp`` reads) and
``metrics.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from ..config import from_dict, load_yaml, require, to_dict
from ..trackers.gating import gate_threshold
from .scene_data import (FlyOptimConfig, SceneConfig, SceneSampler, finish_run, fit_on_the_fly, mean_figures,
                         resolve_recipe_path, start_run)


@dataclass(frozen=True)
class NEBPModelConfig:
    """The network's size (:class:`~.nebp.NEBPNet`) and the differentiable passes of training."""

    hidden: int = 32
    rounds: int = 2
    bound: float = 4.0
    grad_passes: int = 3

    def __post_init__(self) -> None:
        require(1 <= self.hidden <= 1024, f"model.hidden must be in [1, 1024], got {self.hidden}")
        require(0 <= self.rounds <= 8, f"model.rounds must be in [0, 8], got {self.rounds}")
        require(0 < self.bound <= 20, f"model.bound must be in (0, 20] nats, got {self.bound}")
        require(1 <= self.grad_passes <= 50, f"model.grad_passes must be in [1, 50], got {self.grad_passes}")


@dataclass(frozen=True)
class NEBPOptimConfig(FlyOptimConfig):
    """:class:`~.scene_data.FlyOptimConfig`, the labels' gate and the validation GOSPA's cut-off."""

    label_gate_probability: float = 0.999
    gospa_cutoff_m: float = 500.0
    skip_scans: int = 3
    edge_weight: float = 1.0
    detection_weight: float = 1.0
    existence_weight: float = 1.0
    new_weight: float = 1.0
    monitor: str = "gospa_m"

    def __post_init__(self) -> None:
        super().__post_init__()
        w = (self.edge_weight, self.detection_weight, self.existence_weight)
        require(min(w) >= 0 and sum(w) > 0, "optim: edge_weight, detection_weight and existence_weight must be "
                                            "non-negative, not all 0")
        require(0 < self.new_weight <= 100, f"optim.new_weight must be in (0, 100], got {self.new_weight}")
        require(self.monitor in ("gospa_m", "loss"), f"optim.monitor must be gospa_m or loss, got {self.monitor!r}")
        require(0.5 <= self.label_gate_probability < 1.0,
                f"optim.label_gate_probability must be in [0.5, 1), got {self.label_gate_probability}")
        require(self.gospa_cutoff_m > 0 and self.skip_scans >= 0, "optim: gospa_cutoff_m > 0 and skip_scans >= 0")


@dataclass(frozen=True)
class NEBPTrainConfig:
    """A ``kind: nebp`` training config (``train/nebp.yaml``)."""

    kind: str
    name: str = "nebp"
    seed: int = 0
    recipe: str = "../datasets/fitee2023_ca.yaml"
    threads: int | None = None
    scenes: SceneConfig = SceneConfig()
    model: NEBPModelConfig = NEBPModelConfig()
    optim: NEBPOptimConfig = NEBPOptimConfig()

    def __post_init__(self) -> None:
        require(self.kind == "nebp", f"kind must be nebp, got {self.kind!r}")
        require(self.seed >= 0, f"seed must be non-negative, got {self.seed}")
        require(self.threads is None or self.threads >= 1, f"threads must be at least 1, got {self.threads}")
        require(self.scenes.window > self.optim.skip_scans,
                f"scenes.window ({self.scenes.window}) must be longer than optim.skip_scans ({self.optim.skip_scans})")


def load_nebp_config(path, overrides=()) -> NEBPTrainConfig:
    from dataclasses import replace

    from .train_config import apply_overrides

    cfg = from_dict(NEBPTrainConfig, apply_overrides(load_yaml(path), list(overrides)), where="train config")
    return replace(cfg, recipe=resolve_recipe_path(cfg.recipe, path))


def node_labels(x: torch.Tensor, P: torch.Tensor, live: torch.Tensor, targets: torch.Tensor, alive: torch.Tensor,
                gate: float) -> torch.Tensor:
    """``(B, C)`` the target each node describes (-1: none; module docstring): nodes' positions ``x
    (B, C, 2)`` with covariances ``P (B, C, 2, 2)``, ``live (B, C)``; targets' positions ``targets
    (B, N, 2)``, ``alive (B, N)``; a one-to-one assignment (:func:`~pmsr_nn.metrics.sets.min_cost_matching`)
    minimising the summed negative log-likelihoods ``d2 + log det P`` (a node whose Gaussian is
    narrow holds its target against a newborn's wide one), each kept pair's squared Mahalanobis
    distance ``d2`` inside ``gate``."""
    from ..metrics.sets import min_cost_matching

    B, C = live.shape
    if C == 0 or targets.shape[1] == 0:
        return torch.full((B, C), -1, dtype=torch.long)
    diff = targets[:, None, :, :] - x[:, :, None, :]  # (B, C, N, 2)
    Ps = 0.5 * (P + P.transpose(-1, -2))
    d2 = torch.einsum("bcni,bcij,bcnj->bcn", diff, torch.linalg.inv(Ps), diff)
    ok = live[:, :, None] & alive[:, None, :] & (d2 <= gate) & torch.isfinite(d2)
    # the negative log-likelihood (up to a constant), not d2 alone: a newborn's wide Gaussian puts a target at a
    # small d2 and would take it from the track that holds it
    nll = d2 + torch.logdet(Ps)[:, :, None]
    cost = torch.where(ok, nll, torch.full((), 1e12, dtype=d2.dtype))
    return min_cost_matching(cost, ok.any(-1), ok.any(-2), ok)


CLUTTER, LEGACY, NEW = 0, 1, 2
"""A detection's classes in :func:`association_loss`."""


def existence_loss(existence: torch.Tensor, live: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, int]:
    """``(sum, nodes)``: the binary cross-entropy of each live node's updated existence ``existence
    (B, C)`` against ``target (B, C)`` (the node describes a target), floored at 1e-12."""
    p = existence.clamp(1e-12, 1.0 - 1e-12)
    y = target.to(p.dtype)
    bce = -(y * p.log() + (1.0 - y) * (1.0 - p).log())
    return torch.where(live, bce, torch.zeros((), dtype=p.dtype)).sum(), int(live.sum())


def association_loss(association: torch.Tensor, new_existence: torch.Tensor, legacy: torch.Tensor,
                     gated: torch.Tensor, edge_target: torch.Tensor, det_class: torch.Tensor, valid: torch.Tensor,
                     new_weight: float = 1.0) -> tuple[torch.Tensor, torch.Tensor, int, int]:
    """``(edge sum, detection sum, edges, detections)`` of one list (module docstring).

    ``association (B, C, M + 1)`` BP's association probabilities (last column: none),
    ``new_existence (B, M)`` and ``legacy (B, M)`` each detection's new-target and track beliefs
    (the rest is clutter); ``gated (B, C, M)`` the edges scored, ``edge_target (B, C, M)`` bool,
    ``det_class (B, M)`` one of :data:`CLUTTER`, :data:`LEGACY`, :data:`NEW`; ``valid (B, M)``.
    The edge sum is ``-sum [y log p + (1 - y) log (1 - p)]``, the detection sum ``-sum w log
    p(class)`` with ``w = new_weight`` for a :data:`NEW` detection (a target no node describes yet:
    its miss is a late start) and 1 otherwise, each probability floored at 1e-12."""
    M = association.shape[-1] - 1
    p = association[..., :M].clamp(1e-12, 1.0 - 1e-12)
    y = edge_target.to(p.dtype)
    bce = -(y * p.log() + (1.0 - y) * (1.0 - p).log())
    edge_sum = torch.where(gated, bce, torch.zeros((), dtype=p.dtype)).sum()
    clutter = (1.0 - legacy - new_existence)
    probs = torch.stack([clutter, legacy, new_existence], -1).clamp(min=1e-12)
    chosen = probs.gather(-1, det_class.clamp(0, 2).unsqueeze(-1))[..., 0]
    weight = torch.where(det_class == NEW, new_weight, 1.0).to(p.dtype)
    det_sum = torch.where(valid, -chosen.log() * weight, torch.zeros((), dtype=p.dtype)).sum()
    return edge_sum, det_sum, int(gated.sum()), int(valid.sum())


class Supervisor:
    """The training labels of one batch and the loss terms of each list (:func:`association_loss`,
    :func:`existence_loss`): ``truth (B, K, N, n)`` (NaN where a target is not alive), ``origin
    (B, K, S, M)`` the detections' origins, ``pos`` the state's position entries, ``gate`` the
    labels' gate.

    A scan's nodes are its tracks (those at its first pair) and, after them, the new potential
    targets each earlier pair of the scan seeded, one per detection of that pair's list (BP's
    order; a pair whose detections seeded none adds no block). The tracks are labelled by
    :func:`node_labels`; a new potential target is its seeding detection's target where no track
    and no earlier new potential target of the scan holds that target (else it is a duplicate:
    none)."""

    def __init__(self, truth: torch.Tensor, origin: torch.Tensor, pos: list[int], gate: float,
                 edge_weight: float = 1.0, detection_weight: float = 1.0, existence_weight: float = 1.0,
                 new_weight: float = 1.0):
        self.truth, self.origin, self.pos, self.gate = truth, origin, pos, gate
        self.weights = (edge_weight, detection_weight, existence_weight)
        self.new_weight = new_weight
        self.count = 0
        self.edge_sum = 0.0
        self.det_sum = 0.0
        self.existence_sum = 0.0
        self._scan = (-1, 0, 0, [])  # scan, its track count, the node count at the last pair, the seeding pairs

    def labels(self, k: int, pair: int, g, live: torch.Tensor, M: int) -> torch.Tensor:
        """``(B, C)`` the target of each node at pair ``pair`` of scan ``k`` (-1: none; class docstring)."""
        B, C = live.shape
        scan, C0, last, seeding = self._scan
        if scan != k:
            scan, C0, last, seeding = k, C, C, []
        elif C > last:
            seeding = seeding + [pair - 1]
        self._scan = (scan, C0, C, seeding)
        pos = self.pos
        tx = self.truth[:, k][..., pos]  # (B, N, 2)
        alive = torch.isfinite(tx).all(-1)
        x = g.x[:, :C0][..., pos].detach()
        P = g.P[:, :C0][..., pos, :][..., pos].detach()
        tracks = node_labels(x, P, live[:, :C0], torch.nan_to_num(tx), alive, self.gate)  # (B, C0)
        if not seeding:
            return tracks
        seeds = torch.cat([self.origin[:, k, j, :M] for j in seeding], 1)  # (B, C - C0)
        seeds = torch.where(live[:, C0:] & (seeds >= 0), seeds, torch.full_like(seeds, -1))
        held = (seeds.unsqueeze(-1) == tracks.unsqueeze(1)).any(-1)  # a track holds the target
        G = seeds.shape[1]
        earlier = torch.ones(G, G, dtype=torch.bool).tril(-1)  # [a, b]: b seeded before a
        repeat = ((seeds.unsqueeze(-1) == seeds.unsqueeze(1)) & earlier).any(-1)
        newborn = torch.where((seeds >= 0) & ~held & ~repeat, seeds, torch.full_like(seeds, -1))
        return torch.cat([tracks, newborn], 1)

    def __call__(self, k: int, pair: int, g, prior: torch.Tensor, ratio: torch.Tensor, valid: torch.Tensor, beliefs):
        live = prior > 0
        M = ratio.shape[-1]
        labels = self.labels(k, pair, g, live, M)
        origin = self.origin[:, k, pair, :M]  # (B, M)
        gated = (ratio.detach() > 0) & live.unsqueeze(-1) & valid.unsqueeze(1)
        edge_target = (labels.unsqueeze(-1) >= 0) & (origin.unsqueeze(1) == labels.unsqueeze(-1))
        described = (origin.unsqueeze(-1) == labels.unsqueeze(1)).any(-1) & (origin >= 0)  # (B, M)
        det_class = torch.where(origin < 0, CLUTTER, torch.where(described, LEGACY, NEW))
        es, ds, ne, nd = association_loss(beliefs.association, beliefs.new_existence, beliefs.legacy, gated,
                                          edge_target, det_class, valid, self.new_weight)
        xs, nx = existence_loss(beliefs.existence, live, labels >= 0)
        self.count += ne + nd + nx
        self.edge_sum += float(es.detach())
        self.det_sum += float(ds.detach())
        self.existence_sum += float(xs.detach())
        return self.weights[0] * es + self.weights[1] * ds + self.weights[2] * xs


class Problem:
    """What training and validation share: the scenes, the motion and the BP settings of a config."""

    def __init__(self, cfg: NEBPTrainConfig):
        self.cfg = cfg
        self.sampler = SceneSampler(cfg.recipe, cfg.scenes)
        self.recipe, self.motion, self.model = self.sampler.recipe, self.sampler.motion, self.sampler.model
        self.noise_std, self.dt = self.sampler.noise_std, self.sampler.dt
        self.q = self.recipe.effective_motion().q_psd
        self.prior_sd = self.recipe.initiation_prior_sd()
        s = cfg.scenes
        self.scales = [s.range_m[1] if c == "range" else max(abs(v) for v in s.range_rate_mps) if c == "range_rate"
                       else 1.0 for c in self.model.components]
        self.gate = gate_threshold(cfg.optim.label_gate_probability, 2)

    def refiner(self, net, supervisor=None):
        from ..trackers.message_refiner import MessageRefiner

        return MessageRefiner(net, self.model.components, self.model.n_pairs,
                              torch.tensor(self.scales, dtype=torch.float64), self.noise_std[0], supervisor,
                              self.cfg.model.grad_passes)

    def settings(self, pd: float, clutter):
        from ..trackers.bp_tracker import BPSettings
        from ..trackers.jpda import MIN_CLUTTER_PER_SCAN, floored_clutter_density

        return BPSettings(pd=float(pd), clutter_count=max(float(clutter.per_scan), MIN_CLUTTER_PER_SCAN),
                          clutter_density=floored_clutter_density(clutter, self.model.components))

    def track(self, net, step: tuple[int, ...], B: int, train: bool):
        """Run NEBP (``net``) on ``B`` scenes of seed ``step``: ``(report, truth, supervisor, refiner)``."""
        from ..trackers.bp_tracker import bp_tracker

        scans, truth, pd, clutter, _ = self.sampler.draw(step, B)
        o = self.cfg.optim
        sup = Supervisor(truth, scans.origin, list(self.motion.pos_idx), self.gate, o.edge_weight, o.detection_weight,
                         o.existence_weight, o.new_weight)
        refiner = self.refiner(net, sup)
        with torch.set_grad_enabled(train):
            rep = bp_tracker(scans, self.motion, self.dt, self.q, self.model, self.model.R(), self.settings(pd, clutter),
                             self.prior_sd, refiner=refiner)  # kind bp's defaults, its birth velocity prior included
        return rep, truth, sup, refiner

    def gospa_m(self, rep, truth: torch.Tensor) -> float:
        """Root of the mean GOSPA^2 (cut-off ``gospa_cutoff_m``) over runs and scans from ``skip_scans`` on."""
        from ..metrics.sets import gospa

        pos, k0, c = list(self.motion.pos_idx), self.cfg.optim.skip_scans, self.cfg.optim.gospa_cutoff_m
        est = torch.nan_to_num(rep.x[:, k0:][..., pos])
        tr = truth[:, k0:][..., pos]
        alive = torch.isfinite(tr).all(-1)
        return float((gospa(est, rep.exists[:, k0:], torch.nan_to_num(tr), alive, c, 2.0).total ** 2).mean().sqrt())


def batch_figures(cfg: NEBPTrainConfig, problem: Problem, net, step: tuple[int, ...], train: bool) -> dict:
    """The loss (with its gradient in training) and, in validation, the tracker's GOSPA of one batch."""
    rep, truth, sup, refiner = problem.track(net, step, cfg.optim.batch_size, train)
    if refiner.loss is None:  # no list had a node or a detection: a zero gradient
        loss = 0.0 * sum(p.sum() for p in net.parameters())
    else:
        loss = refiner.loss / max(sup.count, 1)
    out = {"loss": loss}
    if not train:
        out["gospa_m"] = torch.tensor(problem.gospa_m(rep, truth))
        for name, v in (("edge_loss", sup.edge_sum), ("detection_loss", sup.det_sum), ("existence_loss", sup.existence_sum)):
            out[name] = torch.tensor(v / max(sup.count, 1))
    return out


def make_module(cfg: NEBPTrainConfig, problem: Problem):
    import lightning.pytorch as pl

    from .nebp import NEBPNet

    class NEBPModule(pl.LightningModule):
        def __init__(self):
            super().__init__()
            m = cfg.model
            self.net = NEBPNet(problem.model.n_pairs, problem.model.components, m.hidden, m.rounds, m.bound)

        def training_step(self, step, _):
            loss = batch_figures(cfg, problem, self.net, (cfg.seed, int(step)), True)["loss"]
            self.log("train/loss", loss, batch_size=cfg.optim.batch_size)
            return loss

        def validation_step(self, i, _):
            for k, v in batch_figures(cfg, problem, self.net, (cfg.seed, 1_000_000, int(i)), False).items():
                self.log(f"val/{k}", v, batch_size=cfg.optim.batch_size)

        def configure_optimizers(self):
            return torch.optim.Adam(self.net.parameters(), lr=cfg.optim.lr)

    return NEBPModule()


def validate(cfg: NEBPTrainConfig, problem: Problem, net) -> dict:
    """The mean figures of :func:`batch_figures` of network ``net`` over the validation scenes."""
    return mean_figures([batch_figures(cfg, problem, net, (cfg.seed, 1_000_000, i), False)
                         for i in range(cfg.optim.val_batches)])


def baseline_validation(cfg: NEBPTrainConfig, problem: Problem) -> dict:
    """BP's loss and GOSPA on the validation scenes (the untrained network: zero corrections)."""
    from .nebp import NEBPNet

    return validate(cfg, problem, NEBPNet(problem.model.n_pairs, problem.model.components, cfg.model.hidden,
                                          cfg.model.rounds, cfg.model.bound))


def train_nebp(cfg: NEBPTrainConfig, out: str | Path, progress: bool = True) -> dict:
    """Train ``cfg`` into the new run folder ``out``; returns the metrics (also in metrics.json)."""
    from .torch_settings import restored_torch_settings

    with restored_torch_settings(cfg.threads):
        return _train_nebp(cfg, out, progress)


def _train_nebp(cfg: NEBPTrainConfig, out: str | Path, progress: bool) -> dict:
    import lightning.pytorch as pl

    from .nebp import nebp_metadata, save_nebp_checkpoint

    out = Path(out)
    start_run(out, cfg, cfg.recipe)
    problem = Problem(cfg)
    base = baseline_validation(cfg, problem)
    if progress:
        print(f"BP alone on the validation scenes: loss {base['loss']:.4f}, GOSPA {base['gospa_m']:.1f} m", flush=True)
    pl.seed_everything(cfg.seed, verbose=False)
    module = make_module(cfg, problem)
    o = cfg.optim
    trainer, ckpt, seconds = fit_on_the_fly(module, out, o.steps, o.val_every, o.val_batches, o.gradient_clip_val,
                                            o.max_time_minutes, monitor=f"val/{o.monitor}", progress=progress)
    meta = nebp_metadata(problem.model.geometry.to_dict(), list(problem.model.components), list(problem.noise_std),
                         problem.dt, problem.motion.dim_x, module.net, problem.scales, seed=cfg.seed,
                         steps=int(trainer.global_step), config=to_dict(cfg))
    save_nebp_checkpoint(out / "tracker.pt", meta, module.net)
    metrics = finish_run(out, trainer, ckpt, seconds, base, f"val/{o.monitor}")
    if progress:
        print(f"trained   {metrics['steps']} steps in {seconds:.0f} s; best val/{o.monitor} {metrics['best_val']} "
              f"(BP alone {base[o.monitor]:.4f})", flush=True)
    return metrics
