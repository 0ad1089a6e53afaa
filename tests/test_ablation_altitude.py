"""The altitude ablation (Table 7 of the MDFNN paper): evaluate/ablation_altitude.py on small runs.

What follows from the maths and can fail for a real bug:

* at h = 0 the planar EKF is the matched filter, so its MSE sits near the per-trajectory
  filtering PCRB computed here, independently of the script, on the same true tracks;
* at h = 500 m every bistatic range exceeds the planar one by about h^2 / (2 d) per leg (about
  33 m here, comparable to the 30 m range deviation); that bias, mapped to position by the
  weighted least-squares solution of one scan, predicts the RMSE increase;
* the horizontal motion (and the noise) is the same at every altitude, and equals what the
  package's own 3-D generator draws at that altitude;
* the same seed gives the same numbers; bad input is one line, exit code 2, nothing written.
"""

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from figure_check import assert_drawn_png

from pmsr_nn.bounds import pcrb
from pmsr_nn.filters import FilterError
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.tracks import build_models, generate_tracks

SCRIPT = Path(__file__).resolve().parents[1] / "evaluate" / "ablation_altitude.py"
TRACKS, STEPS, WARMUP, SEED, HIGH = 400, 150, 100, 0, 500.0


def _load():
    spec = importlib.util.spec_from_file_location("ablation_altitude", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


study = _load()


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    """One torch thread: these batches are small, and two threads on a CPU shared with another
    job spin-wait for each other (measured tens of times slower); restored afterwards."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def small():
    """One run (400 tracks x 150 steps at h = 0 and 500 m, about 3 s) and its true tracks."""
    torch.set_default_dtype(torch.float64)
    res = study.run(TRACKS, STEPS, [0.0, HIGH], SEED, WARMUP, progress=False)
    planar, ground = study.recipes(STEPS, SEED, 0.0)
    truth = study.draw_ground_truth(ground, TRACKS, SEED, 0)  # one chunk: TRACKS <= CHUNK_TRACKS
    return res, planar, truth


def _row(res, h):
    return res["cases"][f"h={h:g} m"]["methods"]["EKF (2-D model)"]


def _mse_after_warmup(res, h):
    """Mean over steps >= WARMUP of the per-step MSE over tracks (= pooled RMSE squared)."""
    return torch.tensor(res["curves"]["rmse_pos_m"][f"{h:g}"])[WARMUP:].pow(2).mean()


def test_truth_is_one_horizontal_draw_lifted_to_each_altitude(small):
    res, planar, truth = small
    assert TRACKS <= study.CHUNK_TRACKS
    # The package's 3-D generator at altitude 300 m (same stream) gives the same horizontal
    # motion: drawing at 0 and setting z = h changes nothing but the altitude here (no track of
    # the envelope comes within 50 m of a sensor, so no rejection depends on h).
    _, lifted = study.recipes(STEPS, SEED, 300.0)
    direct = generate_tracks(lifted, TRACKS, seeded_generator(SEED, study.STREAM_TRUTH, 0))[0].states
    torch.testing.assert_close(direct, study.at_altitude(truth, 300.0), rtol=0, atol=0)
    assert bool((direct[..., 6] == 300.0).all()) and bool((direct[..., 7:] == 0).all())
    # Horizontally the tracks keep well away from every sensor (the planar model's singularity).
    _, model2 = build_models(planar)
    assert not bool(model2.near_sensor(truth[..., :6], planar.min_sensor_distance_m).any())


def test_h0_ekf_mse_is_near_the_per_trajectory_pcrb(small):
    res, planar, truth = small
    motion2, model2 = build_models(planar)
    sd = planar.initiation_prior_sd()
    R = model2.R(torch.tensor([30.0, 2.0, math.radians(3.0)]))
    bound = pcrb(truth[..., :6], motion2, 1.0, planar.effective_motion().q_psd, model2, R, torch.diag(sd**2),
                 form="per_trajectory", smoothing=False)
    b = bound.per_track_position[:, WARMUP:].pow(2).mean(1)  # each track's own bound (m^2)
    ratio = float(_mse_after_warmup(res, 0.0) / b.mean())
    # An efficient filter has E[mse_i] = b_i, and mse_i is a time average of the squared norm of
    # a 2-D Gaussian error, whose relative variance is at most 2 (chi-square with 1 dof). So the
    # ratio sum(mse_i) / sum(b_i) has a standard deviation at most sqrt(2 sum w_i^2), w_i = b_i /
    # sum(b): about 0.07 for 400 tracks. Allow 4 of those, plus 0.1 for the EKF's linearisation
    # and for the per-trajectory bound not being a strict bound on each track.
    w = b / b.sum()
    sd_ratio = math.sqrt(2 * float((w**2).sum()))
    assert sd_ratio < 0.1
    assert abs(ratio - 1) < 0.1 + 4 * sd_ratio, f"EKF MSE / PCRB = {ratio:.3f} (sd {sd_ratio:.3f})"
    # A matched, consistent filter: ANEES near 1 (loose; NEES of 6-D states over many steps).
    assert 0.7 < _row(res, 0.0)["anees"] < 1.3
    # The pooled RMSE is the same average as the curve's (every track has every step).
    assert _row(res, 0.0)["pooled_rmse_pos_m"] == pytest.approx(math.sqrt(_mse_after_warmup(res, 0.0)), rel=1e-9)


def test_altitude_bias_raises_the_rmse_as_the_range_bias_predicts(small):
    res, planar, truth = small
    _, lifted = study.recipes(STEPS, SEED, HIGH)
    _, model2 = build_models(planar)
    _, model3 = build_models(lifted)
    x2, x3 = truth[..., :6], study.at_altitude(truth, HIGH)
    dz = model3.h(x3) - model2.h(x2)  # what the planar model does not explain
    # Range rows: per leg sqrt(d^2 + h^2) - d = h^2 / (d + sqrt(d^2 + h^2)) (~ h^2 / (2 d) for
    # d >> h), d the horizontal distance to the ground sensor: tens of metres here.
    pos = x2[..., [0, 3]].unsqueeze(-2)
    d_tx = (pos - model2.geometry.pair_tx_positions()).norm(dim=-1)
    d_rx = (pos - model2.geometry.pair_rx_positions()).norm(dim=-1)
    leg = lambda d: HIGH**2 / (d + torch.sqrt(d**2 + HIGH**2))  # noqa: E731
    torch.testing.assert_close(dz[..., :3], leg(d_tx) + leg(d_rx), rtol=1e-9, atol=1e-9)
    assert float(dz[..., :3].mean()) > 0.5 * 30.0  # comparable to the range deviation
    assert float(dz[..., 6:].abs().max()) == 0.0  # azimuth is horizontal: unaffected
    # One scan's weighted least-squares position bias (position and velocity solved for).
    cols = [0, 1, 3, 4]
    H = model2.jacobian(x2)[..., cols]
    R_inv = torch.diag(1 / model2.std_vector(torch.tensor([30.0, 2.0, math.radians(3.0)])) ** 2)
    info = H.transpose(-1, -2) @ R_inv @ H
    delta = torch.linalg.solve(info, H.transpose(-1, -2) @ R_inv @ dz.unsqueeze(-1)).squeeze(-1)
    bias2 = float(delta[:, WARMUP:][..., [0, 2]].pow(2).sum(-1).mean())
    mse0, mse_h = float(_mse_after_warmup(res, 0.0)), float(_mse_after_warmup(res, HIGH))
    assert bias2 > mse0  # the bias outweighs the noise-limited error...
    assert _row(res, HIGH)["rmse_pos_m"] > _row(res, 0.0)["rmse_pos_m"]  # ...so the RMSE must grow
    assert _row(res, HIGH)["abs_diff_rmse0_m"] == pytest.approx(_row(res, HIGH)["rmse_pos_m"] - _row(res, 0.0)["rmse_pos_m"])
    # Same noise at both altitudes: error_h ~ error_0 + bias, so MSE_h - MSE_0 ~ |bias|^2 up to the
    # cross term 2 e.b, whose mean over N tracks has sd at most 2 sqrt(MSE_0 |bias|^2 / N). Allow
    # 4 of those and 20 % for the filter averaging the slowly varying bias over time.
    cross_sd = 2 * math.sqrt(mse0 * bias2 / TRACKS)
    assert abs((mse_h - mse0) - bias2) < 0.2 * bias2 + 4 * cross_sd, (mse_h - mse0, bias2, cross_sd)
    assert _row(res, HIGH)["diverged"] == 0 and _row(res, 0.0)["diverged"] == 0


def test_same_seed_same_numbers_other_seed_differs():
    a = study.run(30, 40, [0.0, 200.0], 3, 10, chunk_tracks=20, progress=False)
    b = study.run(30, 40, [0.0, 200.0], 3, 10, chunk_tracks=20, progress=False)
    assert a["curves"] == b["curves"]
    for h in (0.0, 200.0):
        ra, rb = _row(a, h), _row(b, h)
        assert {k: v for k, v in ra.items() if "seconds" not in k} == {k: v for k, v in rb.items() if "seconds" not in k}
    c = study.run(30, 40, [0.0, 200.0], 4, 10, chunk_tracks=20, progress=False)
    assert c["curves"]["rmse_pos_m"] != a["curves"]["rmse_pos_m"]


def test_a_failing_run_is_isolated_kept_and_counted(monkeypatch):
    """The EKF stops a whole batch on one bad run; the study isolates it (NaN, counted, never dropped)."""
    real = study.ekf
    marked = []

    def flaky(prior, z, *args):
        if bool((prior.x[:, 0] == marked[0]).any()):
            raise FilterError("state of run 0 became non-finite at step 3")
        return real(prior, z, *args)

    planar, ground = study.recipes(20, 0, 0.0)
    motion2, model2 = build_models(planar)
    truth = study.draw_ground_truth(ground, 8, 0, 0)
    prior = study.prior_for(truth[..., :6], planar.initiation_prior_sd(), 0, 0)
    noise = torch.tensor(study.NOISE_STD)
    z = model2.sample(truth[..., :6], noise, generator=seeded_generator(0))
    R = model2.R(noise)
    ok = real(prior, z, motion2, 1.0, 1e-7, model2, R).x
    marked.append(float(prior.x[5, 0]))
    monkeypatch.setattr(study, "ekf", flaky)
    x, P, failed = study.ekf_isolating_failures(prior, z, motion2, 1.0, 1e-7, model2, R)
    assert failed == 1
    assert bool(torch.isnan(x[5]).all())
    keep = [i for i in range(8) if i != 5]
    torch.testing.assert_close(x[keep], ok[keep])


@pytest.mark.figures
def test_cli_writes_outputs_atomically(tmp_path, capsys):
    out = tmp_path / "alt"
    args = ["--out", str(out), "--tracks", "12", "--steps", "30", "--warmup", "10", "--altitudes", "0", "300",
            "--no-progress"]
    assert study.main(args) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alt"]  # no temporary folder left
    res = json.loads((out / "results.json").read_text())
    assert res["settings"]["tracks"] == 12 and res["environment"]["threads"] >= 1
    assert set(res["cases"]) == {"h=0 m", "h=300 m"}
    table = (out / "table.md").read_text()
    assert "paper RMSE (m, reference)" in table and "| 300 |" in table
    assert_drawn_png(out / "rmse_vs_time.png")
    assert "paper RMSE (ref.)" in capsys.readouterr().out
    # An existing folder is refused (nothing changed), replaced only with --overwrite.
    before = (out / "results.json").read_text()
    assert study.main(args) == 2
    assert "already exists" in capsys.readouterr().err
    assert (out / "results.json").read_text() == before
    assert study.main(args + ["--overwrite", "--seed", "1"]) == 0
    assert json.loads((out / "results.json").read_text())["seed"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alt"]


@pytest.mark.parametrize("bad, message", [
    (["--tracks", "-5"], "--tracks must be at least 1"),
    (["--altitudes", "0", "-100"], "non-negative"),
    (["--steps", "50", "--warmup", "50"], "--warmup must be in"),
    (["--altitudes", "100", "200"], "must include 0"),
    (["--tracks", "many"], "invalid int value"),
])
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, bad, message):
    out = tmp_path / "alt"
    try:
        code = study.main(["--out", str(out), "--no-progress", *bad])
    except SystemExit as exc:  # argparse's own type errors
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and message in err and "\n" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.integration
def test_bad_input_from_the_command_line(tmp_path):
    out = tmp_path / "alt"
    proc = subprocess.run([sys.executable, str(SCRIPT), "--out", str(out), "--tracks", "-1"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith("error: ") and len(proc.stderr.strip().splitlines()) == 1
    assert proc.stdout == "" and list(tmp_path.iterdir()) == []

