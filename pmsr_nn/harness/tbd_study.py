"""Track-before-detect studies (``kind: tbd``): every filter on the same range-Doppler maps.

The Remote Sensing 2020 seed's Sections 4-5: one target seen by one receiver through the maps of
several satellites, the PMB, ICMB (known SNRs, ascending or descending order), the modified ICMB
(online SNR estimate) and detect-then-track on the same Monte Carlo maps. Per case (a setting of
the map SNRs) and block of runs: the truth (:class:`~pmsr_nn.tbd.scene.TBDScene`), the ``rd_maps``
product from a generator seeded by ``(seed, case, block)``, then each method on the whole block
with its own generator ``(seed, case, block, crc32(name))``. Per frame the runner keeps sums over
runs; ``results.json``, ``report.md`` and figures follow.

Scoring, per frame ``k`` (0-based in arrays, 1-based in the seed's words):

* *detected*: the most probable component's existence is above the filter's ``threshold`` (the
  seed's detected-frame rate while the target is present, a false alarm while it is absent);
* RMS position / velocity error of that component over the runs that detect, while present;
* OSPA (cut-off ``ospa_c_m``, order 1) between the components above the threshold and the truth;
* the SNRs the update used (estimated by the modified ICMB), the existence, the particle count.
"""

from __future__ import annotations

import dataclasses
import json
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from ..config import from_dict, require, to_dict
from ..environment import environment
from ..errors import ConfigError
from ..metrics.sets import ospa
from ..rng import seeded_generator
from ..simulation.products import SensorSetup
from ..tbd.detect import DetectSpec
from ..tbd.maps import power_ratio
from ..tbd.multibernoulli import MBSpec
from ..tbd.run import run_filter
from ..tbd.scene import TBDScene, make_rd_maps
from .scenario import StudyFile


@dataclass(frozen=True)
class TBDMethodSpec:
    """A filter: ``filter`` overrides the study's filter settings (:class:`~pmsr_nn.tbd.multibernoulli.MBSpec`
    keys); with ``detect`` it tracks threshold detections of the maps instead (detect-then-track)."""

    name: str
    filter: dict = field(default_factory=dict)
    detect: DetectSpec | None = None

    def __post_init__(self) -> None:
        require(bool(self.name) and "/" not in self.name, f"method name {self.name!r} must be non-empty, without '/'")


@dataclass(frozen=True)
class TBDCaseSpec:
    """A setting: ``snr_db`` and ``doppler_cell_hz`` override the scene's; ``methods`` names the
    methods it runs (all if empty)."""

    name: str
    title: str = ""
    snr_db: tuple[float, ...] | None = None
    doppler_cell_hz: float | None = None
    methods: tuple[str, ...] = ()


@dataclass(frozen=True)
class TBDReferenceSpec:
    """The seed's Table 2 in ``file`` under ``key``; ``label`` names it in the report."""

    file: str = "reference/paper_tables.json"
    key: str = "remotesensing2020_icmb.table2_subarea"
    label: str = "paper"


@dataclass(frozen=True)
class TBDScenario(StudyFile):
    name: str
    scene: TBDScene
    cases: tuple[TBDCaseSpec, ...]
    methods: tuple[TBDMethodSpec, ...]
    kind: Literal["tbd"] = "tbd"
    description: str = ""
    seed: int = 0
    mc_runs: int = 10
    block_runs: int = 5
    filter: MBSpec = MBSpec()
    accel_model: Literal["cv"] = "cv"
    ospa_c_m: float = 1000.0
    table2_frame: int = 15
    reference: TBDReferenceSpec | None = None
    base_dir: str = field(default=".", init=False, compare=False)

    def __post_init__(self) -> None:
        require(1 <= self.mc_runs <= 1_000_000 and self.block_runs >= 1, "mc_runs must be in [1, 1e6], block_runs >= 1")
        require(self.seed >= 0 and self.ospa_c_m > 0, "seed must be >= 0 and ospa_c_m positive")
        require(1 <= self.table2_frame <= self.scene.frames, "table2_frame must be a frame of the scene (1-based)")
        require(len(self.cases) > 0 and len(self.methods) > 0, "a study needs cases and methods")
        for what, names in (("case", [c.name for c in self.cases]), ("method", [m.name for m in self.methods])):
            dup = sorted({n for n in names if names.count(n) > 1})
            require(not dup, f"duplicate {what} name(s): {dup}")
        known = {m.name for m in self.methods}
        for c in self.cases:
            unknown = [m for m in c.methods if m not in known]
            require(not unknown, f"case {c.name!r} names unknown methods {unknown}")
            require(c.snr_db is None or len(c.snr_db) == self.scene.P,
                    f"case {c.name!r}: snr_db needs one value per satellite ({self.scene.P})")

    def with_checkpoints(self, checkpoints):
        raise ConfigError("a track-before-detect study has no learned methods: --checkpoint does not apply")

    def method_spec(self, m: TBDMethodSpec) -> MBSpec:
        """The study's filter settings with the method's overrides (checked like the YAML)."""
        return from_dict(MBSpec, {**to_dict(self.filter), **m.filter}, where=f"methods.{m.name}.filter")

    def to_dict(self) -> dict:
        return to_dict(self)


