"""Random draws shared by the simulators: seeded generators and fast standard normals."""

from __future__ import annotations

import numpy as np
import torch


def seeded_generator(seed: int, *stream: int, device=None) -> torch.Generator:
    """An independent ``torch.Generator`` for ``(seed, *stream)`` (e.g. one per chunk of tracks).

    The 64-bit seed comes from NumPy's ``SeedSequence``, so neighbouring streams are unrelated.
    """
    state = np.random.SeedSequence([seed, *stream]).generate_state(2, np.uint32)
    g = torch.Generator(device=device) if device is not None else torch.Generator()
    g.manual_seed(int(state[0]) << 32 | int(state[1]))
    return g


def standard_normal(shape, generator: torch.Generator | None, dtype=torch.float64, device=None) -> torch.Tensor:
    """Standard normal draws of ``shape`` in ``dtype``.

    The draws are made in float32 and cast: on this project's 2-core CPU that is about 3.6x the
    rate of torch's float64 sampler, cast included (``benchmarks/simulate_throughput.py`` measures
    it), and the simulator's time is dominated by these draws. The only loss is
    resolution in the far tail: |z| can not exceed about 5.8 (probability below 1e-8 per draw),
    which no statistic of this package can see.
    """
    return torch.randn(shape, generator=generator, dtype=torch.float32, device=device).to(dtype)
