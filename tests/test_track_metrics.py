"""Track-level scores (tracks per target, false / lost tracks, delays) and matched errors, by hand."""

from __future__ import annotations

import math

import pytest
import torch

from pmsr_nn.metrics import matched_errors, optimal_assignment, track_scores

NAN = float("nan")
FIELDS = ("tracks_per_target", "false_tracks", "missed_scans", "alive_scans", "scans_to_first_track", "lost", "switches", "fragmentations")


def rows(*lines: str) -> torch.Tensor:
    """``(len(lines), K)`` bool from strings of 0/1 (one line per target or slot, scans left to right)."""
    return torch.tensor([[ch == "1" for ch in line.split()] for line in lines])


def hand_case():
    """Two runs, K = 8 scans, M = 4 slots, N = 2 targets; ``assignment (2, K, M)``, ``exists (2, K, M)``,
    ``truth_mask (2, K, N)``.

    Run 0 (scans 0..7):
      target 0 lives 0..7; target 1 lives 1..6.
      slot 0 exists 2..5: target 0 at 2, 3; target 1 at 4 (the two tracks swap); none at 5 (drifted off).
      slot 1 exists 3..6, never assigned (a false track).
      slot 2 exists 6..7: target 0 at 6, 7.
      slot 3 exists 2..4: target 1 at 2, 3; target 0 at 4.
    Run 1:
      target 0 lives 2..6 and is never tracked; target 1 lives 0..6.
      slot 0 exists 0..7, never assigned; slot 2 exists at 3 only, never assigned (two false tracks).
      slot 1 exists 0..3: target 1 at 0..3, then dropped while target 1 lives 4..6.
      slot 3 never exists (not a reported track, so not false).
    """
    truth_mask = torch.stack([
        rows("1 1 1 1 1 1 1 1",
             "0 1 1 1 1 1 1 0"),
        rows("0 0 1 1 1 1 1 0",
             "1 1 1 1 1 1 1 0"),
    ]).transpose(-1, -2)
    exists = torch.stack([
        rows("0 0 1 1 1 1 0 0",
             "0 0 0 1 1 1 1 0",
             "0 0 0 0 0 0 1 1",
             "0 0 1 1 1 0 0 0"),
        rows("1 1 1 1 1 1 1 1",
             "1 1 1 1 0 0 0 0",
             "0 0 0 1 0 0 0 0",
             "0 0 0 0 0 0 0 0"),
    ]).transpose(-1, -2)
    _ = -1
    assignment = torch.tensor([
        [[_, _, 0, 0, 1, _, _, _],
         [_, _, _, _, _, _, _, _],
         [_, _, _, _, _, _, 0, 0],
         [_, _, 1, 1, 0, _, _, _]],
        [[_, _, _, _, _, _, _, _],
         [1, 1, 1, 1, _, _, _, _],
         [_, _, _, _, _, _, _, _],
         [_, _, _, _, _, _, _, _]],
    ]).transpose(-1, -2)
    return assignment, exists, truth_mask


# Per target, run 0 target 0 is covered by slots [-, -, 0, 0, 3, -, 2, 2], target 1 by [-, -, 3, 3, 0, -, -, (dead)].
HAND = dict(
    tracks_per_target=[[3.0, 2.0],   # run 0: slots {0, 3, 2} and {3, 0}; run 1: none and {1}
                       [0.0, 1.0]],
    false_tracks=[1.0, 2.0],          # run 0: slot 1; run 1: slots 0 and 2 (slot 3 never reported)
    missed_scans=[[3.0, 3.0],        # run 0: scans 0, 1, 5 and 1, 5, 6; run 1: all 5 living and 4, 5, 6
                  [5.0, 3.0]],
    alive_scans=[[8.0, 6.0], [5.0, 7.0]],
    scans_to_first_track=[[2.0, 1.0],   # run 0: first track at 2 (born 0) and 2 (born 1)
                          [NAN, 0.0]],  # run 1: never tracked; tracked from birth
    switches=[[1.0, 1.0],            # the swap between scans 3 and 4 (the gap 5 -> 6 is not a switch)
              [0.0, 0.0]],
    fragmentations=[[1.0, 0.0],      # run 0 target 0: covered at 4, not at 5, again at 6; target 1 never again
                    [0.0, 0.0]],
)
# lost: after its last assigned scan, run 0 target 1 lives 2 more scans (5, 6), run 1 target 1 lives 3 (4, 5, 6);
# run 0 target 0 is covered to the end, run 1 target 0 never.
LOST = {
    1: [[False, True], [False, True]],
    2: [[False, True], [False, True]],
    3: [[False, False], [False, True]],
    4: [[False, False], [False, False]],
}