def is_tbd(data) -> bool:
    return isinstance(data, dict) and data.get("kind") == "tbd"


def tbd_from_dict(data: dict, base_dir: str | Path = ".", where: str = "scenario") -> TBDScenario:
    sc = from_dict(TBDScenario, data, where=where)
    object.__setattr__(sc, "base_dir", str(Path(base_dir).resolve()))
    return sc


@dataclass
class TBDSetup:
    """A study resolved and checked: per case its scene, per method its filter settings."""

    scenario: TBDScenario
    scenes: dict[str, TBDScene]
    specs: dict[str, MBSpec]
    cases: dict[str, list[str]]


def prepare_tbd(sc: TBDScenario) -> TBDSetup:
    """Every user error surfaces here, before anything is written: the map grid (a birth box outside
    a given map extent), sub-areas larger than the map, the methods' settings."""
    specs = {m.name: sc.method_spec(m) for m in sc.methods}
    scenes, cases = {}, {}
    for c in sc.cases:
        scene = sc.scene if c.snr_db is None else dataclasses.replace(sc.scene, snr_db=tuple(c.snr_db))
        if c.doppler_cell_hz is not None:
            scene = dataclasses.replace(scene, maps=dataclasses.replace(scene.maps, doppler_cell_hz=c.doppler_cell_hz))
        grid = scene.grid
        for name in c.methods or [m.name for m in sc.methods]:
            s = specs[name].snr_model_db
            if s is not None and len(s) not in (1, scene.P):
                raise ConfigError(f"method {name!r}: snr_model_db needs one value or one per satellite ({scene.P}), "
                                  f"got {len(s)}")
            h = specs[name].subarea_half
            if h is not None and (2 * h + 1 > grid.D or 2 * h + 1 > grid.U):
                raise ConfigError(f"method {name!r}: sub-area {2 * h + 1}x{2 * h + 1} is larger than the maps "
                                  f"({grid.D} Doppler x {grid.U} range cells); use subarea_half: null for the whole map")
        truth = scene.truth()
        alive = truth.alive[:, 0]
        for k in torch.nonzero(alive)[:, 0].tolist():
            d, u = scene.cells(truth.x[k, 0], k)
            if bool(((d < 0) | (d > grid.D - 1) | (u < 0) | (u > grid.U - 1)).any()):
                raise ConfigError(f"case {c.name!r}: the target leaves the maps at frame {k + 1}; put its track inside "
                                  "the birth box or widen map_extent")
        scenes[c.name] = scene
        cases[c.name] = list(c.methods) or [m.name for m in sc.methods]
    return TBDSetup(sc, scenes, specs, cases)


def _run_method(setup: TBDSetup, scene: TBDScene, name: str, product, g: torch.Generator):
    method = next(m for m in setup.scenario.methods if m.name == name)
    spec = setup.specs[name]
    return run_filter(scene, spec, product, g, method.detect), spec


