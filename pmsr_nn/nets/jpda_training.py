"""``pmsr train`` for the hybrid tracker on detections (a config with ``kind: jpda_gain``).

The learned gain correction of :mod:`pmsr_nn.trackers.learned_gain` is trained inside the tracker
it serves, S-MSJPDA with JPDA association, on scenes drawn on the fly
(:func:`pmsr_nn.simulation.scenes.draw_scenes`: formations, crossings, independent tracks) with
detections from the package's simulator at a Pd and clutter count drawn per batch from the
config's ranges. No dataset on disk: step ``i`` draws from the seed ``(seed, i)``, so a run is
reproducible and never reads the same scene twice; validation reads fixed scenes of its own seed.

``tracking`` says how the tracks start in training:

* ``oracle`` (the default): each target's track is handed its start (truth plus a prior draw),
  so training teaches the gain, not the track management. Loss: the Huber loss of each track's
  position error in units of ``loss_scale_m`` (quadratic below ``huber_delta`` of them, linear
  beyond: a track the association lost does not drown the rest), from scan ``skip_scans`` on.
* ``managed``: the tracker starts, confirms and deletes its own tracks (the method kinds' default
  management, :meth:`~pmsr_nn.trackers.management.Management.defaults`), as the rows with
  ``initiation: detections`` run it, so training meets the tracks initiation makes: a track
  started on a wrong combination of a formation's detections (a ghost) that the association then
  keeps. Loss: each scan's GOSPA^p (``p = loss_order``, cut-off ``loss_cutoff_m``) between the
  reported tracks and the targets, in units of ``loss_scale_m^p``: the assignment is a constant
  (:func:`~pmsr_nn.metrics.sets.optimal_assignment`), the distances of the assigned pairs carry
  the gradient (a track is pulled to the target it is assigned to: with ``p = 1`` as hard at
  20 m as at 400 m, with ``p = 2`` in proportion to the distance), missed targets and false
  tracks cost ``c^p / 2`` each (no gradient). Validation also logs GOSPA with ``p = 2``
  (``val/gospa_m``).

The association weights are constants (no gradient runs through Murty's assignment); gradients
run through the gain, the UKF moments and the means.

Run folder: ``config.yaml``, ``tb/`` (TensorBoard), ``checkpoints/last.ckpt`` and ``best.ckpt``
(Lightning's, read with ``weights_only``), ``tracker.pt`` (the best weights as a
:mod:`.jpda_gain` checkpoint, what ``kind: jpda_learned_gain`` reads) and ``metrics.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from ..config import from_dict, load_yaml, require, to_dict
from .scene_data import (FlyOptimConfig, SceneConfig, SceneSampler, finish_run, fit_on_the_fly, mean_figures,
                         resolve_recipe_path, start_run)


@dataclass(frozen=True)
class GainModelConfig:
    hidden: int = 32
    gain_scale: float = 0.1

    def __post_init__(self) -> None:
        require(1 <= self.hidden <= 4096, f"model.hidden must be in [1, 4096], got {self.hidden}")
        require(0 < self.gain_scale <= 10, f"model.gain_scale must be in (0, 10], got {self.gain_scale}")


@dataclass(frozen=True)
class GainOptimConfig(FlyOptimConfig):
    """:class:`~.scene_data.FlyOptimConfig` and the loss (module docstring)."""

    loss_scale_m: float = 30.0
    huber_delta: float = 3.0
    skip_scans: int = 3
    loss_cutoff_m: float = 500.0
    loss_order: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.loss_scale_m > 0 and self.huber_delta > 0 and self.skip_scans >= 0 and self.loss_cutoff_m > 0,
                "optim: loss_scale_m, huber_delta and loss_cutoff_m must be positive, skip_scans >= 0")
        require(1.0 <= self.loss_order <= 4.0, f"optim.loss_order must be in [1, 4], got {self.loss_order}")


TRACKING = ("oracle", "managed")
"""How the tracks start in training (module docstring)."""

LEARNED_ON = ("all", "confirmed")
"""Which of a managed tracker's tracks the learned gain corrects (``confirmed``: tentative tracks
are confirmed or dropped by the model's gain alone); kind ``jpda_learned_gain`` reads it from the
checkpoint."""


@dataclass(frozen=True)
class GainTrainConfig:
    """A ``kind: jpda_gain`` training config (``train/jpda_gain.yaml``)."""

    kind: str
    name: str = "jpda_gain"
    seed: int = 0
    recipe: str = "../datasets/fitee2023_ca.yaml"
    threads: int | None = None
    m_best: int = 10
    gate_probability: float = 0.999
    tracking: str = "oracle"
    learned_on: str = "all"
    scenes: SceneConfig = SceneConfig()
    model: GainModelConfig = GainModelConfig()
    optim: GainOptimConfig = GainOptimConfig()

    def __post_init__(self) -> None:
        require(self.kind == "jpda_gain", f"kind must be jpda_gain, got {self.kind!r}")
        require(self.seed >= 0, f"seed must be non-negative, got {self.seed}")
        require(self.threads is None or self.threads >= 1, f"threads must be at least 1, got {self.threads}")
        require(self.tracking in TRACKING, f"tracking must be one of {', '.join(TRACKING)}, got {self.tracking!r}")
        require(self.learned_on in LEARNED_ON, f"learned_on must be one of {', '.join(LEARNED_ON)}, got "
                                               f"{self.learned_on!r}")
        require(self.tracking != "managed" or self.scenes.window > self.optim.skip_scans,
                f"scenes.window ({self.scenes.window}) must be longer than optim.skip_scans ({self.optim.skip_scans})")


def load_gain_config(path, overrides=()) -> GainTrainConfig:
    from dataclasses import replace

    from .train_config import apply_overrides

    cfg = from_dict(GainTrainConfig, apply_overrides(load_yaml(path), list(overrides)), where="train config")
    return replace(cfg, recipe=resolve_recipe_path(cfg.recipe, path))


class Problem:
    """What training and validation share: the scenes (:class:`~.scene_data.SceneSampler`), the
    motion and the tracker settings of a config."""

    def __init__(self, cfg: GainTrainConfig):
        self.cfg = cfg
        self.sampler = SceneSampler(cfg.recipe, cfg.scenes)
        self.recipe, self.motion, self.model = self.sampler.recipe, self.sampler.motion, self.sampler.model
        self.noise_std, self.dt = self.sampler.noise_std, self.sampler.dt
        self.q = self.recipe.effective_motion().q_psd
        self.prior_sd = self.recipe.initiation_prior_sd()

    def draw(self, seed: tuple[int, ...], B: int):
        """``(scans, prior, truth, settings)`` of ``B`` scenes from the seed ``seed``."""
        from ..filters.gaussian import Gaussian
        from ..trackers.jpda import floored_clutter_density
        from ..trackers.msjpda import JPDASettings

        scans, truth, pd, clutter, g = self.sampler.draw(seed, B)
        N = truth.shape[2]
        x0 = truth[:, 0] + torch.randn(truth[:, 0].shape, generator=g, dtype=torch.float64) * self.prior_sd
        prior = Gaussian(x0, torch.diag(self.prior_sd**2).expand(B, N, -1, -1))
        settings = JPDASettings(pd, floored_clutter_density(clutter, self.model.components), self.cfg.m_best,
                                self.cfg.gate_probability)
        return scans, prior, truth, settings

    def _correction(self, net):
        from ..trackers.learned_gain import GainCorrection

        return None if net is None else GainCorrection(net, torch.tensor(self.noise_std, dtype=torch.float64),
                                                       self.prior_sd, confirmed_only=self.cfg.learned_on == "confirmed")

    def track(self, net, scans, prior, settings):
        """Tracks ``(B, K, N, n)`` of the hybrid handed its targets' starts (``net`` None: plain S-MSJPDA)."""
        from ..trackers.msjpda import msjpda

        return msjpda(scans, prior, self.motion, self.dt, self.q, self.model, self.model.R(), settings, "sequential",
                      correction=self._correction(net)).x

    def track_managed(self, net, scans, settings):
        """The reported tracks of the hybrid starting its own tracks (``net`` None: plain S-MSJPDA):
        ``(x (B, K, T, n), exists (B, K, T))``."""
        from ..trackers.management import Management
        from ..trackers.msjpda_managed import managed_msjpda

        rep = managed_msjpda(scans, self.motion, self.dt, self.q, self.model, self.model.R(), settings, "sequential",
                             Management.defaults(self.model, self.prior_sd), correction=self._correction(net))
        return rep.x, rep.exists

    def position_error(self, x: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
        pos = list(self.motion.pos_idx)
        return (x[..., pos] - truth[..., pos]).norm(dim=-1)[:, self.cfg.optim.skip_scans:]  # (B, K', N)

    def set_errors(self, x: torch.Tensor, exists: torch.Tensor, truth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per run and scan from ``skip_scans`` on: GOSPA^p with ``p = loss_order`` (its assigned
        distances carry the gradient) and, without gradient, GOSPA^2 (``p = 2``), both with cut-off
        ``loss_cutoff_m``; ``(B, K')`` each (m^p, m^2)."""
        from ..metrics.sets import gospa, optimal_assignment

        pos, k0, c = list(self.motion.pos_idx), self.cfg.optim.skip_scans, self.cfg.optim.loss_cutoff_m
        p = self.cfg.optim.loss_order
        est, ex, tr = x[:, k0:][..., pos], exists[:, k0:], truth[:, k0:][..., pos]
        est = torch.where(ex[..., None], est, torch.zeros((), dtype=est.dtype))  # NaN outside a track's life
        alive = torch.isfinite(tr).all(-1)
        tr = torch.nan_to_num(tr)
        assign = optimal_assignment(est.detach(), ex, tr, alive, c, p)  # (B, K', T): a target per track, -1 none
        hit = assign >= 0
        target = tr.gather(2, assign.clamp(min=0)[..., None].expand(*assign.shape, len(pos)))
        d = ((est - target).square().sum(-1) + 1e-12).sqrt()  # the epsilon keeps the gradient finite at 0
        n = hit.sum(-1)
        g1 = torch.where(hit, d ** p, torch.zeros((), dtype=d.dtype)).sum(-1) + c ** p / 2 * (alive.sum(-1) + ex.sum(-1) - 2 * n)
        g2 = gospa(est.detach(), ex, tr, alive, c, 2.0).total ** 2
        return g1, g2


def _loss(err: torch.Tensor, o: GainOptimConfig) -> torch.Tensor:
    return torch.nn.functional.huber_loss(err / o.loss_scale_m, torch.zeros_like(err), delta=o.huber_delta)


def make_module(cfg: GainTrainConfig, problem: Problem):
    import lightning.pytorch as pl

    from .jpda_gain import GainNet

    class GainModule(pl.LightningModule):
        def __init__(self):
            super().__init__()
            self.net = GainNet(problem.model.n_pairs, len(problem.model.components), problem.motion.dim_x,
                               cfg.model.hidden, cfg.model.gain_scale)

        def training_step(self, step, _):
            loss = batch_figures(cfg, problem, self.net, (cfg.seed, int(step)))["loss"]
            self.log("train/loss", loss, prog_bar=False, batch_size=cfg.optim.batch_size)
            return loss

        def validation_step(self, i, _):
            for k, v in batch_figures(cfg, problem, self.net, (cfg.seed, 1_000_000, int(i))).items():
                self.log(f"val/{k}", v, batch_size=cfg.optim.batch_size)

        def configure_optimizers(self):
            return torch.optim.Adam(self.net.parameters(), lr=cfg.optim.lr)

    return GainModule()


def batch_figures(cfg: GainTrainConfig, problem: Problem, net, step: tuple[int, ...]) -> dict[str, torch.Tensor]:
    """The loss and the figures of one batch (``net`` None: plain S-MSJPDA): ``loss`` (with its
    gradient), and ``pos_rmse_m`` (oracle tracking) or ``gospa_m`` (managed: root of the mean
    GOSPA^2 over runs and scans)."""
    scans, prior, truth, settings = problem.draw(step, cfg.optim.batch_size)
    if cfg.tracking == "managed":
        g1, g2 = problem.set_errors(*problem.track_managed(net, scans, settings), truth)
        loss = g1.mean() / cfg.optim.loss_scale_m ** cfg.optim.loss_order
        if net is not None and not loss.requires_grad:  # no track in any run: nothing to pull, a zero gradient
            loss = loss + 0.0 * sum(p.sum() for p in net.parameters())
        return {"loss": loss, "gospa_m": g2.mean().sqrt()}
    err = problem.position_error(problem.track(net, scans, prior, settings), truth)
    return {"loss": _loss(err, cfg.optim), "pos_rmse_m": err.square().mean().sqrt()}


def baseline_validation(cfg: GainTrainConfig, problem: Problem) -> dict:
    """The plain S-MSJPDA's loss and figure on the validation scenes (what training must beat):
    the means over the validation batches, as Lightning logs the trained network's."""
    return mean_figures([batch_figures(cfg, problem, None, (cfg.seed, 1_000_000, i)) for i in range(cfg.optim.val_batches)])


def train_gain(cfg: GainTrainConfig, out: str | Path, progress: bool = True) -> dict:
    """Train ``cfg`` into the new run folder ``out``; returns the metrics (also in metrics.json)."""
    from .torch_settings import restored_torch_settings

    with restored_torch_settings(cfg.threads):
        return _train_gain(cfg, out, progress)


def _train_gain(cfg: GainTrainConfig, out: str | Path, progress: bool) -> dict:
    import lightning.pytorch as pl

    from .jpda_gain import gain_metadata, save_gain_checkpoint

    out = Path(out)
    start_run(out, cfg, cfg.recipe)
    problem = Problem(cfg)
    base = baseline_validation(cfg, problem)
    if progress:
        figure = (f"GOSPA {base['gospa_m']:.1f} m" if "gospa_m" in base else f"position RMSE {base['pos_rmse_m']:.2f} m")
        print(f"S-MSJPDA alone on the validation scenes ({cfg.tracking} tracking): loss {base['loss']:.4f}, {figure}",
              flush=True)
    pl.seed_everything(cfg.seed, verbose=False)
    module = make_module(cfg, problem)
    o = cfg.optim
    trainer, ckpt, seconds = fit_on_the_fly(module, out, o.steps, o.val_every, cfg.optim.val_batches, o.gradient_clip_val,
                                            o.max_time_minutes, progress=progress)
    meta = gain_metadata(problem.model.geometry.to_dict(), list(problem.model.components), list(problem.noise_std),
                         problem.dt, module.net, problem.prior_sd.tolist(), seed=cfg.seed, steps=int(trainer.global_step),
                         config=to_dict(cfg))
    save_gain_checkpoint(out / "tracker.pt", meta, module.net)
    metrics = finish_run(out, trainer, ckpt, seconds, base, "val/loss")
    if progress:
        print(f"trained   {metrics['steps']} steps in {seconds:.0f} s; best validation loss {metrics['best_val']} "
              f"(S-MSJPDA alone {base['loss']:.4f})", flush=True)
    return metrics
