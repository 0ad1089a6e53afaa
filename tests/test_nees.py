"""normalised_nees (pmsr_nn.metrics.pointwise): the closed form where the covariance is regular,
NaN (not a crash) where the estimate or covariance is not finite, the pseudo-inverse where the
covariance is singular."""

from __future__ import annotations

import math

import torch

from pmsr_nn.metrics.pointwise import normalised_nees


def test_nees_is_the_closed_form_nan_where_not_finite_and_the_pseudo_inverse_where_singular():
    x = torch.tensor([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0], [3.0, 0.0]], dtype=torch.float64)
    truth = torch.zeros(4, 2, dtype=torch.float64)
    P = torch.stack([torch.diag(torch.tensor([4.0, 1.0])), torch.diag(torch.tensor([4.0, 1.0])),
                     torch.full((2, 2), math.nan), torch.diag(torch.tensor([9.0, 0.0]))]).to(torch.float64)
    x[1, 0] = math.nan  # a track with no estimate there
    got = normalised_nees(x, P, truth)
    assert got[0].item() == (1.0 / 4 + 4.0 / 1) / 2  # e^T P^-1 e / n
    assert math.isnan(got[1].item()) and math.isnan(got[2].item())
    assert abs(got[3].item() - (9.0 / 9.0) / 2) < 1e-12  # singular: the pseudo-inverse ignores the null direction
