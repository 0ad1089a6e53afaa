"""Multi-object metrics (OSPA, GOSPA, assignments, label switches) against brute force."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from pmsr_nn.metrics import (
    cardinality_error,
    gospa,
    label_switches,
    labelled_assignment,
    optimal_assignment,
    ospa,
    set_scores,
)

# ---------------------------------------------------------------- helpers


def random_sets(gen: torch.Generator, lead: tuple[int, ...], slots: int = 5, d: int = 2, max_size: int = 4, scale: float = 10.0):
    """Padded sets of 0..max_size points at random slots; padded entries are NaN."""
    n = torch.randint(0, max_size + 1, lead, generator=gen)
    order = torch.rand(*lead, slots, generator=gen).argsort(-1)  # which slots are used: random, not a prefix
    mask = order < n.unsqueeze(-1)
    x = torch.rand(*lead, slots, d, generator=gen, dtype=torch.float64) * scale
    x = torch.where(mask.unsqueeze(-1), x, torch.full_like(x, float("nan")))
    return x, mask


def points(x: torch.Tensor, mask: torch.Tensor) -> list[np.ndarray]:
    return [x[i].numpy() for i in range(mask.shape[-1]) if mask[i]]


def dist(a, b) -> float:
    return math.sqrt(sum((float(u) - float(v)) ** 2 for u, v in zip(a, b)))


def brute_ospa(X, Y, c, p) -> float:
    if len(X) > len(Y):
        X, Y = Y, X
    m, n = len(X), len(Y)
    if n == 0:
        return 0.0
    best = min(sum(min(dist(X[i], Y[j]), c) ** p for i, j in enumerate(perm)) for perm in itertools.permutations(range(n), m))
    return ((best + c**p * (n - m)) / n) ** (1 / p)


def brute_gospa_p(X, Y, c, p) -> float:
    """GOSPA**p (alpha = 2) by its assignment form, over every partial one-to-one assignment."""
    if len(X) > len(Y):
        X, Y = Y, X
    m, n = len(X), len(Y)
    best = math.inf
    for perm in itertools.permutations(list(range(n)) + [None] * m, m):  # X[i] -> Y[perm[i]] or unassigned
        pairs = [(i, j) for i, j in enumerate(perm) if j is not None]
        cost = sum(dist(X[i], Y[j]) ** p for i, j in pairs) + c**p / 2 * (m + n - 2 * len(pairs))
        best = min(best, cost)
    return best


# ---------------------------------------------------------------- OSPA / GOSPA


@pytest.mark.parametrize("p", [1.0, 2.0, 3.0])
def test_ospa_gospa_match_brute_force(p):
    gen = torch.Generator().manual_seed(int(p) + 10)
    c = 3.0
    est, em = random_sets(gen, (50,))
    truth, tm = random_sets(gen, (50,))
    # make sure the empty cases are in: both empty, only est empty, only truth empty
    em[0] = False
    tm[0] = False
    em[1] = False
    tm[2] = False
    tm[1, 1:3] = True
    truth[1, 1:3] = torch.tensor([[1.0, 2.0], [4.0, 4.5]])
    em[2, 0::2] = True
    est[2, 0::2] = torch.tensor([[1.0, 2.0], [4.0, 4.5], [9.0, 0.5]])
    est = torch.where(em.unsqueeze(-1), est, torch.full_like(est, float("nan")))
    truth = torch.where(tm.unsqueeze(-1), truth, torch.full_like(truth, float("nan")))
    assert tm[1].any() and em[2].any()

    o = ospa(est, em, truth, tm, c, p)
    g = gospa(est, em, truth, tm, c, p)
    assert o.shape == (50,) and g.total.shape == (50,)
    for b in range(50):
        X, Y = points(est[b], em[b]), points(truth[b], tm[b])
        ref_o = brute_ospa(X, Y, c, p)
        ref_g = brute_gospa_p(X, Y, c, p)
        assert float(o[b]) == pytest.approx(ref_o, rel=1e-12, abs=1e-12), b
        assert float(g.total[b]) ** p == pytest.approx(ref_g, rel=1e-12, abs=1e-12), b
        assert float(g.localisation[b] + g.missed[b] + g.false[b]) == pytest.approx(ref_g, rel=1e-12, abs=1e-12), b
        assert float(g.n_missed[b] - g.n_false[b]) == len(Y) - len(X)
        assert float(g.missed[b]) == pytest.approx(c**p / 2 * float(g.n_missed[b]), rel=1e-14)
    assert float(o[0]) == 0.0 and float(g.total[0]) == 0.0
    assert float(o[1]) == pytest.approx(c) and float(o[2]) == pytest.approx(c)
    assert float(g.n_false[1]) == 0 and float(g.n_missed[1]) == float(tm[1].sum())
    assert float(g.n_missed[2]) == 0 and float(g.n_false[2]) == float(em[2].sum())
    assert torch.isfinite(o).all() and torch.isfinite(g.total).all()


def test_gospa_decomposition_by_hand():
    nan = float("nan")
    truth = torch.tensor([[0.0, 0.0], [100.0, 0.0], [nan, nan]])
    tm = torch.tensor([True, True, False])
    # (3, 4) is 5 m from (0, 0); (50, 50) and (-60, 0) are beyond c of every truth
    est = torch.tensor([[nan, nan], [3.0, 4.0], [50.0, 50.0], [-60.0, 0.0]])
    em = torch.tensor([False, True, True, True])
    c, p = 10.0, 2.0
    g = gospa(est, em, truth, tm, c, p)
    # localisation 5^2 = 25; one missed truth (100, 0): 10^2 / 2 = 50; two false estimates: 2 * 50 = 100
    assert float(g.localisation) == pytest.approx(25.0, rel=1e-14)
    assert float(g.n_missed) == 1.0 and float(g.missed) == pytest.approx(50.0, rel=1e-14)
    assert float(g.n_false) == 2.0 and float(g.false) == pytest.approx(100.0, rel=1e-14)
    assert float(g.total) == pytest.approx(math.sqrt(175.0), rel=1e-14)
    assert float(g.total) ** p == pytest.approx(float(g.localisation + g.missed + g.false), rel=1e-14)
    assert optimal_assignment(est, em, truth, tm, c, p).tolist() == [-1, 0, -1, -1]
    assert float(cardinality_error(em, tm)) == 1.0


def test_worked_example_c5_p1():
    # truths (0,0), (10,0); estimates (1,0), (30,0); c = 5, p = 1.
    # distances: e1-t1 1, e1-t2 9, e2-t1 30, e2-t2 20 -> cut at 5: [[1, 5], [5, 5]]
    # OSPA: best matching e1-t1, e2-t2: (1 + 5) / 2 = 3.
    # GOSPA: e1-t1 localisation 1; t2 missed and e2 false (20 >= c): 5/2 + 5/2; total 1 + 5 = 6.
    truth = torch.tensor([[0.0, 0.0], [10.0, 0.0]])
    est = torch.tensor([[1.0, 0.0], [30.0, 0.0]])
    m = torch.tensor([True, True])
    assert float(ospa(est, m, truth, m, 5.0, 1.0)) == pytest.approx(3.0, rel=1e-14)
    g = gospa(est, m, truth, m, 5.0, 1.0)
    assert float(g.total) == pytest.approx(6.0, rel=1e-14)
    assert float(g.localisation) == pytest.approx(1.0, rel=1e-14)
    assert float(g.missed) == pytest.approx(2.5) and float(g.false) == pytest.approx(2.5)
    assert float(g.n_missed) == 1.0 and float(g.n_false) == 1.0
    assert optimal_assignment(est, m, truth, m, 5.0, 1.0).tolist() == [0, -1]


def test_bad_arguments():
    x = torch.zeros(2, 2)
    m = torch.ones(2, dtype=torch.bool)
    with pytest.raises(ValueError, match="alpha=2"):
        gospa(x, m, x, m, 1.0, 1.0, alpha=1.0)
    with pytest.raises(ValueError, match="order p"):
        ospa(x, m, x, m, 1.0, 0.5)
    with pytest.raises(ValueError, match="cut-off"):
        ospa(x, m, x, m, 0.0, 1.0)
    with pytest.raises(ValueError, match="masks"):
        ospa(x, m[:1], x, m, 1.0, 1.0)


def test_batched_equals_looped():
    gen = torch.Generator().manual_seed(3)
    B, K, c, p = 3, 4, 3.0, 2.0
    est, em = random_sets(gen, (B, K))
    truth, tm = random_sets(gen, (B, K), slots=4)
    a = optimal_assignment(est, em, truth, tm, c, p)
    o = ospa(est, em, truth, tm, c, p)
    g = gospa(est, em, truth, tm, c, p)
    ce = cardinality_error(em, tm)
    assert a.shape == (B, K, 5) and a.dtype == torch.int64 and o.shape == (B, K) and ce.shape == (B, K)
    for b in range(B):
        for k in range(K):
            args = (est[b, k], em[b, k], truth[b, k], tm[b, k], c, p)
            assert torch.equal(optimal_assignment(*args), a[b, k])
            assert float(ospa(*args)) == pytest.approx(float(o[b, k]), rel=1e-12, abs=0)
            gi = gospa(*args)
            for f in ("total", "localisation", "missed", "false", "n_missed", "n_false"):
                assert float(getattr(gi, f)) == pytest.approx(float(getattr(g, f)[b, k]), rel=1e-12, abs=0), f
            assert float(cardinality_error(em[b, k], tm[b, k])) == float(ce[b, k])
    # labelled assignment over (B, K) equals per run
    la = labelled_assignment(est, em, truth, tm, c)
    assert la.shape == (B, 5)
    for b in range(B):
        assert torch.equal(labelled_assignment(est[b : b + 1], em[b : b + 1], truth[b : b + 1], tm[b : b + 1], c)[0], la[b])
    # label switches per run equal the batched ones
    sw = label_switches(a, tm)
    for b in range(B):
        assert torch.equal(label_switches(a[b], tm[b]), sw[b])


# ---------------------------------------------------------------- labelled tracks


def labelled_cost(assign, est, em, truth, tm, c) -> float:
    """Sum over scans of the labelled cost of a label -> target map (``assign[m]`` target or -1)."""
    K, M = em.shape
    N = tm.shape[1]
    total = 0.0
    for k in range(K):
        for m in range(M):
            n = assign[m]
            if n < 0:
                total += c * c * bool(em[k, m])
            elif em[k, m] and tm[k, n]:
                total += min(dist(est[k, m], truth[k, n]) ** 2, c * c)
            elif em[k, m] or tm[k, n]:
                total += c * c
        for n in set(range(N)) - set(int(a) for a in assign if a >= 0):
            total += c * c * bool(tm[k, n])
    return total


def test_labelled_assignment_recovers_swapped_labels():
    K = 6
    ks = torch.arange(K, dtype=torch.float64)
    truth = torch.stack([torch.stack([ks, torch.zeros(K)], -1), torch.stack([ks, torch.full((K,), 20.0)], -1)], 1)  # (K, 2, 2)
    tm = torch.ones(K, 2, dtype=torch.bool)
    nan = torch.full((K, 2), float("nan"))
    # label 0 follows target 1, label 1 follows target 0 (0.5 m off), label 2 never exists
    est = torch.stack([truth[:, 1] + 0.5, truth[:, 0] - 0.5, nan], 1)
    em = torch.tensor([[True, True, False]] * K)
    # one scan where label 1 is missing, and one where label 0 wanders off beyond c
    em[2, 1] = False
    est[2, 1] = float("nan")
    est[4, 0] = torch.tensor([100.0, 100.0])
    a = labelled_assignment(est[None], em[None], truth[None], tm[None], c=5.0)
    assert a.tolist() == [[1, 0, -1]]


def test_labelled_assignment_brute_force():
    gen = torch.Generator().manual_seed(7)
    c = 4.0
    for _ in range(25):
        K = 3
        est, em = random_sets(gen, (1, K), slots=3, max_size=3)
        truth, tm = random_sets(gen, (1, K), slots=3, max_size=3)
        a = labelled_assignment(est, em, truth, tm, c)[0].tolist()
        M, N = 3, 3
        best = min(
            labelled_cost(perm, est[0], em[0], truth[0], tm[0], c)
            for perm in itertools.permutations(list(range(N)) + [-1] * M, M)
        )
        got = labelled_cost(a, est[0], em[0], truth[0], tm[0], c)
        assert got == pytest.approx(best, rel=1e-12, abs=1e-12)
        # a label kept is one that co-exists with its target at some scan
        for m, n in enumerate(a):
            if n >= 0:
                assert bool((em[0, :, m] & tm[0, :, n]).any())


# ---------------------------------------------------------------- label switches


def test_label_switches_hand_built():
    tm = torch.ones(1, 5, 2, dtype=torch.bool)
    # truth 0: track 0, 0, 1, 1, 1 -> one switch; truth 1: track 2 throughout -> none
    a = torch.tensor([[[0, -1, 1], [0, -1, 1], [-1, 0, 1], [-1, 0, 1], [-1, 0, 1]]])
    assert label_switches(a, tm).tolist() == [[1, 0]]
    # truth 0: track 0, unassigned, track 1: no consecutive pair assigned at both scans -> no switch
    a2 = torch.tensor([[[0, -1, 1], [-1, -1, 1], [-1, 0, 1], [-1, 0, 1], [-1, 0, 1]]])
    assert label_switches(a2, tm).tolist() == [[0, 0]]
    # one track per truth throughout -> none
    a3 = torch.tensor([[[0, 1, -1]] * 5])
    assert label_switches(a3, tm).tolist() == [[0, 0]]
    # no track slots at all
    assert label_switches(torch.zeros(1, 5, 0, dtype=torch.int64), tm).tolist() == [[0, 0]]


def test_label_switches_from_optimal_assignment():
    # two targets that cross at scan 2; the tracker's labels swap there
    K = 5
    truth = torch.zeros(1, K, 2, 2)
    truth[0, :, 0, 0] = torch.arange(K, dtype=torch.float64)
    truth[0, :, 1, 0] = torch.arange(K, dtype=torch.float64) + 50.0
    est = truth.clone() + 0.3
    est[0, 2:] = est[0, 2:].flip(-2)  # from scan 2 on, label 0 sits on target 1 and label 1 on target 0
    m = torch.ones(1, K, 2, dtype=torch.bool)
    a = optimal_assignment(est, m, truth, m, c=5.0, p=2.0)
    assert label_switches(a, m).tolist() == [[1, 1]]
    assert label_switches(optimal_assignment(truth + 0.3, m, truth, m, 5.0, 2.0), m).tolist() == [[0, 0]]


# ---------------------------------------------------------------- running sums


def test_set_scores_equal_the_separate_metrics():
    """One solve for OSPA, GOSPA and the assignment gives what three separate solves give."""
    gen = torch.Generator().manual_seed(7)
    est, em = random_sets(gen, (6, 5))
    tru, tm = random_sets(gen, (6, 5))
    both = set_scores(est, em, tru, tm, 4.0, 2.0)
    assert torch.equal(both.ospa, ospa(est, em, tru, tm, 4.0, 2.0))
    g = gospa(est, em, tru, tm, 4.0, 2.0)
    assert torch.equal(both.gospa.total, g.total) and torch.equal(both.gospa.missed, g.missed)
    assert torch.equal(both.assignment, optimal_assignment(est, em, tru, tm, 4.0, 2.0))


@pytest.mark.parametrize("seed", range(3))
def test_enumerated_small_sets_equal_scipy_matching(seed, monkeypatch):
    """The permutation path for small sets gives SciPy's optimum (values to rounding; sets random)."""
    import pmsr_nn.metrics.sets as sets

    gen = torch.Generator().manual_seed(seed)
    est, em = random_sets(gen, (40,), slots=4)
    tru, tm = random_sets(gen, (40,), slots=3)
    small = set_scores(est, em, tru, tm, 6.0, 2.0)
    monkeypatch.setattr(sets, "SMALL_SETS", 0)
    big = set_scores(est, em, tru, tm, 6.0, 2.0)
    assert torch.allclose(small.ospa, big.ospa, rtol=1e-12, atol=1e-12)
    assert torch.allclose(small.gospa.total, big.gospa.total, rtol=1e-12, atol=1e-12)
    assert torch.equal(small.gospa.n_missed, big.gospa.n_missed)