def assert_scores(s, expected: dict, lost: list | None = None) -> None:
    for name, value in expected.items():
        torch.testing.assert_close(getattr(s, name), torch.tensor(value, dtype=torch.float64), equal_nan=True, msg=name)
    if lost is not None:
        assert torch.equal(s.lost, torch.tensor(lost)), s.lost


def assert_same_scores(a, b) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        torch.testing.assert_close(x, y, equal_nan=True, msg=name)


def test_hand_case():
    assignment, exists, truth_mask = hand_case()
    s = track_scores(assignment, exists, truth_mask)
    assert_scores(s, HAND, LOST[1])
    assert s.lost.dtype == torch.bool


@pytest.mark.parametrize("loss_scans", [1, 2, 3, 4])
def test_lost_needs_loss_scans_living_scans_after_the_last_track(loss_scans):
    s = track_scores(*hand_case(), loss_scans=loss_scans)
    assert torch.equal(s.lost, torch.tensor(LOST[loss_scans]))


def geometric_case(c: float = 100.0):
    """Positions realising :func:`hand_case` through :func:`optimal_assignment`: target 0 at
    ``(100 k, 0)``, target 1 at ``(100 k, 2000)`` m; an assigned track 5 m off its target; run 0 slot 0
    at scan 5 drifted 150 m (> c) off target 0; other reported tracks 1e5 m away; NaN padding."""
    assignment, exists, truth_mask = hand_case()
    B, K, M = assignment.shape
    k = torch.arange(K, dtype=torch.float64)
    truth = torch.stack([torch.stack([100 * k, torch.zeros(K)], -1), torch.stack([100 * k, torch.full((K,), 2000.0)], -1)], -2)
    truth = truth.expand(B, K, 2, 2).clone()
    on = truth.gather(-2, assignment.clamp(min=0).unsqueeze(-1).expand(B, K, M, 2)) + torch.tensor([3.0, -4.0])
    far = torch.stack([-1e5 + 1e3 * torch.arange(M, dtype=torch.float64), torch.full((M,), -1e5)], -1).expand(B, K, M, 2)
    est = torch.where((assignment >= 0).unsqueeze(-1), on, far).clone()
    est[0, 5, 0] = truth[0, 5, 0] + torch.tensor([150.0, 0.0])
    est = torch.where(exists.unsqueeze(-1), est, torch.full((), NAN))
    truth = torch.where(truth_mask.unsqueeze(-1), truth, torch.full((), NAN))
    return est, exists, truth, truth_mask, assignment


def test_geometric_case_through_optimal_assignment():
    est, exists, truth, truth_mask, expected_assignment = geometric_case()
    assignment = optimal_assignment(est, exists, truth, truth_mask, c=100.0, p=2.0)
    assert torch.equal(assignment, expected_assignment)
    assert_scores(track_scores(assignment, exists, truth_mask, loss_scans=3), HAND, LOST[3])


def test_batch_equals_each_run_alone_and_leading_dims():
    assignment, exists, truth_mask = hand_case()
    # run 1 then run 0, so a score that leaked across runs or ignored the order would differ
    order = [1, 0]
    whole = track_scores(assignment[order], exists[order], truth_mask[order])
    for i, b in enumerate(order):
        alone = track_scores(assignment[b : b + 1], exists[b : b + 1], truth_mask[b : b + 1])
        for name in FIELDS:
            torch.testing.assert_close(getattr(whole, name)[i : i + 1], getattr(alone, name), equal_nan=True, msg=name)
    # leading dims (2, 1) and none at all: the same numbers
    nested = track_scores(assignment[order].unsqueeze(1), exists[order].unsqueeze(1), truth_mask[order].unsqueeze(1))
    for name in FIELDS:
        torch.testing.assert_close(getattr(nested, name).squeeze(1), getattr(whole, name), equal_nan=True, msg=name)
    single = track_scores(assignment[1], exists[1], truth_mask[1])
    for name in FIELDS:
        torch.testing.assert_close(getattr(single, name), getattr(whole, name)[0], equal_nan=True, msg=name)


