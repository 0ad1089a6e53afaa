"""The filterpy reference of ``benchmarks/bench_filters.py`` has its own numpy measurement model
(so the benchmark's ratio does not move with our code's speed): it must be the same function as
ours on the benchmark's scenario, and refuse a model it does not describe."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from bench_module import load_benchmark


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("bench_filters")


def test_numpy_reference_model_is_ours(bench):
    motion, model, z, R, prior = bench.scenario(20, "cpu")
    ref = bench.reference_model(model)
    g = torch.Generator().manual_seed(0)
    # priors and states 2 km / 50 m/s around them: ranges of ~1e5 m, so float64 agrees to ~1e-10 m
    xs = prior.x + torch.randn(prior.x.shape, generator=g, dtype=torch.float64) * torch.tensor([2e3, 50, 1, 2e3, 50, 1.0])
    for x in xs:
        zh, H = model.h(x).numpy(), model.jacobian(x).numpy()
        scale = np.abs(zh) + 1.0
        assert np.all(np.abs(ref.h(x.numpy()) - zh) <= 1e-12 * scale * 100)
        assert np.allclose(ref.jacobian(x.numpy()), H, rtol=1e-10, atol=1e-14)


def test_numpy_reference_refuses_other_models(bench):
    _, model, *_ = bench.scenario(2, "cpu")
    with pytest.raises(SystemExit, match="numpy reference models 2-D CA"):
        bench.reference_model(replace(model, layout="pair"))