def _block_sums(out, spec: MBSpec, truth_x: torch.Tensor, present: torch.Tensor, c_m: float) -> dict[str, np.ndarray]:
    """Sums over the block's runs, per frame (module docstring)."""
    x, det, r = out.best(spec.threshold)  # (B, K, 4), (B, K), (B, K)
    t = truth_x[:, :, 0]  # (B, K, 4)
    hit = det & present[None]
    e_p = ((x[..., [0, 2]] - t[..., [0, 2]]) ** 2).sum(-1)
    e_v = ((x[..., [1, 3]] - t[..., [1, 3]]) ** 2).sum(-1)
    zero = torch.zeros((), dtype=e_p.dtype)
    est_mask = out.r > spec.threshold  # (B, K, Q)
    o = ospa(out.x[..., [0, 2]], est_mask, torch.nan_to_num(t[..., None, [0, 2]]), present[None, :, None].expand(*det.shape, 1),
             c_m, 1.0)
    return {"detected": det.sum(0).double().numpy(), "pos": torch.where(hit, e_p, zero).sum(0).numpy(),
            "vel": torch.where(hit, e_v, zero).sum(0).numpy(), "hits": hit.sum(0).double().numpy(),
            "existence": r.sum(0).numpy(), "ospa": o.sum(0).numpy(), "snr_db": out.snr_db.sum(0).numpy(),
            "particles": out.particles.sum(0).double().numpy(), "estimates": est_mask.sum(-1).sum(0).double().numpy(),
            "run_pos_err": torch.where(hit, e_p.sqrt(), torch.full_like(e_p, float("nan"))).numpy()}  # per run (B, K)


PER_RUN = ("run_pos_err",)
"""Quantities kept per run (concatenated over blocks); the others are summed."""


def run_tbd(setup: TBDSetup, progress: bool = True) -> tuple[dict, dict]:
    """Every method of every case on every block: ``(sums, examples)``; ``sums[case][method]`` holds the
    per-frame sums and ``seconds``; ``examples[case]`` run 0's maps at three frames and tracks."""
    from tqdm.auto import tqdm

    sc = setup.scenario
    sums: dict = {}
    examples: dict = {}
    total = sum(len(m) for m in setup.cases.values()) * sc.n_blocks
    bar = tqdm(total=total, disable=not progress, unit="method-block", desc=sc.name, leave=False)
    with torch.no_grad():
        for ci, c in enumerate(sc.cases):
            scene = setup.scenes[c.name]
            sensing = SensorSetup(model=None, prior_sd=None, rd_maps=scene)
            for block in range(sc.n_blocks):
                b = len(sc.block_runs_range(block))
                g = seeded_generator(sc.seed, ci, block)
                truth = scene.truth().draw(b, g)
                product = make_rd_maps(sensing, truth, g, g)
                present = truth.alive[:, 0]
                for name in setup.cases[c.name]:
                    bar.set_postfix_str(f"{c.name} {name}", refresh=False)
                    t0 = time.perf_counter()
                    out, spec = _run_method(setup, scene, name, product,
                                            seeded_generator(sc.seed, ci, block, zlib.crc32(name.encode())))
                    seconds = time.perf_counter() - t0
                    s = _block_sums(out, spec, truth.x, present, sc.ospa_c_m)
                    per = sums.setdefault(c.name, {}).setdefault(name, {"seconds": 0.0})
                    for q, v in s.items():
                        per[q] = np.concatenate([per[q], v]) if q in PER_RUN and q in per else per.get(q, 0.0) + v
                    per["seconds"] += seconds
                    if block == 0:
                        xb, det, _ = out.best(spec.threshold)
                        ex = examples.setdefault(c.name, {"truth": truth.x[0, :, 0].numpy(), "tracks": {}})
                        ex["tracks"][name] = torch.where(det[0, :, None], xb[0], float("nan")).numpy()
                    bar.update()
                if block == 0:
                    frames = [k for k in (scene.appears_frame, (scene.appears_frame + scene.disappears_frame) // 2,
                                          scene.disappears_frame - 1)]
                    examples[c.name]["maps"] = {k: product.frame(k - 1)[0].abs().numpy() ** 2 for k in frames}
                    examples[c.name]["truth_cells"] = {k: [v.numpy() for v in scene.cells(truth.x[0, k - 1, 0], k - 1)]
                                                       for k in frames}
    bar.close()
    return sums, examples


