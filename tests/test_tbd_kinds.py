"""Track-before-detect filters as method kinds of an ordinary scenario (issue 35): the maps of a
scenario's ``rd_maps`` section (any receiver, several targets, fixed or moving transmitters), the
kinds ``pmb`` / ``icmb`` / ``modified_icmb`` / ``detect_then_track`` through the one runner
(prepare, blocks, warm-up, shards, merge, the report's Remote Sensing figures) and their refusals."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from pmsr_nn.cli import main
from pmsr_nn.errors import ConfigError
from pmsr_nn.harness import evaluate, merge
from pmsr_nn.harness.run import blocks
from pmsr_nn.harness.run.blocks import call_method, draw_block, run_blocks
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import scenario_from_dict
from pmsr_nn.tbd.maps import C, MapGrid, MapSpec, power_ratio, range_doppler, simulate_frame
from pmsr_nn.tbd.multibernoulli import BirthBox
from pmsr_nn.tbd.scene import MapScene, RangeDopplerMaps

ROOT = Path(__file__).resolve().parents[1]
SVN2 = {"name": "SVN2", "position_m": [-17745000.0, 1835500.0, 13077300.0], "velocity_mps": [2229.2, -519.2, 2058.0]}
SVN18 = {"name": "SVN18", "position_m": [6818700.0, -6090400.0, 18620300.0], "velocity_mps": [1654.7, -2019.3, -926.3]}
SMALL = {"particles_min": 50, "particles_max": 200, "birth_particles": 200}
TARGET = {"name": "t", "start_m": [5000.0, 3000.0], "velocity_mps": [-20.0, 10.0], "birth_s": 1.0,
          "segments": [{"duration_s": 2.0}]}


def tiny(**over) -> dict:
    """Two satellites seen from the origin, one target present at frames 2-3 of 4 (the built-in
    recipe's 1 s scans), a birth box around it, 12 dB maps, a small particle budget."""
    d = {"name": "tbd_tiny", "seed": 3, "mc_runs": 2, "block_runs": 1, "warmup_steps": 0,
         "set_metrics": {"c_m": 1000.0, "p": 1.0},
         "rd_maps": {"transmitters": [SVN2, SVN18], "receiver_m": [0.0, 0.0, 0.0], "snr_db": [12.0, 12.0],
                     "maps": {"wavelength_m": 0.19, "doppler_cell_hz": 10.0, "altitude_m": 500.0},
                     "birth_box": {"x_m": [4500.0, 5500.0], "y_m": [2500.0, 3500.0], "vx_mps": [-25.0, -15.0],
                                   "vy_mps": [5.0, 15.0]}},
         "methods": [{"name": "m", "kind": "modified_icmb", "options": dict(SMALL)}],
         "cases": [{"name": "c", "targets": [dict(TARGET)], "end_s": 4.0}]}
    d.update(copy.deepcopy(over))
    return d


def write(tmp_path: Path, d: dict, name: str = "t.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return path


# ------------------------------------------------------------------ the maps


def test_range_doppler_for_a_receiver_away_from_the_origin_matches_direct_geometry():
    """Excess bistatic range against numpy float64 distances |p - t| + |p - r| - |t - r| (the
    satellites' 20,000 km cancel to well under a millimetre only in the cancellation-free form;
    the direct form's own rounding, ~4e-9 m per 2e7 m distance, is the tolerance), Doppler
    against a central finite difference of the range (exact for the range's quadratic part:
    step 1e-3 s, error ~1e-9 Hz), and a receiver at the origin bit for bit as none."""
    spec = MapSpec(wavelength_m=0.19)
    tx = torch.tensor([SVN2["position_m"], SVN18["position_m"], [3000.0, -2000.0, 0.0]], dtype=torch.float64)
    rx = torch.tensor([[12_000.0, -7_000.0, 30.0], [-4_000.0, 2_500.0, 0.0], [500.0, 800.0, 0.0]], dtype=torch.float64)
    x = torch.tensor([[140e3, -30.0, 2e3, 100.0], [9e3, -45.0, -4e3, 85.0]], dtype=torch.float64)
    rng, dop = range_doppler(x, tx, spec, rx)
    p = np.stack([x[:, 0].numpy(), x[:, 2].numpy(), np.full(2, spec.altitude_m)], -1)[:, None]
    t, r = tx.numpy()[None], rx.numpy()[None]
    direct = np.linalg.norm(p - t, axis=-1) + np.linalg.norm(p - r, axis=-1) - np.linalg.norm(t - r, axis=-1)
    np.testing.assert_allclose(rng.numpy(), direct, rtol=0, atol=1e-7 * 20)
    h = 1e-3
    moved = lambda s: torch.stack([x[:, 0] + s * x[:, 1], x[:, 1], x[:, 2] + s * x[:, 3], x[:, 3]], -1)
    rate = (range_doppler(moved(h), tx, spec, rx)[0] - range_doppler(moved(-h), tx, spec, rx)[0]) / (2 * h)
    np.testing.assert_allclose(dop.numpy(), (-rate / spec.wavelength_m).numpy(), rtol=0, atol=1e-4)
    # per-map wavelengths divide per map
    lam = torch.tensor([0.19, 0.5, 3.0], dtype=torch.float64)
    np.testing.assert_allclose(range_doppler(x, tx, spec, rx, lam)[1].numpy(), (dop * 0.19 / lam).numpy(), rtol=1e-12)
    zero = torch.zeros(3, 3, dtype=torch.float64)
    a, b = range_doppler(x, tx, spec), range_doppler(x, tx, spec, zero)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


@pytest.mark.integration
def test_two_targets_give_two_lobes_each_at_its_snr_with_its_own_phase():
    """Two targets at integer cells far apart (other target's response exactly zero there) in
    8 dB and 3 dB maps, 3,000 runs x 2 maps: at a target's cell |z|^2 / sigma^2 is non-central
    chi-square (2 degrees of freedom, halved): mean 1 + SNR, variance 1 + 2 SNR; the sample mean
    is within 4 standard errors of it. A noise cell's mean is 1 (variance 1). The two targets'
    complex values are uncorrelated (own phases: E[z_a conj(z_b)] = 0, variance (1 + S_a)(1 + S_b)).
    A target marked absent adds nothing (its cell's mean is 1)."""
    grid = MapGrid(torch.zeros(2, dtype=torch.float64), torch.zeros(2, dtype=torch.float64), 41, 101, 60.0, 10.0)
    spec = MapSpec(wavelength_m=0.19, noise_power=2.0)
    B = 3000
    cells = torch.tensor([[10.0, 20.0], [30.0, 70.0], [20.0, 45.0]], dtype=torch.float64)  # (target, [d, u])
    rng = (cells[:, 1] * 60.0).expand(B, 2, 3).clone()  # (B, P, N)
    dop = (cells[:, 0] * 10.0).expand(B, 2, 3).clone()
    present = torch.tensor([True, True, False]).expand(B, 3)
    snr_db = torch.tensor([8.0, 3.0], dtype=torch.float64)
    maps = simulate_frame(rng, dop, present, snr_db, grid, spec, torch.Generator().manual_seed(7))
    z = maps.to(torch.complex128) / math.sqrt(spec.noise_power)
    snr = 10 ** (snr_db / 10)
    at = lambda n: z[:, :, int(cells[n, 0]), int(cells[n, 1])]  # (B, P)
    for n in (0, 1):
        power = at(n).abs() ** 2
        se = torch.sqrt((1 + 2 * snr) / B)
        assert bool(((power.mean(0) - (1 + snr)).abs() < 4 * se).all()), (n, power.mean(0))
        # the lobe: the strongest mean cell of the target's neighbourhood is its own
        d, u = int(cells[n, 0]), int(cells[n, 1])
        mean = (z[:, :, d - 3:d + 4, u - 8:u + 9].abs() ** 2).mean(0)
        assert all(int(mean[p].argmax()) == 3 * 17 + 8 for p in range(2))
    cross = (at(0) * at(1).conj()).mean(0)
    assert bool((cross.abs() < 4 * torch.sqrt((1 + snr) * (1 + snr) / B)).all()), cross
    for cell in ((2, 0), (40, 100)):  # the absent target's cell, a corner
        power = (z[:, :, cell[0], cell[1]] if cell != (2, 0) else at(2)).abs() ** 2
        assert bool(((power.mean(0) - 1).abs() < 4 / math.sqrt(B)).all())


def test_maps_of_a_scene_hold_each_living_target_at_its_cell():
    """A fixed transmitter and a receiver away from the origin (an FM pair), two targets with
    their own lives, 30 dB: in every frame the strongest cell near each living target's
    fractional cell is the nearest one (+-1 cell), and a dead target's cell is noise."""
    box = BirthBox((-2000.0, 6000.0), (1000.0, 9000.0), (-30.0, 30.0), (-30.0, 30.0))
    scene = MapScene(("tx1-rx1",), ((0.0, 0.0, 0.0),), ((0.0, 0.0, 0.0),), ((-7000.0, -3000.0, 0.0),), (C / 100e6,),
                     (30.0,), MapSpec(sample_rate_hz=2e6, chip_rate_hz=0.5e6, doppler_cell_hz=0.5, altitude_m=300.0),
                     box, 3, 1.0)
    K = 3
    x0 = torch.tensor([[0.0, 20.0, 3000.0, 5.0], [5000.0, -10.0, 8000.0, -20.0]], dtype=torch.float64)  # (N, 4)
    x = torch.stack([x0 + k * torch.stack([x0[:, 1], torch.zeros(2), x0[:, 3], torch.zeros(2)], -1) for k in range(K)])
    alive = torch.tensor([[True, True], [True, True], [True, False]])
    truth = torch.where(alive[..., None], x, torch.full_like(x, float("nan")))[None]  # (1, K, 2, 4)
    product = RangeDopplerMaps(scene, truth, alive, seed=11)
    grid = scene.grid
    for k in range(K):
        power = product.frame(k)[0, 0].abs() ** 2
        d, u = scene.cells(x[k], k)  # (2, 1)
        for n in range(2):
            dc, uc = int(round(float(d[n, 0]))), int(round(float(u[n, 0])))
            win = power[dc - 3:dc + 4, uc - 6:uc + 7]
            r, c = divmod(int(win.argmax()), win.shape[1])
            if alive[k, n]:
                assert abs(r - 3) <= 1 and abs(c - 6) <= 1 and float(win.max()) > 100, (k, n)
            else:
                assert float(power[dc, uc]) < 30, (k, n)  # 30 dB would give ~1000; noise exceeds 30 with p = e^-30
    # the same maps whatever is asked first, and a selection of runs is a slice of the block's
    two = RangeDopplerMaps(scene, truth.expand(2, K, 2, 4), alive, seed=11)
    assert torch.equal(two.frame(2)[:1], two.runs(slice(0, 1)).frame(2))
    after = two.frame(1)  # asked after frame 2 (and its selection), of one product ...
    fresh = RangeDopplerMaps(scene, truth.expand(2, K, 2, 4), alive, seed=11).frame(1)  # ... first, of another
    assert torch.equal(after, fresh)
    # and the maps are drawn: another seed, another frame and the other run give other noise
    other = RangeDopplerMaps(scene, truth.expand(2, K, 2, 4), alive, seed=12).frame(1)
    assert not torch.equal(after, other) and not torch.equal(after, two.frame(2)) and not torch.equal(after[0], after[1])


# ------------------------------------------------------------------ through the runner


@pytest.mark.parametrize("estimator", ["max", "bootstrap"])
def test_a_tbd_kind_runs_through_prepare_and_blocks_and_finds_the_target(tmp_path, estimator):
    """25 dB maps, a 1x1 sub-area, births around the target: the modified ICMB detects it in every
    run at every frame it is present and at none before it is born; its tracks are scored like
    every tracker's (OSPA, GOSPA, matched RMSE) besides the per-frame figures. With the seed's SNR
    estimate a frame after it died its tracks have faded (a component persists at most a frame:
    survival 0.95 and maps without it). The bias-corrected estimate does not promise that: without
    the target it falls to the noise peaks' level, lower than the seed's, under which a target is
    harder to reject (measured over 20 runs: detected 0.5 / 0.2 of the runs one / two frames
    after death, against 0.2 / 0)."""
    d = tiny(mc_runs=4, block_runs=2)
    d["rd_maps"]["snr_db"] = [25.0]
    d["rd_maps"]["birth_box"] = {"x_m": [4800.0, 5200.0], "y_m": [2800.0, 3200.0], "vx_mps": [-23.0, -17.0],
                                 "vy_mps": [7.0, 13.0]}
    d["methods"][0]["options"] = {"particles_min": 200, "particles_max": 800, "birth_particles": 2000, "subarea_half": 0,
                                  "snr_estimator": estimator}
    d["cases"][0]["targets"][0]["segments"] = [{"duration_s": 4.0}]
    d["cases"][0]["end_s"] = 7.0
    sc = scenario_from_dict(d, tmp_path)
    setup = prepare(sc)
    case = setup.cases[0]
    assert case.info["rd_maps"]["present"] == [False, True, True, True, True, False, False]
    assert case.bounds is None  # the recipe's PCRB is not the maps'
    assert setup.cases[0].sensing.rd_maps.snr_db == (25.0, 25.0)
    bs = run_blocks(setup, range(2), progress=False)
    from pmsr_nn.harness.results.finalise import finalise

    row = finalise(setup, bs)["c"]["methods"]["m"]
    t = row["tbd"]
    assert t["detected_frame_rate"][:5] == [0.0, 1.0, 1.0, 1.0, 1.0]
    if estimator == "max":
        assert t["detected_frame_rate"][6] == 0.0 and t["existence"][6] < 0.1
        assert t["false_alarm_rate_absent"] <= 1 / 3  # at most the frame after it died
    assert max(t["rms_pos_m"][1:5]) < 300.0  # inside the range triangle's half-width (293 m of path)
    snr = np.asarray(t["snr_db"])  # (K, S): the online estimate, biased up on a 1x1 sub-area (the largest of the
    assert snr.shape == (7, 2) and bool((snr[2:5] > 22.0).all())  # particles' ML amplitudes) but near the 25 dB
    assert row["initiation"] == "detections" and row["confirmed_tracks_per_target"] >= 1.0
    assert row["rmse_pos_m"] < 300.0 and row["ospa_m"] < 300.0  # one target, found at every frame of its life
    assert t["power_ratio"] == pytest.approx(power_ratio(0, MapSpec(sample_rate_hz=5e6).lobe_cells))


def test_the_warm_up_calls_each_method_once_on_the_first_run_untimed(tmp_path, monkeypatch):
    """The runner's warm-up (one call per method on run 0 of its first case, generator words
    ``(seed, 2**30)``) reads a selection of the block's maps equal to run 0's; the timed calls
    then get the whole block with ``(seed, case, block)``; a method a case does not name is not
    called in it. A second evaluation in the same process warms nothing again."""
    monkeypatch.setattr(blocks, "WARMED", set())  # as in a fresh process
    d = tiny(mc_runs=4, block_runs=2)
    d["methods"].append({"name": "p", "kind": "pmb", "options": dict(SMALL)})
    d["cases"].append({"name": "only_p", "targets": [dict(TARGET)], "end_s": 4.0, "methods": ["p"]})
    setup = prepare(scenario_from_dict(d, tmp_path))
    calls = []
    for name, kind in setup.kinds.items():
        def spy(call, run=kind.run):
            calls.append((call.spec.name, call.product.B, call.seed, call.product.frame(1)[0].clone()))
            return run(call)
        setup.kinds[name] = dataclasses.replace(kind, run=spy)
    run_blocks(setup, range(1), progress=False)
    assert [(n, b, s) for n, b, s, _ in calls] == [("m", 1, (3, 1 << 30)), ("p", 1, (3, 1 << 30)),
                                                  ("m", 2, (3, 0, 0)), ("p", 2, (3, 0, 0)), ("p", 2, (3, 1, 0))]
    assert torch.equal(calls[0][3], calls[2][3])  # the warm-up's run 0 maps are the block's run 0 maps
    assert blocks.WARMED == {blocks.warm_key(m) for m in setup.methods}  # each method warmed once, in its first case
    calls.clear()
    run_blocks(setup, range(1, 2), progress=False)  # e.g. the next block of a bank, or a second study
    assert [s for _, _, s, _ in calls] == [(3, 0, 1), (3, 0, 1), (3, 1, 1)]


def test_a_map_kind_warms_up_on_the_first_frames_only(tmp_path, monkeypatch):
    """On a case longer than the warm-up's slice, a map kind warms up once, on the frames up to
    ``WARM_SCANS`` after the first birth of run 0: it reads its frame count from the product it is
    handed, not from the case (which made the slice fail and the warm-up run the whole first run)."""
    setup = prepare(scenario_from_dict(tiny(cases=[{"name": "c", "targets": [dict(TARGET)], "end_s": 40.0}]),
                                       tmp_path))
    case, spec = setup.cases[0], setup.methods[0]
    K = case.alive.shape[0]
    W = int(case.alive.any(1).nonzero()[0]) + blocks.WARM_SCANS
    assert K > W  # the slice is shorter than the case
    _, products = draw_block(setup, 0, 0)
    kind, calls = setup.kinds[spec.name], []

    def spy(call, run=kind.run):
        calls.append((call.product.B, call.product.scene.frames))
        return run(call)
    monkeypatch.setitem(setup.kinds, spec.name, dataclasses.replace(kind, run=spy))
    blocks.warm_up(setup, spec, case, products)
    assert calls == [(1, W)]


def test_shards_merge_to_exactly_the_unsharded_figures(tmp_path):
    """Shards 1/2 and 2/2 of a TBD scenario merged give the unsharded results.json bit for bit
    (timings aside), the Remote Sensing per-frame figures included."""
    path = write(tmp_path, tiny(mc_runs=2, block_runs=1))
    a = evaluate(path, tmp_path / "a", progress=False)
    evaluate(path, tmp_path / "s1", shard=(1, 2), progress=False)
    evaluate(path, tmp_path / "s2", shard=(2, 2), progress=False)
    merged = merge([tmp_path / "s2", tmp_path / "s1"], tmp_path / "m")

    def strip(res):
        return {c: {m: {k: v for k, v in r.items() if k != "seconds_per_run"} for m, r in case["methods"].items()}
                for c, case in res["cases"].items()}

    assert json.dumps(strip(merged), sort_keys=True) == json.dumps(strip(a), sort_keys=True)
    assert "tbd" in a["cases"]["c"]["methods"]["m"] and len(a["cases"]["c"]["methods"]["m"]["tbd"]["ospa_frame_m"]) == 4
    assert (tmp_path / "m" / "c_maps.png").is_file()  # run 0's maps travel in shard 1's examples


@pytest.mark.integration
@pytest.mark.figures
def test_pmsr_evaluate_writes_the_remote_sensing_figures(tmp_path):
    """`pmsr evaluate` on a tiny TBD scenario: per-frame figures for every method, Table 2 beside
    the paper's rows, and the figures the report names (port of the former study's test)."""
    import shutil

    d = tiny(mc_runs=1, block_runs=1)
    d["methods"] = [{"name": "m5", "kind": "modified_icmb", "options": dict(SMALL)},
                    {"name": "m1", "kind": "modified_icmb", "options": {**SMALL, "subarea_half": 0}},
                    {"name": "dtt", "kind": "detect_then_track", "options": {**SMALL, "pfa": 1e-4}}]
    d["rd_maps"]["table_frame"] = 3
    d["reference"] = {"file": "paper_tables.json", "subarea_table": "remotesensing2020_icmb.table2_subarea"}
    shutil.copy(ROOT / "evaluate" / "reference" / "paper_tables.json", tmp_path)
    path = write(tmp_path, d)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "pmsr_nn.cli", "evaluate", str(path), "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "detected %" in proc.stdout and "m5" in proc.stdout  # the terminal's track-before-detect table
    res = json.loads((out / "results.json").read_text())
    assert res["kind"] == "sampled"  # a case only maps are formed of has no PCRB (the recipe's model is not the maps')
    case = res["cases"]["c"]
    assert case["rd_maps"]["present"] == [False, True, True, False] and case["rd_maps"]["table_frame"] == 3
    # the map bound (pmsr_nn.tbd.bound, tested in tests/test_tbd_bound.py): NaN while no target lives, falling as
    # frames add information, and what the report's ratio column divides by
    bound = case["rd_maps"]["bound_pos_m"]
    assert math.isnan(bound[0]) and math.isnan(bound[3]) and 0 < bound[2] < bound[1]
    assert set(case["methods"]) == {"m5", "m1", "dtt"}
    m5 = case["methods"]["m5"]["tbd"]
    assert len(m5["detected_frame_rate"]) == 4 and len(m5["snr_db"]) == 4 and len(m5["snr_db"][0]) == 2
    assert m5["power_ratio"] == pytest.approx(power_ratio(2, MapSpec(sample_rate_hz=5e6).lobe_cells))
    assert m5["update"] == "ascending" and m5["snr"] == "estimated (bootstrap)" and len(m5["median_pos_err_m"]) == 4
    dtt = case["methods"]["dtt"]["tbd"]
    assert dtt["power_ratio"] is None and dtt["update"] == "detect-then-track" and dtt["snr"] == "true"
    assert "tbd.detected_frame_rate" in res["definitions"] and res["settings"]["set_metrics"] == {"c_m": 1000.0, "p": 1.0}
    report = (out / "report.md").read_text()
    assert "| m1 | 1x1 |" in report and "| 46.7 | 36.86 | 51.9 |" in report  # ours beside the paper's row
    assert "| m5 | own, from rd_maps |" in report  # the tracks table names what map rows start tracks from
    assert f"Map bound: {bound[2]:.1f} m at the last frame with a target" in report
    held, spare = m5["targets_held_rate"], m5["unassigned_tracks_per_frame"]
    assert 0.0 <= held <= 1.0 and f"| {100 * m5['detected_rate_present']:.1f} | {100 * held:.1f} | {spare:.2f} |" in report
    rms = case["methods"]["m5"]["tbd"]["rms_pos_last_present_m"]
    assert f"| {rms:.1f} | {case['methods']['m5']['tbd']['median_pos_err_last_present_m']:.1f} | {rms / bound[2]:.1f} |" \
        in report
    assert f"where the map bound is {bound[2]:.1f} m" in proc.stdout
    for fig in ("detected", "tbd_rms", "snr", "subarea", "existence", "ospa", "maps"):
        assert (out / f"c_{fig}.png").stat().st_size > 10_000, fig
        assert f"c_{fig}.png" in report


def test_fixed_transmitters_of_the_recipe_make_one_map_per_pair(tmp_path):
    """Without listed transmitters every pair of the recipe makes a map (the built-in recipe: one
    650 MHz transmitter, three receivers), each on its transmitter's carrier, receivers where the
    recipe puts them; one SNR value serves every map."""
    d = tiny()
    d["rd_maps"] = {"snr_db": [15.0], "maps": {"sample_rate_hz": 2e6, "chip_rate_hz": 0.5e6, "doppler_cell_hz": 0.5,
                                                "altitude_m": 300.0}, "birth_box": d["rd_maps"]["birth_box"]}
    setup = prepare(scenario_from_dict(d, tmp_path))
    scene = setup.cases[0].sensing.rd_maps
    assert scene.names == ("tx1-rx1", "tx1-rx2", "tx1-rx3") and scene.snr_db == (15.0,) * 3
    assert scene.wavelength_m == (C / 650e6,) * 3
    assert scene.rx_position_m[0] == pytest.approx((7560.0 * math.sin(math.radians(240)), 7560.0 * math.cos(math.radians(240)), 0.0))
    assert torch.equal(scene.tx[0], scene.tx[-1])  # fixed
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[0], setup.cases[0], products, (3, 0, 0))
    assert est.x.shape[-1] == 6 and not est.paired and est.extras["tbd_snr_db"].shape == (1, 4, 3)


# ------------------------------------------------------------------ refusals


def _refused(tmp_path: Path, d: dict, capsys) -> str:
    path = write(tmp_path, d)
    out = tmp_path / "out"
    assert main(["evaluate", str(path), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pmsr: error: ") and "\n" not in err
    assert not out.exists() and not list(tmp_path.glob("out*"))  # nothing written
    return err


def test_a_tbd_method_without_maps_is_refused(tmp_path, capsys):
    d = tiny()
    del d["rd_maps"]
    err = _refused(tmp_path, d, capsys)
    assert "method 'm' (kind modified_icmb) reads range-Doppler maps" in err and "add an rd_maps section" in err


def test_a_target_leaving_the_maps_is_refused(tmp_path, capsys):
    d = tiny()
    d["cases"][0]["targets"][0]["start_m"] = [8000.0, 3000.0]  # 2.5 km outside the birth box the maps cover
    err = _refused(tmp_path, d, capsys)
    assert "case 'c': target 't' leaves the maps at frame 2" in err and "widen rd_maps.birth_box" in err


def test_a_birth_box_outside_the_maps_is_refused(tmp_path, capsys):
    d = tiny()
    d["rd_maps"]["map_extent"] = {"range_m": [0.0, 3000.0], "doppler_hz": [-100.0, 100.0]}
    err = _refused(tmp_path, d, capsys)
    assert "the birth box is outside the map's coverage for SVN2" in err and "widen rd_maps.map_extent" in err


def test_maps_too_coarse_to_localise_are_refused(tmp_path, capsys):
    """A 1 km birth box seen through an FM channel's 1.5 km range cells spans under 4 of them."""
    d = tiny()
    d["rd_maps"]["maps"]["bandwidth_hz"] = 1.0e5
    err = _refused(tmp_path, d, capsys)
    assert "map SVN18: its range cells of 1499 m give 0.9 cells" in err and "fewer than 4" in err and "maps.bandwidth_hz" in err


def test_a_bandwidth_sets_the_range_cells_and_lobe():
    """``bandwidth_hz`` B: a range triangle of half-width c / B over cells of c / 2B; with either rate
    it sets given otherwise, one line (the rates it sets, as a recorded spec holds them, reload)."""
    dvbt = MapSpec(bandwidth_hz=7.6e6, wavelength_m=0.5)
    assert dvbt.range_cell_m == pytest.approx(C / 15.2e6) and dvbt.lobe_cells == pytest.approx(2.0)
    assert MapSpec(**{**dataclasses.asdict(dvbt)}) == dvbt
    with pytest.raises(ConfigError, match="give bandwidth_hz, or sample_rate_hz and chip_rate_hz, not both"):
        MapSpec(bandwidth_hz=1.0e5, sample_rate_hz=3.0e5)
    assert MapSpec().sample_rate_hz == 5.0e6 and MapSpec().chip_rate_hz == 1.023e6  # the seed's, without one


@pytest.mark.parametrize("transmitters", [True, False])
def test_an_snr_list_of_the_wrong_length_is_refused(tmp_path, capsys, transmitters):
    d = tiny()
    d["rd_maps"]["snr_db"] = [8.0, 9.0, 10.0]
    if not transmitters:  # the built-in recipe's 3 pairs: 2 values fit neither
        del d["rd_maps"]["transmitters"], d["rd_maps"]["receiver_m"]
        d["rd_maps"]["snr_db"] = [8.0, 9.0]
    err = _refused(tmp_path, d, capsys)
    want = "one per map (2 transmitters), got 3" if transmitters else "one per map (3 maps: every transmitter-receiver pair"
    assert "rd_maps.snr_db needs one value or" in err and want in err


def test_a_case_override_is_checked_like_the_section(tmp_path, capsys):
    d = tiny()
    d["cases"][0]["rd_maps"] = {"snr_db": [8.0, 9.0, 10.0]}
    assert "case 'c': rd_maps" in _refused(tmp_path, d, capsys)
    d = tiny()
    d["cases"][0]["methods"] = ["nope"]
    assert "case 'c': methods ['nope'] are not methods of the scenario" in _refused(tmp_path, d, capsys)


def test_every_refusal_of_a_file_comes_in_one_message(tmp_path, capsys):
    """Two methods without maps and a sub-area larger than another case's maps: one line naming all."""
    d = tiny()
    del d["rd_maps"]
    d["methods"].append({"name": "p", "kind": "pmb", "options": dict(SMALL)})
    err = _refused(tmp_path, d, capsys)
    assert "method 'm' (kind modified_icmb)" in err and "method 'p' (kind pmb)" in err and err.count("; ") >= 1
    d = tiny()
    d["methods"][0]["options"]["subarea_half"] = 400
    d["cases"][0]["targets"][0]["start_m"] = [8000.0, 3000.0]
    err = _refused(tmp_path, d, capsys)
    assert "leaves the maps" in err and "sub-area 801x801 is larger than the maps" in err


def test_option_and_schema_errors_name_the_method_or_key(tmp_path, capsys):
    d = tiny()
    d["methods"][0]["options"]["particles_min"] = 500
    assert "method 'm': particles_min (500) must be at least 1 and at most particles_max (200)" in \
        _refused(tmp_path, d, capsys)
    d = tiny()
    d["methods"][0] = {"name": "i", "kind": "icmb", "options": {"order": "sideways"}}
    assert "option order must be one of ascending, descending, given" in _refused(tmp_path, d, capsys)
    d = tiny()
    d["rd_maps"]["snr_db"] = [float("nan"), 12.0]
    assert "rd_maps.snr_db[0]: expected a finite number" in _refused(tmp_path, d, capsys)
    d = tiny()
    del d["rd_maps"]["receiver_m"]
    assert "give rd_maps.receiver_m" in _refused(tmp_path, d, capsys)
    d = tiny()
    d["kind"] = "tbd"
    assert "'kind: tbd' study files are gone" in _refused(tmp_path, d, capsys)


def test_the_shipped_scenario_is_the_seeds_set_up():
    """evaluate/remotesensing2020_icmb.yaml: a designed scenario whose case 'mixed' is the seed's
    Section 4 (satellites, 20 frames of 2 s, target present at frames 5-16 from (140, 0) km at
    (-30, 100) m/s, 8/9/10 dB) and whose other cases change the maps and run one method."""
    from pmsr_nn.harness.scenario.schema import load_scenario

    sc = load_scenario(ROOT / "evaluate" / "remotesensing2020_icmb.yaml")
    setup = prepare(sc)
    mixed = setup.cases[0]
    assert mixed.steps == 20 and mixed.alive[:, 0].nonzero().flatten().tolist() == list(range(4, 16))
    x = mixed.truth.x[4, 0]
    assert x[[0, 3]].tolist() == [140_000.0, 0.0] and x[[1, 4]].tolist() == [-30.0, 100.0]
    assert mixed.truth.x[15, 0, 0].item() == 140_000.0 + 11 * 2.0 * -30.0
    assert mixed.sensing.rd_maps.names == ("SVN2", "SVN10", "SVN18") and mixed.sensing.rd_maps.snr_db == (8.0, 9.0, 10.0)
    assert [c.sensing.rd_maps.snr_db for c in setup.cases[1:3]] == [(8.0,) * 3, (10.0,) * 3]
    assert setup.cases[3].sensing.rd_maps.maps.doppler_cell_hz == 0.5
    assert [c.methods for c in setup.cases[1:]] == [("ICMB ascending (known SNR)",)] * 3
    assert setup.set_metric == (1000.0, 1.0) and len(setup.methods) == 13


def test_a_reused_component_slot_starts_a_new_track():
    """Estimates' unpaired convention (a slot holds one track for the whole run): a component slot
    that dies and takes a later birth becomes a second track; a life never above the threshold is
    no track; each track's mean and existence come from its own frames."""
    from pmsr_nn.methods.tbd import tracks_of
    from pmsr_nn.tbd.multibernoulli import MBOutput

    r = torch.tensor([[[0.8, 0.0, 0.0], [0.9, 0.01, 0.0], [0.6, 0.02, 0.0], [0.7, 0.0, 0.3]]], dtype=torch.float64)
    born = torch.tensor([[0, 1, 0, 2]])  # slot 0's second life starts at frame 2
    x = torch.arange(4 * 3 * 4, dtype=torch.float64).view(1, 4, 3, 4)
    out = MBOutput(x, r, torch.zeros(1, 4, 1), torch.zeros(1, 4, 1, dtype=torch.int64), torch.zeros(1, 4), born)
    states, exists, existence = tracks_of(out, 0.5, lambda cv: cv)
    assert states.shape == (1, 4, 2, 4)
    assert exists[0].tolist() == [[True, False], [True, False], [False, True], [False, True]]
    assert torch.equal(states[0, 1, 0], x[0, 1, 0]) and torch.equal(states[0, 3, 1], x[0, 3, 0])
    assert existence[0, :, 0].tolist() == [0.8, 0.9, 0.0, 0.0] and existence[0, :, 1].tolist() == [0.0, 0.0, 0.6, 0.7]


def test_a_track_is_confirmed_and_deleted_by_existence():
    """Hysteresis: confirmed above the threshold (0.5), reported while above ``delete`` (0.2): slot 0's
    first life dips to 0.3 at frame 1 (still reported) and ends below 0.2 at frame 2; its second
    life (a birth at frame 3) at 0.4 is not confirmed yet, then is at 0.6; slot 1's life never
    passes the threshold (no track) though above ``delete``. Without ``delete``, frame 1's dip
    ends the report there (the same label comes back at frame 2 of the life if above 0.5)."""
    from pmsr_nn.methods.tbd import tracks_of
    from pmsr_nn.tbd.multibernoulli import MBOutput

    r = torch.tensor([[[0.8, 0.3], [0.3, 0.4], [0.1, 0.45], [0.4, 0.3], [0.6, 0.3]]], dtype=torch.float64)
    born = torch.tensor([[0, 1, 1, 0, 1]])  # slot 0 reborn at frame 3 (0-based)
    x = torch.arange(5 * 2 * 4, dtype=torch.float64).view(1, 5, 2, 4)
    out = MBOutput(x, r, torch.zeros(1, 5, 1), torch.zeros(1, 5, 1, dtype=torch.int64), torch.zeros(1, 5), born)
    _, exists, _ = tracks_of(out, 0.5, lambda cv: cv, delete=0.2)
    assert exists[0].tolist() == [[True, False], [True, False], [False, False], [False, False], [False, True]]
    _, plain, _ = tracks_of(out, 0.5, lambda cv: cv)
    assert plain[0].tolist() == [[True, False], [False, False], [False, False], [False, False], [False, True]]


def test_the_progress_bar_says_when_a_method_warms_up(tmp_path, monkeypatch, capsys):
    """The untimed warm-up shows as such on the bar, not as the previous row's work."""
    monkeypatch.setattr(blocks, "WARMED", set())
    setup = prepare(scenario_from_dict(tiny(mc_runs=1, block_runs=1), tmp_path))
    run_blocks(setup, range(1), progress=True)
    err = capsys.readouterr().err
    assert "c m (warm-up, untimed)" in err
    capsys.readouterr()
    run_blocks(setup, range(1), progress=True)  # warmed: no warm-up to show
    assert "warm-up" not in capsys.readouterr().err


def test_targets_held_and_unassigned_tracks_are_counted_from_the_set_assignment_by_hand():
    """Two frames, two targets (the second born at frame 2), three tracks: track 0 on target 0 at
    both frames, track 1 assigned to target 1 at frame 2 but 600 m off (beyond c = 500 m, so not
    held and unassigned), track 2 assigned to nothing at frame 1. Held: 1 of 1 living target at
    frame 1, 1 of 2 at frame 2; unassigned tracks: 1 at each frame."""
    from pmsr_nn.methods.kind_metrics import BlockContext, TBDFrames
    from pmsr_nn.simulation.products import Truth
    from pmsr_nn.trackers.base import Estimates

    nan = float("nan")
    tx = torch.tensor([[[[0.0, 0.0], [nan, nan]], [[10.0, 0.0], [1000.0, 0.0]]]], dtype=torch.float64)  # (1, 2, 2, 2)
    truth = Truth(tx, torch.tensor([[True, False], [True, True]]))
    x = torch.tensor([[[[20.0, 0.0], [0.0, 0.0], [3000.0, 0.0]],
                       [[15.0, 0.0], [1600.0, 0.0], [0.0, 0.0]]]], dtype=torch.float64)  # (1, 2, 3, 2)
    exists = torch.tensor([[[True, False, True], [True, True, False]]])
    extras = {"tbd_detected": exists.any(-1), "tbd_best_x": x[:, :, 0], "tbd_best_r": torch.ones(1, 2, dtype=torch.float64),
              "tbd_snr_db": torch.zeros(1, 2, 1, dtype=torch.float64), "tbd_particles": torch.ones(1, 2)}
    est = Estimates(x, exists, None, extras, paired=False)
    assignment = torch.tensor([[[0, -1, -1], [0, 1, -1]]])
    s = TBDFrames(lambda spec, maps: {}).update(est, truth, BlockContext([0], [1], None, assignment, 500.0))
    assert s["tbd_held"].tolist() == [1.0, 1.0] and s["tbd_living"].tolist() == [1.0, 2.0]
    assert s["tbd_unassigned"].tolist() == [1.0, 1.0]
