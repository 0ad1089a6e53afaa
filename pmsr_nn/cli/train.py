"""``pmsr train`` (one learned tracker into a run folder) and ``pmsr select`` (the best of u trained models)."""

from __future__ import annotations

from pathlib import Path

from ..errors import PmsrError
from .common import positive_int


def add_train(sub) -> None:
    t = sub.add_parser(
        "train",
        help="train a learned tracker (DFNN / MDFNN / RNN / KalmanNet-style filter on measurement streams; "
        "nebp on detections)",
        description="Train a tracker from a YAML config (train/*.yaml) into a run folder: a network on "
        "measurement streams (model.kind mdfnn, dfnn, rnn or kalmannet), or a tracker on detections "
        "(kind: nebp, trained on scenes drawn on the fly). Checkpoints "
        "(best and last), TensorBoard logs (RUN/tb), the resolved config, tracker.pt for inference and "
        "metrics.json. KEY=VALUE overrides change any config entry, e.g. trainer.max_epochs=5 "
        "model.filter_order=10. A missing dataset is simulated once into the config's cache_dir.",
    )
    t.add_argument("config", nargs="?", help="training config YAML (optional with --resume)")
    t.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides (YAML values)")
    t.add_argument("--out", type=Path, required=True, help="run folder (new, or the run to --resume)")
    t.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from RUN/checkpoints/last.ckpt, or where that is missing or "
                   "unreadable from the newest readable checkpoint (one line says which); a run with results but "
                   "no readable checkpoint is refused, and a worse session never replaces the recorded best")
    t.add_argument("--verbose", action="store_true",
                   help="Lightning's own progress bars, model summary and messages instead of one line per epoch")
    t.set_defaults(run=cmd_train)


def add_select(sub) -> None:
    sel = sub.add_parser(
        "select",
        help="train u models and keep the best (Section 3.3 of the MDFNN paper)",
        description="Train --members models of one config with different seeds and cross-validation folds "
        "of the train+val tracks, evaluate each on its validation fold and on fresh tracks never used in "
        "training, keep the best (lowest fresh-track position RMSE) as OUT/best.pt and write the "
        "comparison table OUT/selection.md and OUT/selection.json.",
    )
    sel.add_argument("config", help="training config YAML")
    sel.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides (YAML values)")
    sel.add_argument("--out", type=Path, required=True, help="output folder (must not exist)")
    sel.add_argument("--members", type=positive_int, default=10, help="number of models u (default 10, the paper's)")
    sel.add_argument("--fresh-tracks", type=positive_int, default=20, help="fresh evaluation tracks (default 20)")
    sel.set_defaults(run=cmd_select)


def split_overrides(config: str | None, overrides: list[str]) -> tuple[str | None, list[str]]:
    """``(config, overrides)``: a first positional that is a KEY=VALUE (``train --resume k=v``) is an override."""
    if config is not None and "=" in config and not config.endswith((".yaml", ".yml")):
        return None, [config, *overrides]
    return config, list(overrides)


def cmd_train(args) -> int:
    from ..nets.train_config import load_train_config
    from ..nets.training import train

    config, overrides = split_overrides(args.config, args.overrides)
    if config is None and not args.resume:
        raise PmsrError("give a training config (e.g. train/smoke.yaml), or --resume an existing run")
    kind = _detection_tracker_kind(config)
    if kind is not None:
        return _train_on_detections(kind, config, overrides, args)
    cfg = load_train_config(config, overrides) if config is not None else None
    if args.resume and cfg is None and overrides:
        raise PmsrError("overrides need the config they apply to; a resumed run keeps its own config")
    m = train(cfg, args.out, resume=args.resume, console="lightning" if args.verbose else "lines")
    if m["global_rank"] != 0:  # DDP workers: rank 0 reports
        return 0
    print(f"run       {args.out}  ({m['epochs']} epochs, {m['global_step']} steps in {m['fit_seconds_this_session']:.0f} s"
          + (f", {m['train_windows_per_second']:.0f} windows/s)" if m['train_windows_per_second'] else ")"))
    print(f"val       position RMSE {m['val']['pos_rmse_m']:.2f} m, velocity RMSE {m['val']['vel_rmse_mps']:.3f} m/s "
          f"(best checkpoint {m['best_checkpoint']}; every sample of every window)")
    print(f"test      position RMSE {m['test']['pos_rmse_m']:.2f} m, velocity RMSE {m['test']['vel_rmse_mps']:.3f} m/s")
    print(f"tracker   {args.out / 'tracker.pt'}   (tensorboard --logdir {args.out / 'tb'})")
    return 0


def cmd_select(args) -> int:
    from ..nets.selection import select_best
    from ..nets.train_config import load_train_config

    cfg = load_train_config(args.config, args.overrides)
    result = select_best(cfg, args.out, members=args.members, fresh_tracks_n=args.fresh_tracks)
    print(result["table"])
    print(f"\nbest      member {result['best']} -> {args.out / 'best.pt'}")
    return 0


RETIRED_KINDS = {"set_tracker": "pmsr_nn.set_tracker", "jpda_gain": "pmsr_nn.jpda_gain"}
"""Training config kinds of trackers this package no longer has (kind -> its checkpoint format in
:data:`pmsr_nn.nets.checkpoint.RETIRED_FORMATS`, which says what it was and where it lives)."""


def _detection_tracker_kind(config: str | None) -> str | None:
    """The kind (``nebp``) of a config of a tracker on detections, else None; a config
    of a kind in ``RETIRED_KINDS`` is refused in one line."""
    from pathlib import Path

    from ..config import load_yaml
    from ..nets.checkpoint import RETIRED_FORMATS

    if config is None or not Path(config).is_file():
        return None
    raw = load_yaml(config)
    kind = raw.get("kind") if isinstance(raw, dict) else None
    if isinstance(kind, str) and kind in RETIRED_KINDS:
        raise PmsrError(f"{config}: kind {kind} is {RETIRED_FORMATS[RETIRED_KINDS[kind]]}; this pmsr_nn does not "
                        "train it")
    return kind if kind == "nebp" else None


def _train_on_detections(kind: str, config: str, overrides: list[str], args) -> int:
    """A tracker on detections, trained on scenes drawn on the fly (:mod:`pmsr_nn.nets.nebp_training`)."""
    if args.resume:
        raise PmsrError(f"a {kind} run can not be resumed (its steps draw fresh scenes): train it again into a new --out")
    if kind == "nebp":
        from ..nets.nebp_training import load_nebp_config, train_nebp

        m = train_nebp(load_nebp_config(config, overrides), args.out)
    print(f"tracker   {args.out / 'tracker.pt'}   (tensorboard --logdir {args.out / 'tb'})")
    return 0 if m["steps"] > 0 else 1