def finalise_tbd(setup: TBDSetup, sums: dict) -> dict:
    sc = setup.scenario
    R = sc.mc_runs
    out = {}
    for c in sc.cases:
        scene = setup.scenes[c.name]
        present = scene.truth().alive[:, 0].numpy()
        rows = {}
        for name in setup.cases[c.name]:
            s = sums[c.name][name]
            spec = setup.specs[name]
            hits = np.where(s["hits"] > 0, s["hits"], np.nan)
            det = s["detected"] / R
            rms_p, rms_v = np.sqrt(s["pos"] / hits), np.sqrt(s["vel"] / hits)
            err = s["run_pos_err"]  # (R, K), NaN where the run does not detect
            med = np.array([np.median(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in err.T])
            last = int(np.nonzero(present)[0][-1])
            method = next(m for m in sc.methods if m.name == name)
            rows[name] = {
                "update": "detect-then-track" if method.detect is not None else spec.update,
                "snr": "estimated" if spec.estimate_snr and method.detect is None else
                       ("true" if spec.snr_model_db is None else f"modelled {list(spec.snr_model_db)} dB"),
                "subarea": "full" if spec.subarea_half is None else f"{2 * spec.subarea_half + 1}x{2 * spec.subarea_half + 1}",
                "power_ratio": power_ratio(spec.subarea_half, scene.maps.lobe_cells) if method.detect is None else None,
                "detected_frame_rate": det.tolist(),
                "detected_rate_present": float(det[present].mean()),
                "false_alarm_rate_absent": float(det[~present].mean()) if (~present).any() else None,
                "detected_rate_table2_frame": float(det[sc.table2_frame - 1]),
                "rms_pos_m": rms_p.tolist(), "rms_vel_mps": rms_v.tolist(),
                "rms_pos_last_present_m": float(rms_p[last]), "rms_vel_last_present_mps": float(rms_v[last]),
                "median_pos_err_m": med.tolist(), "median_pos_err_last_present_m": float(med[last]),
                "existence": (s["existence"] / R).tolist(), "ospa_m": (s["ospa"] / R).tolist(),
                "ospa_mean_m": float((s["ospa"] / R).mean()),
                "snr_db": (s["snr_db"] / R).tolist(), "particles": (s["particles"] / R).tolist(),
                "estimates_per_frame": (s["estimates"] / R).tolist(),
                "seconds_per_run": float(s["seconds"] / R),
                **({"detect": to_dict(method.detect)} if method.detect is not None else {}),
            }
        grid = scene.grid
        out[c.name] = {"title": c.title or c.name, "snr_db": list(scene.snr_db), "present": present.tolist(),
                       "doppler_cell_hz": scene.maps.doppler_cell_hz, "range_cell_m": scene.maps.range_cell_m,
                       "map_cells": [grid.D, grid.U], "methods": rows}
    return out


DEFINITIONS = {
    "detected_frame_rate": "per frame: fraction of runs whose most probable Bernoulli component has existence above "
                           "the threshold (0.5), the seed's N_d,k / N_mc; while the target is absent it is a false-alarm rate",
    "detected_rate_table2_frame": "detected_frame_rate at table2_frame (the seed's Table 2 uses frame 15)",
    "rms_pos_m": "per frame: root mean square position error of the most probable component over the runs that "
                 "detect the target at that frame (NaN where none does)",
    "median_pos_err_m": "per frame: median over the runs that detect of the position error of the most probable "
                        "component (robust to the few runs locked onto a ghost, which dominate rms_pos_m)",
    "ospa_m": "per frame: OSPA (order 1, cut-off ospa_c_m) between the components above the threshold and the "
              "target (empty set while absent), mean over runs",
    "snr_db": "per frame and map: the SNR the update used, mean over runs (the modified ICMB's online estimate: the "
              "largest ML amplitude over the predicted particles, Eq. 25)",
    "power_ratio": "expected share of the target's map energy inside the sub-area, for the triangle x sinc response "
                   "with uniform sub-cell offsets (pmsr_nn.tbd.maps.power_ratio)",
    "seconds_per_run": "wall-clock seconds of the filter per Monte Carlo run (whole-block calls / runs), this machine",
}


def write_tbd_outputs(setup: TBDSetup, sums: dict, examples: dict, out: Path, device: str) -> dict:
    from .tbd_report import write_tbd_report

    sc = setup.scenario
    ref = None
    if sc.reference is not None:
        ref = sc.keyed_reference()
    res = {"scenario": sc.name, "kind": "tbd", "seed": sc.seed, "mc_runs": sc.mc_runs, "environment": environment(device),
           "description": sc.description, "settings": {"scene": to_dict(sc.scene), "filter": to_dict(sc.filter),
                                                      "methods": {m.name: to_dict(setup.specs[m.name]) | (
                                                          {"detect": to_dict(m.detect)} if m.detect else {})
                                                          for m in sc.methods},
                                                      "block_runs": sc.block_runs, "ospa_c_m": sc.ospa_c_m,
                                                      "table2_frame": sc.table2_frame},
           "definitions": DEFINITIONS, "reference": ref, "cases": finalise_tbd(setup, sums)}
    (out / "results.json").write_text(json.dumps(res, indent=1, allow_nan=True) + "\n")
    write_tbd_report(res, examples, out)
    return res