def reference_scores(assignment, exists, truth_mask, loss_scans):
    """The definitions of :class:`TrackScores`, one run and target at a time, in plain Python."""
    B, K, M = assignment.shape
    N = truth_mask.shape[-1]
    out = {name: [] for name in FIELDS}
    for b in range(B):
        a, e, t = assignment[b].tolist(), exists[b].tolist(), truth_mask[b].tolist()
        out["false_tracks"].append(float(sum(any(e[k][m] for k in range(K)) and all(a[k][m] < 0 for k in range(K)) for m in range(M))))
        for name in FIELDS:
            if name != "false_tracks":
                out[name].append([])
        for n in range(N):
            cover = [next((m for m in range(M) if a[k][m] == n), None) for k in range(K)]
            living = [k for k in range(K) if t[k][n]]
            covered = [k for k in range(K) if cover[k] is not None]
            out["tracks_per_target"][b].append(float(len({cover[k] for k in covered})))
            out["missed_scans"][b].append(float(sum(cover[k] is None for k in living)))
            out["alive_scans"][b].append(float(len(living)))
            out["scans_to_first_track"][b].append(float(covered[0] - living[0]) if covered else NAN)
            out["lost"][b].append(bool(covered) and sum(k > covered[-1] for k in living) >= loss_scans)
            out["switches"][b].append(float(sum(cover[k] is not None and cover[k - 1] is not None and cover[k] != cover[k - 1] for k in range(1, K))))
            out["fragmentations"][b].append(float(sum(
                cover[k - 1] is not None and t[k][n] and cover[k] is None and any(c is not None for c in cover[k + 1 :]) for k in range(1, K)
            )))
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_random_cases_equal_the_definitions(seed):
    gen = torch.Generator().manual_seed(seed)
    B, K, M, N = 5, 12, 5, 4
    truth_mask = torch.rand(B, K, N, generator=gen) < 0.6
    exists = torch.rand(B, K, M, generator=gen) < 0.5
    est = torch.rand(B, K, M, 2, generator=gen) * 100
    truth = torch.rand(B, K, N, 2, generator=gen) * 100
    assignment = optimal_assignment(est, exists, truth, truth_mask, c=30.0, p=1.0)
    assert 0 < int((assignment >= 0).sum()) < int(exists.sum())  # both assigned and unassigned tracks occur
    for loss_scans in (1, 2):
        s = track_scores(assignment, exists, truth_mask, loss_scans=loss_scans)
        ref = reference_scores(assignment, exists, truth_mask, loss_scans)
        expected = {name: value for name, value in ref.items() if name != "lost"}
        assert_scores(s, expected, ref["lost"])


def test_no_slots():
    truth_mask = torch.stack([rows("1 1 0", "0 1 1"), rows("0 0 0", "1 0 0")]).transpose(-1, -2)  # (2, 3, 2)
    s = track_scores(torch.zeros(2, 3, 0, dtype=torch.int64), torch.zeros(2, 3, 0, dtype=torch.bool), truth_mask)
    assert_scores(s, dict(
        tracks_per_target=[[0.0, 0.0], [0.0, 0.0]], false_tracks=[0.0, 0.0],
        missed_scans=[[2.0, 2.0], [0.0, 1.0]], alive_scans=[[2.0, 2.0], [0.0, 1.0]],  # missed = alive: nothing tracks
        scans_to_first_track=[[NAN, NAN], [NAN, NAN]], switches=[[0.0, 0.0], [0.0, 0.0]], fragmentations=[[0.0, 0.0], [0.0, 0.0]],
    ), [[False, False], [False, False]])


def test_no_targets():
    exists = torch.stack([rows("1 1 0", "0 0 0", "0 1 0"), rows("0 0 0", "0 0 0", "0 0 0")]).transpose(-1, -2)  # (2, 3, 3)
    s = track_scores(torch.full((2, 3, 3), -1), exists, torch.zeros(2, 3, 0, dtype=torch.bool))
    torch.testing.assert_close(s.false_tracks, torch.tensor([2.0, 0.0]))  # every reported track is false
    for name in FIELDS:
        if name != "false_tracks":
            assert getattr(s, name).shape == (2, 0), name


def test_one_scan_and_a_target_that_never_lives():
    # K = 1: target 0 tracked by slot 1, target 1 living untracked, target 2 never living; slot 0 false
    s = track_scores(torch.tensor([[[-1, 0]]]), torch.tensor([[[True, True]]]), torch.tensor([[[True, True, False]]]))
    assert_scores(s, dict(
        tracks_per_target=[[1.0, 0.0, 0.0]], false_tracks=[1.0], missed_scans=[[0.0, 1.0, 0.0]], alive_scans=[[1.0, 1.0, 0.0]],
        scans_to_first_track=[[0.0, NAN, NAN]], switches=[[0.0, 0.0, 0.0]], fragmentations=[[0.0, 0.0, 0.0]],
    ), [[False, False, False]])


