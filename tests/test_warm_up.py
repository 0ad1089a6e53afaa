"""The runner's untimed warm-up: once per process and kind, on a slice of the first run's scans
(issue 57 item 3: a one-run study no longer runs every method twice)."""

from __future__ import annotations

import dataclasses

import pytest

from pmsr_nn.harness.run import blocks
from pmsr_nn.harness.run.blocks import WARM_SCANS, draw_block, warm_up
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.loading import load_any
from test_one_scenario import two_drones

METHODS = [{"name": "EKF", "kind": "ekf"}, {"name": "S-MSJPDA", "kind": "s_msjpda", "options": {"initiation": "detections"}}]


@pytest.fixture
def scene(tmp_path):
    setup = prepare(load_any(two_drones(tmp_path, methods=METHODS, mc_runs=2, block_runs=2)))
    return setup, setup.cases[0], draw_block(setup, 0, 0)[1]


def _spy(monkeypatch):
    calls = []
    real = blocks.call_method

    def spy(setup, spec, case, products, seed, alive=None):
        reads = setup.kinds[spec.name].reads
        p = products[reads]
        scans = p.z.shape[2] if reads == "measurements" else p.scans.z.shape[1]
        runs = p.z.shape[0] if reads == "measurements" else p.scans.z.shape[0]
        calls.append((spec.name, runs, scans, None if alive is None else alive.shape[0]))
        return real(setup, spec, case, products, seed, alive)
    monkeypatch.setattr(blocks, "call_method", spy)
    return calls


def test_the_warm_up_runs_one_run_over_the_scans_after_the_first_birth(scene, monkeypatch):
    setup, case, products = scene
    K = case.alive.shape[0]
    assert K > WARM_SCANS and bool(case.alive[0].any())  # a birth at scan 0: the slice is WARM_SCANS long
    calls = _spy(monkeypatch)
    for spec in setup.methods:
        warm_up(setup, spec, case, products)
    assert calls == [("EKF", 1, WARM_SCANS, WARM_SCANS), ("S-MSJPDA", 1, WARM_SCANS, WARM_SCANS)]


def test_a_kind_the_slice_does_not_suit_warms_up_on_the_whole_first_run(scene, monkeypatch):
    setup, case, products = scene
    spec = setup.methods[1]
    kind = setup.kinds[spec.name]
    K = case.alive.shape[0]

    def whole_runs_only(call):
        if call.alive.shape[0] < K:
            raise ValueError("needs every scan")
        return run(call)
    run = kind.run
    monkeypatch.setitem(setup.kinds, spec.name, dataclasses.replace(kind, run=whole_runs_only))
    calls = _spy(monkeypatch)
    warm_up(setup, spec, case, products)
    assert calls == [("S-MSJPDA", 1, WARM_SCANS, WARM_SCANS), ("S-MSJPDA", 1, K, None)]
