"""benchmarks/profile_rows.py's operation counter: its arithmetic estimate per operation (a matrix
product 2 m n k, a factorisation or solve n^3 per matrix, one per element written otherwise)."""

from __future__ import annotations


import pytest
import torch

from bench_module import load_benchmark

@pytest.fixture(scope="module")
def profile_rows():
    return load_benchmark("profile_rows")


def counted(profile_rows, fn) -> tuple[int, int, int]:
    counter = profile_rows.OpCounter()
    with counter:
        fn()
    return counter.ops, counter.flops, counter.elements


def test_each_operation_is_counted_by_its_own_rule(profile_rows):
    a, b = torch.rand(5, 3, dtype=torch.float64), torch.rand(3, 7, dtype=torch.float64)
    assert counted(profile_rows, lambda: a @ b) == (1, 2 * 5 * 7 * 3, 35)
    P = torch.eye(3, dtype=torch.float64).expand(4, 3, 3) * 2.0
    ops, flops, _ = counted(profile_rows, lambda: torch.linalg.cholesky(P))
    assert flops == 4 * 3**3
    # elementwise, whatever letters its name shares with a factorisation: sqrt is not a QR, detach no determinant
    x = torch.rand(1, 1000, dtype=torch.float64)
    assert counted(profile_rows, lambda: x.sqrt())[1] == 1000
    assert counted(profile_rows, lambda: x.detach())[1] == 1000