def test_refusals():
    assignment, exists, truth_mask = hand_case()
    with pytest.raises(ValueError, match="loss_scans"):
        track_scores(assignment, exists, truth_mask, loss_scans=0)
    with pytest.raises(ValueError, match="loss_scans"):
        track_scores(assignment, exists, truth_mask, loss_scans=1.5)
    with pytest.raises(ValueError, match="same leading dims"):
        track_scores(assignment, exists[..., :3], truth_mask)
    with pytest.raises(ValueError, match="same leading dims"):
        track_scores(assignment, exists, truth_mask[:, :7])
    with pytest.raises(ValueError, match="bool"):
        track_scores(assignment, exists.to(torch.int64), truth_mask)
    with pytest.raises(ValueError, match="integer"):
        track_scores(assignment.to(torch.float64), exists, truth_mask)
    for bad in (-2, 2):
        a = assignment.clone()
        a[0, 0, 0] = bad
        with pytest.raises(ValueError, match=r"\[-1, 1\]"):
            track_scores(a, exists, truth_mask)
    a = assignment.clone()
    a[0, 3, 1] = 0  # slot 1 also given target 0, which slot 0 holds at scan 3
    with pytest.raises(ValueError, match="two track slots"):
        track_scores(a, exists, truth_mask)
    a = assignment.clone()
    a[1, 3, 3] = 0  # slot 3 of run 1 never exists
    with pytest.raises(ValueError, match="slot that does not exist"):
        track_scores(a, exists, truth_mask)
    a = assignment.clone()
    a[0, 7, 1] = 1  # slot 1 of run 0 did not exist at 7 either; make it exist so only the dead target is wrong
    e = exists.clone()
    e[0, 7, 1] = True
    with pytest.raises(ValueError, match="does not live"):
        track_scores(a, e, truth_mask)
    track_scores(assignment, e, truth_mask)  # the control: the same exists without that pair is accepted


def test_matched_errors_by_hand():
    # state [x, vx, y, vy], positions [0, 2]; velocities are huge so using them would show
    truth_x = torch.tensor([[
        [[0.0, 900, 0.0, 900], [10.0, 900, 10.0, 900], [100.0, 900, 100.0, 900]],  # scan 0
        [[0.0, 900, 0.0, 900], [20.0, 900, 20.0, 900], [NAN, NAN, NAN, NAN]],      # scan 1: target 2 dead
    ]])
    est_x = torch.tensor([[
        [[103.0, -5, 96.0, -5], [NAN, NAN, NAN, NAN], [1.0, -5, 2.0, -5]],
        [[23.0, -5, 24.0, -5], [-2.0, -5, 0.0, -5], [7.0, -5, 7.0, -5]],
    ]])
    # scan 0: slot 0 -> target 2 (3^2 + 4^2), slot 2 -> target 0 (1 + 4), slot 1 padding, target 1 untracked.
    # scan 1: slot 0 -> target 1 (9 + 16), slot 1 -> target 0 (4), slot 2 unassigned.
    assignment = torch.tensor([[[2, -1, 0], [1, 0, -1]]])
    sq, matched = matched_errors(assignment, est_x, truth_x, [0, 2])
    torch.testing.assert_close(sq, torch.tensor([[[5.0, NAN, 25.0], [4.0, 25.0, NAN]]]), equal_nan=True)
    assert torch.equal(matched, torch.tensor([[[True, False, True], [True, True, False]]]))
    # slots permuted (slot i becomes slot perm[i]): the same errors per target
    perm = torch.tensor([2, 0, 1])
    est_p = torch.empty_like(est_x)
    est_p[..., perm, :] = est_x
    a_p = torch.empty_like(assignment)
    a_p[..., perm] = assignment
    sq_p, matched_p = matched_errors(a_p, est_p, truth_x, [0, 2])
    torch.testing.assert_close(sq_p, sq, equal_nan=True)
    assert torch.equal(matched_p, matched)


def test_matched_errors_without_slots_and_refusals():
    truth_x = torch.zeros(2, 3, 2, 4)
    sq, matched = matched_errors(torch.zeros(2, 3, 0, dtype=torch.int64), torch.zeros(2, 3, 0, 4), truth_x, [0, 2])
    assert sq.shape == (2, 3, 2) and bool(sq.isnan().all())
    assert matched.shape == (2, 3, 2) and not bool(matched.any())
    a, est = torch.tensor([[[0, -1], [-1, 1]]]), torch.zeros(1, 2, 2, 4)
    truth = torch.zeros(1, 2, 2, 4)
    with pytest.raises(ValueError, match="est_x"):
        matched_errors(a, est[..., :1, :], truth, [0, 2])
    with pytest.raises(ValueError, match="truth_x"):
        matched_errors(a, est, truth[..., :3], [0, 2])
    with pytest.raises(ValueError, match="pos"):
        matched_errors(a, est, truth, [0, 4])
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        matched_errors(a + 1, est, truth, [0, 2])
    with pytest.raises(ValueError, match="two track slots"):
        matched_errors(torch.tensor([[[0, 0], [-1, 1]]]), est, truth, [0, 2])
    assert not math.isnan(float(matched_errors(a, est, truth, [0, 2])[0][0, 0, 0]))  # the control: target 0 matched
