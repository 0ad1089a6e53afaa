"""Device-agnostic trackers (issue 57, item 5): every kind that may run with ``pmsr evaluate
--device cuda`` creates its tensors on the device of its inputs.

This machine has no GPU: the check is :func:`device_check.on_meta_default` (a tensor made without
``device=`` lands on the meta device and breaks the call), first shown to catch such a tensor.
Each kind is called on a small scene (one block of 2 runs) through the runner's
:func:`~pmsr_nn.harness.run.blocks.call_method`, once as usual and once on the meta default,
and the two answers must agree bit for bit (the check changes nothing it does not break). The
kinds that are not device-agnostic yet are strict xfails: the day one passes, the test fails
until its mark is taken off and its kind's ``any_device`` set.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
import yaml

from device_check import on_meta_default
from pmsr_nn.errors import ConfigError
from pmsr_nn.harness.run.blocks import _first_runs, call_method, draw_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario
from pmsr_nn.methods import MethodCall, registry

ROOT = Path(__file__).resolve().parents[1]


# -- the check itself ------------------------------------------------------------------------------

def _implicit(x: torch.Tensor) -> torch.Tensor:
    return x + torch.zeros(3)


def _explicit(x: torch.Tensor) -> torch.Tensor:
    return x + torch.zeros(3, dtype=x.dtype, device=x.device)


def test_the_meta_default_catches_a_tensor_made_without_device():
    x = torch.ones(3, dtype=torch.float64)
    with pytest.raises(RuntimeError, match="meta"):
        on_meta_default(_implicit, x)
    with pytest.raises(RuntimeError, match="meta"):
        on_meta_default(lambda: torch.arange(3).tolist())
    with pytest.raises(RuntimeError, match="meta"):
        on_meta_default(lambda: float(torch.tensor(2.0)))
    assert torch.equal(on_meta_default(_explicit, x), x) and _implicit(x).device.type == "cpu"
    assert torch.zeros(1).device.type == "cpu"  # the default is restored after a failing call too


# -- every kind on a small scene -------------------------------------------------------------------

def _flight(r: float, bearing: float, speed: float, heading: float, seconds: float, **life) -> dict:
    return {"start_range_m": r, "start_bearing_deg": bearing, "speed_mps": speed, "heading_deg": heading,
            "segments": [{"duration_s": seconds}], **life}


TWO = [{"name": "a", **_flight(4000.0, 130.0, 10.0, 20.0, 30.0)},
       {"name": "b", **_flight(7800.0, 140.0, 12.0, 0.0, 20.0, birth_s=8.0)}]
CLUTTER = {"per_scan": 3, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}


def _designed(methods: list[dict], targets=TWO, **over) -> dict:
    d = {"name": "device", "seed": 3, "mc_runs": 2, "block_runs": 2, "warmup_steps": 2,
         "random_streams": "per_product", "set_metrics": {"c_m": 300.0, "p": 2.0},
         "cases": [{"name": "c", "targets": targets}], "methods": methods}
    d.update(over)
    return d


def _streams() -> dict:
    """One target over 100 scans (the released networks' window), each single-target kind."""
    return _designed([{"name": "ekf", "kind": "ekf"}, {"name": "ukf", "kind": "ukf"}, {"name": "imm", "kind": "imm"},
                      {"name": "si_kf", "kind": "si_kf", "options": {"refine_steps": 2}},
                      {"name": "particle_filter", "kind": "particle_filter", "options": {"particles": 200}},
                      {"name": "learned", "kind": "learned", "checkpoint": str(ROOT / "models/released/rnn.pt")}],
                     targets=[{"name": "a", **_flight(4000.0, 130.0, 10.0, 20.0, 100.0)}], warmup_steps=10)


DETECTIONS = [{"name": "s_msjpda", "kind": "s_msjpda"},
              {"name": "s_msjpda own tracks", "kind": "s_msjpda", "options": {"initiation": "detections"}},
              {"name": "s_msjpda bias test", "kind": "s_msjpda",
               "options": {"initiation": "detections", "bias_window": 5.0, "bias_burn_in": 2}},
              {"name": "p_msjpda", "kind": "p_msjpda"},
              {"name": "p_msjpda relaxation", "kind": "p_msjpda", "options": {"m_best_search": "relaxation"}},
              {"name": "p_msjpda own tracks", "kind": "p_msjpda", "options": {"initiation": "detections"}},
              {"name": "bp", "kind": "bp"},
              {"name": "bp two scans", "kind": "bp", "options": {"init_scans": 2}},
              {"name": "smc_phd_pair", "kind": "smc_phd_pair",
               "options": {"particles_per_target": 100, "particles_per_birth": 50}},
              {"name": "known_association_kf_pair", "kind": "known_association_kf_pair"},
              {"name": "stonesoup", "kind": "stonesoup"}]


def _range_rate() -> dict:
    """Two targets (one born at 8 s) seen in range and range rate (the spherical initiator)."""
    return _designed(DETECTIONS, detections={"pd": 0.9, "components": ["range", "range_rate"], "clutter": CLUTTER})


def _azimuth() -> dict:
    """The same with azimuth (the fix initiator; BP seeds a target from each detection)."""
    methods = [m for m in DETECTIONS if m["kind"] in ("s_msjpda", "p_msjpda", "bp", "stonesoup")
               and m["name"] != "bp two scans"]
    phd = {"name": "smc_phd", "kind": "smc_phd", "options": {"particles_per_target": 100, "particles_per_birth": 50}}
    two_scans = {"name": "p_msjpda two scans azimuth", "kind": "p_msjpda",  # the multi-scan initiator around it
                 "options": {"initiation": "detections", "init_scans": 2, "fix_covariance": "unscented"}}
    nebp = {"name": "nebp azimuth", "kind": "nebp", "checkpoint": "nebp.pt"}  # learned corrections on BP
    return _designed([{**m, "name": f"{m['name']} azimuth"} for m in methods] + [two_scans, phd, nebp],
                     detections={"pd": 0.9, "clutter": CLUTTER})


MARGINAL = {"e_step": "marginal", "anneal": 3.0, "tolerance_m": 1.0}
"""PMHT's other E-step, with annealing and the early stop."""


def _from_start() -> dict:
    """Two targets alive from the first scan (the true-assignment references start every track there)."""
    targets = [TWO[0], {"name": "b", **_flight(7800.0, 140.0, 12.0, 0.0, 30.0)}]
    return _designed([{"name": "true_assignment", "kind": "true_assignment"},
                      {"name": "true_assignment_smoother", "kind": "true_assignment_smoother"},
                      {"name": "pmht", "kind": "pmht"}, {"name": "pmht_3d", "kind": "pmht_3d"},
                      {"name": "pmht_3d marginal", "kind": "pmht_3d", "options": MARGINAL}], targets=targets,
                     detections={"pd": 0.9, "clutter": CLUTTER})


def _pooled() -> dict:
    """The one_sky network (a single-frequency network) with lists pooled per receiver."""
    return _designed([{"name": "bp_3d", "kind": "bp_3d"},
                      {"name": "pmht_3d pooled", "kind": "pmht_3d", "options": {"initiation": "detections"}},
                      {"name": "pmht_3d pooled marginal", "kind": "pmht_3d",
                       "options": {**MARGINAL, "initiation": "detections"}}],
                     recipe=str(ROOT / "datasets/one_sky_fm.yaml"),
                     detections={"pd": 0.9, "illuminator_known": False, "clutter": {**CLUTTER, "per_scan": 4}})


SVN2 = {"name": "SVN2", "position_m": [-17745000.0, 1835500.0, 13077300.0], "velocity_mps": [2229.2, -519.2, 2058.0]}
SVN18 = {"name": "SVN18", "position_m": [6818700.0, -6090400.0, 18620300.0], "velocity_mps": [1654.7, -2019.3, -926.3]}


def _maps() -> dict:
    """tests/test_tbd_kinds.py's tiny scene: two satellites, a target at frames 2-3 of 4."""
    small = {"particles_min": 50, "particles_max": 200, "birth_particles": 200}
    return {"name": "device_maps", "seed": 3, "mc_runs": 2, "block_runs": 2, "warmup_steps": 0,
            "set_metrics": {"c_m": 1000.0, "p": 1.0},
            "rd_maps": {"transmitters": [SVN2, SVN18], "receiver_m": [0.0, 0.0, 0.0], "snr_db": [12.0, 12.0],
                        "maps": {"wavelength_m": 0.19, "doppler_cell_hz": 10.0, "altitude_m": 500.0},
                        "birth_box": {"x_m": [4500.0, 5500.0], "y_m": [2500.0, 3500.0], "vx_mps": [-25.0, -15.0],
                                      "vy_mps": [5.0, 15.0]}},
            "methods": [{"name": k, "kind": k, "options": dict(small) if k != "detect_then_track" else {}}
                        for k in ("modified_icmb", "pmb", "icmb", "detect_then_track")],
            "cases": [{"name": "c", "targets": [{"name": "t", "start_m": [5000.0, 3000.0], "velocity_mps": [-20.0, 10.0],
                                                 "birth_s": 1.0, "segments": [{"duration_s": 2.0}]}], "end_s": 4.0}]}


SCENES = {"streams": _streams, "range_rate": _range_rate, "azimuth": _azimuth, "from_start": _from_start,
          "pooled": _pooled, "maps": _maps}

NOT_YET = "not yet device-agnostic (issue 57 item 5)"
ROWS = [(scene, m["name"]) for scene, make in SCENES.items() for m in make()["methods"]]
XFAIL: dict[str, str] = {name: NOT_YET for name in ("stonesoup", "stonesoup azimuth")}
"""Rows whose meta check fails today (strict: one that passes fails the test until its mark goes)."""


def _nebp_checkpoint(folder: Path, scenario: dict) -> None:
    """An untrained NEBP checkpoint (its heads drawn, so the corrections act) for the scene's sensors."""
    from pmsr_nn.nets.nebp import NEBPNet, nebp_metadata, save_nebp_checkpoint

    plain = {**scenario, "methods": [m for m in scenario["methods"] if m["kind"] != "nebp"]}
    (folder / "plain.yaml").write_text(yaml.safe_dump(plain))
    det = prepare(load_scenario(folder / "plain.yaml")).cases[0].sensing.detection_model
    torch.manual_seed(0)
    net = NEBPNet(det.n_pairs, det.components, hidden=8)
    with torch.no_grad():
        for head in (net.edge_out, net.det_out):
            head.weight.copy_(torch.randn(head.weight.shape, generator=torch.Generator().manual_seed(1)) * 0.3)
    meta = nebp_metadata(det.geometry.to_dict(), list(det.components), list(det.noise_std), 1.0, 6, net,
                         [25000.0, 40.0, 1.0])
    save_nebp_checkpoint(folder / "nebp.pt", meta, net)


def prepared(name: str, folder: Path):
    """Scene ``name`` prepared in ``folder``: its setup and block 0's products of its first 2 runs."""
    d = SCENES[name]()
    if any(m["kind"] == "nebp" for m in d["methods"]):
        _nebp_checkpoint(folder, d)
    (folder / "s.yaml").write_text(yaml.safe_dump(d))
    setup = prepare(load_scenario(folder / "s.yaml"))
    _, products = draw_block(setup, 0, 0)
    return setup, _first_runs(products, 2)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Scene name -> :func:`prepared`, once per module."""
    cache = {}

    def get(name: str):
        if name not in cache:
            cache[name] = prepared(name, tmp_path_factory.mktemp(name))
        return cache[name]

    return get


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.dtype == b.dtype and a.shape == b.shape and a.device == b.device and \
        bool(torch.equal(a.isnan(), b.isnan()) and torch.equal(a.nan_to_num(), b.nan_to_num()))


@pytest.mark.parametrize("scene, method", [pytest.param(s, m, marks=pytest.mark.xfail(strict=True, reason=XFAIL[m]))
                                           if m in XFAIL else (s, m) for s, m in ROWS])
def test_a_kind_makes_every_tensor_on_its_inputs_device(scenes, scene, method):
    setup, products = scenes(scene)
    spec = next(m for m in setup.methods if m.name == method)
    case = setup.cases[0]
    plain = call_method(setup, spec, case, products, (3, 0, 0))
    meta = on_meta_default(call_method, setup, spec, case, products, (3, 0, 0))
    assert _same(meta.x, plain.x) and _same(meta.exists, plain.exists) and _same(meta.P, plain.P)
    assert _same(meta.existence, plain.existence) and meta.paired == plain.paired


def test_the_rows_a_kind_runs_on_any_device_are_those_that_pass(scenes):
    """``MethodKind.any_device`` (what ``pmsr evaluate --device cuda`` lets run) says yes for every
    row above that passes the meta check and no, with its reason, for every strict xfail."""
    from pmsr_nn.methods import runs_on_any_device

    seen = set()
    for scene in SCENES:
        setup, _ = scenes(scene)
        for spec in setup.methods:
            ok, why = runs_on_any_device(setup.kinds[spec.name], spec, setup.cases[0].sensing)
            assert ok == (spec.name not in XFAIL) and (ok or why == "" or why.startswith(" ")), (spec.name, why)
            seen.add(spec.kind)
    assert seen == set(registry()) - {"pcrb"}  # every kind but the bound (never called) has a row above


# -- what the meta check can not see ---------------------------------------------------------------

PACKAGE = ROOT / "pmsr_nn"
SCANNED = ("trackers", "filters", "methods", "tbd")
OUT_OF_SCOPE = {"methods/stonesoup.py", "methods/kind_metrics.py"}
"""Files of kinds that run on the CPU only (strict xfails above), and the kinds' metrics, which
read the estimates after the runner has moved them to the CPU."""
CPU_LITERAL = re.compile(r"""device\s*=\s*["']cpu["']|torch\.device\(\s*["']cpu["']\s*\)""")


def _sources(skip=frozenset()):
    for sub in SCANNED:
        for path in sorted((PACKAGE / sub).glob("*.py")):
            rel = f"{sub}/{path.name}"
            if rel not in skip:
                yield rel, path.read_text().splitlines()


def _calls(text: str, opener: str):
    """``(line number, the text after the call)`` of each ``opener(...)`` call in ``text``."""
    for m in re.finditer(re.escape(opener), text):
        depth, i = 1, m.end()
        while depth:
            depth += {"(": 1, ")": -1}.get(text[i], 0)
            i += 1
        yield text.count("\n", 0, m.start()) + 1, text[i:i + 4]


def test_no_tensor_is_made_on_a_literal_cpu_without_saying_why():
    """A literal CPU device (``device="cpu"``, ``torch.device("cpu")``) in the trackers, filters,
    methods and track-before-detect only with a comment on its line saying why (``# device: ...``,
    e.g. a check of the geometry alone); ``.cpu()`` on the way to numpy is the next test's."""
    found = [f"{rel}:{i + 1}: {line.strip()}" for rel, lines in _sources() for i, line in enumerate(lines)
             if CPU_LITERAL.search(line.split("#")[0]) and "# device:" not in line]
    assert not found, found


def test_numpy_is_read_from_the_cpu_and_its_tensors_go_back_to_the_device():
    """Outside the CPU-only files: every ``.numpy()`` is a ``.cpu().numpy()`` (a no-op on the CPU,
    a copy from a GPU) and every ``torch.from_numpy(...)`` is moved ``.to(...)`` the tracker's
    device, unless its line says ``# cpu:`` why it stays there."""
    bad = []
    for rel, lines in _sources(OUT_OF_SCOPE):
        text = "\n".join(lines)
        for i, line in enumerate(lines):
            code = line.split("#")[0]
            if re.search(r"(?<!\.cpu\(\))\.numpy\(\)", code) and "# cpu:" not in line:
                bad.append(f"{rel}:{i + 1}: {line.strip()}")
        for n, after in _calls(text, "torch.from_numpy("):
            if not after.startswith(".to(") and "# cpu:" not in lines[n - 1]:
                bad.append(f"{rel}:{n}: {lines[n - 1].strip()}")
    assert not bad, bad


def test_the_static_checks_find_what_they_look_for():
    assert CPU_LITERAL.search('x = torch.zeros(3, device="cpu")') and CPU_LITERAL.search("torch.device('cpu')")
    assert not CPU_LITERAL.search("y = torch.zeros(3, device=x.device)")
    assert [a for _, a in _calls("a = torch.from_numpy(f(b)).to(d)\nc = torch.from_numpy(e) + 1", "torch.from_numpy(")] \
        == [".to(", " + 1"]


# -- the runner on another device ------------------------------------------------------------------

def test_the_runner_moves_a_call_to_the_device_and_its_estimates_back(scenes, monkeypatch):
    """On ``setup.device`` other than the CPU, :func:`call_method` hands the kind its product,
    lives, models and sensing on that device and gives the estimates back on the CPU."""
    import dataclasses

    from pmsr_nn.trackers.base import Estimates

    setup, products = scenes("range_rate")
    spec = setup.methods[0]
    seen = {}

    def run(call):
        seen.update(z=call.product.scans.z.device, prior=call.product.prior.x.device, alive=call.alive.device,
                    R=call.models.R.device, sd=call.sensing.prior_sd.device)
        B, K, N = 2, call.alive.shape[0], call.alive.shape[1]
        return Estimates(torch.zeros(B, K, N, 6, device="meta"), torch.zeros(B, K, N, dtype=torch.bool, device="meta"))

    kind = dataclasses.replace(setup.kinds[spec.name], run=run)
    moved = dataclasses.replace(setup, device="meta", kinds={**setup.kinds, spec.name: kind})
    with pytest.raises(NotImplementedError, match="meta"):  # the estimates are brought back: from meta, no data
        call_method(moved, spec, moved.cases[0], products, (3, 0, 0))
    assert {str(d) for d in seen.values()} == {"meta"} and len(seen) == 5
    assert products["detections"].scans.z.device.type == "cpu"  # the draws stay where they were made


def test_the_maps_product_hands_its_maps_on_its_device_and_draws_them_on_the_cpu(scenes):
    """The ``rd_maps`` product draws a frame's maps when a kind asks, where the truth is (the CPU,
    so every device reads the same maps), and hands them on the device the runner moved it to
    (:meth:`~pmsr_nn.methods.MethodCall.to`), whose ``device`` the map kinds follow."""
    setup, products = scenes("maps")
    maps = products["rd_maps"]
    call = MethodCall(setup.methods[0], maps, setup.cases[0].alive, setup.models, setup.cases[0].sensing)
    moved = call.to("meta").product
    assert (maps.device.type, moved.device.type, moved.truth_x.device.type) == ("cpu", "meta", "cpu")
    frame, there = maps.frame(1), moved.frame(1)
    assert there.device.type == "meta" and (there.shape, there.dtype) == (frame.shape, frame.dtype)
    assert moved.first_scans(2).device.type == "meta" and torch.equal(maps.to("cpu").frame(1), frame)


def test_kinds_that_run_on_the_cpu_only_are_refused_on_another_device_in_one_line(tmp_path):
    d = _designed([{"name": "S", "kind": "s_msjpda"}, {"name": "stone", "kind": "stonesoup"},
                   {"name": "own", "kind": "s_msjpda", "options": {"initiation": "detections"}},
                   {"name": "P", "kind": "pmht"}, {"name": "phd", "kind": "smc_phd"},
                   {"name": "stone 2", "kind": "stonesoup"}], targets=[TWO[0]],
                  detections={"pd": 0.9, "clutter": CLUTTER})
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(d))
    sc = load_scenario(tmp_path / "s.yaml")
    prepare(sc)  # the CPU runs every kind
    with pytest.raises(ConfigError) as err:
        prepare(sc, "cuda")
    text = str(err.value)
    # the fix initiator, PMHT, the SMC-PHD: anywhere
    assert "\n" not in text and not any(f"'{m}'" in text for m in ("S", "own", "P", "phd"))
    why = "runs on the CPU only (Stone Soup is NumPy); --device cuda is refused (use --device cpu)"
    assert all(f"method '{m}': kind stonesoup {why}" in text for m in ("stone", "stone 2"))  # two in one line
    maps = _maps()  # the map kinds: anywhere (their maps drawn on the CPU, handed on the device)
    (tmp_path / "maps.yaml").write_text(yaml.safe_dump(maps))
    assert prepare(load_scenario(tmp_path / "maps.yaml"), "cuda").device == "cuda"
    d["methods"] = d["methods"][:1]
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(d))
    assert prepare(load_scenario(tmp_path / "s.yaml"), "cuda").device == "cuda"  # nothing refused, nothing run yet
