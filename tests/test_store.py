"""The on-disk dataset: determinism, splits, normalisation, windows, atomic writes, DataModule."""

import json

import h5py
import numpy as np
import pytest
import torch

from pmsr_nn.data import WindowDataset, open_dataset, write_dataset
from pmsr_nn.data.datamodule import TrackWindowDataModule
from pmsr_nn.errors import DatasetError, OutputError
from pmsr_nn.simulation import tracks as tracks_module


def read(path, name):
    with h5py.File(path / "tracks.h5", "r") as f:
        return f[name][()]


@pytest.fixture
def dataset(tmp_path, small_recipe):
    write_dataset(small_recipe, tmp_path / "d", progress=False)
    return tmp_path / "d"


def test_same_seed_gives_byte_identical_arrays(tmp_path, small_recipe):
    write_dataset(small_recipe, tmp_path / "a", progress=False)
    write_dataset(small_recipe, tmp_path / "b", progress=False)
    write_dataset(small_recipe.with_overrides(seed=1), tmp_path / "c", progress=False)
    for name in ("states", "measurements", "noise_std", "split", "violations"):
        assert read(tmp_path / "a", name).tobytes() == read(tmp_path / "b", name).tobytes()
    assert read(tmp_path / "a", "states").tobytes() != read(tmp_path / "c", "states").tobytes()
    ma, mb = (json.loads((tmp_path / d / "manifest.json").read_text()) for d in "ab")
    assert ma["checksums_sha256"] == mb["checksums_sha256"]


def test_manifest_contents(dataset, small_recipe):
    m = open_dataset(dataset).manifest
    assert m["recipe"] == small_recipe.to_dict()
    assert m["seed"] == small_recipe.seed and m["pmsr_nn_version"]
    assert m["shapes"] == {"states": [24, 120, 6], "measurements": [24, 120, 9], "noise_std": [24, 3]}
    assert m["windows_per_track"] == 120 - 20 + 1
    assert set(m["checksums_sha256"]) == {"states", "measurements", "noise_std", "split", "violations"}
    with h5py.File(dataset / "tracks.h5", "r") as f:  # readable without pmsr_nn, manifest inside too
        assert json.loads(f.attrs["manifest"]) == m


def test_splits_are_disjoint_whole_tracks(dataset):
    ds = open_dataset(dataset)
    parts = [set(ds.split_indices(s)) for s in ("train", "val", "test")]
    assert [len(p) for p in parts] == [21, 2, 1]  # 24 tracks: val round(2.4) = 2, test round(1.2) = 1
    assert not (parts[0] & parts[1] or parts[0] & parts[2] or parts[1] & parts[2])
    assert set().union(*parts) == set(range(24))


def test_normalisation_is_fitted_on_training_tracks_only(dataset):
    ds = open_dataset(dataset)
    train = ds.split_indices("train")
    for name in ("states", "measurements"):
        arr = read(dataset, name).astype(np.float64)
        sc = ds.scaler(name)
        np.testing.assert_array_equal(sc.lo.numpy(), arr[train].min((0, 1)))
        np.testing.assert_array_equal(sc.hi.numpy(), arr[train].max((0, 1)))
    # ... which is not what all tracks give
    all_states = read(dataset, "states").astype(np.float64)
    assert not np.array_equal(ds.scaler("states").lo.numpy(), all_states.min((0, 1)))


def test_windows_are_lazy_slices_of_the_tracks(dataset):
    ds = open_dataset(dataset)
    w = WindowDataset(ds, "val", normalise=False, dtype=torch.float64)
    assert len(w) == 2 * 101
    states = read(dataset, "states")
    for i in (0, 100, 101, 201):
        track, start = w.locate(i)
        z, x = w[i]
        np.testing.assert_array_equal(x.numpy(), states[track, start : start + 20])
    assert w.locate(100)[1] + 20 == 120  # the last window ends on the last sample
    with pytest.raises(IndexError):
        w.locate(len(w))


def test_batched_cached_and_lazy_reads_agree(dataset):
    ds = open_dataset(dataset)
    cached = WindowDataset(ds, "train", in_memory=True)
    lazy = WindowDataset(ds, "train", in_memory=False)
    idx = [0, 5, 1999, 101, 77]
    batch = cached.__getitems__(idx)
    for j, i in enumerate(idx):
        for a, b, c in zip(batch[j], cached[i], lazy[i]):
            assert torch.equal(a, b) and torch.equal(b, c)


def test_a_dataset_without_splits_serves_tracking_not_training(tmp_path, small_recipe):
    from pmsr_nn.errors import ConfigError
    from pmsr_nn.simulation.recipe import NO_SPLITS

    write_dataset(small_recipe.with_overrides(tracks=3, splits=NO_SPLITS), tmp_path / "d", progress=False)
    ds = open_dataset(tmp_path / "d")
    try:
        assert ds.manifest["splits"] == {"train": 0, "val": 0, "test": 3} and not ds.has_splits()
        assert ds.manifest["recipe"]["splits"] == {"train": 0.0, "val": 0.0, "test": 1.0}
        assert ds.manifest["normalisation"]["fitted_on"] == "all"  # no training tracks: finite statistics of all
        states = read(tmp_path / "d", "states").astype(np.float64)
        np.testing.assert_array_equal(ds.scaler("states").lo.numpy(), states.min((0, 1)))
        ds.verify()
    finally:
        ds.close()
    json.loads((tmp_path / "d" / "manifest.json").read_text(), parse_constant=pytest.fail)  # no Infinity / NaN
    with pytest.raises(ConfigError, match=r"has no train/val split \(all its 3 tracks are test tracks.*simulate more"):
        TrackWindowDataModule(tmp_path / "d")


def test_window_longer_than_track_is_refused(dataset):
    with pytest.raises(DatasetError, match="longer than the tracks"):
        WindowDataset(dataset, "train", window=121)


def test_datamodule_serves_normalised_pairs(dataset):
    dm = TrackWindowDataModule(dataset, batch_size=64)
    dm.setup("fit")
    z, x = next(iter(dm.train_dataloader()))
    assert z.shape == (64, 20, 9) and x.shape == (64, 20, 6) and z.dtype == torch.float32
    assert float(z.abs().max()) <= 1 + 1e-6 and float(x.abs().max()) <= 1 + 1e-6  # train split spans [-1, 1]
    phys = dm.state_scaler.denormalise(x.double())
    assert float(phys[..., 0].abs().max()) > 100  # back in metres
    loader = dm.train_dataloader()
    again = next(iter(dm.train_dataloader()))
    assert torch.equal(next(iter(loader))[0], again[0])  # shuffling is seeded


def test_verify_detects_corruption(dataset):
    open_dataset(dataset).verify()
    with h5py.File(dataset / "tracks.h5", "r+") as f:
        f["measurements"][3, 7, 2] += 1.0
    with pytest.raises(DatasetError, match="checksum"):
        open_dataset(dataset).verify()


def test_failed_run_leaves_nothing(tmp_path, small_recipe, monkeypatch):
    calls = {"n": 0}
    real = tracks_module.generate_tracks

    def failing(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("disk full")
        return real(*a, **k)

    monkeypatch.setattr("pmsr_nn.data.store.generate_tracks", failing)
    with pytest.raises(RuntimeError):
        write_dataset(small_recipe, tmp_path / "d", progress=False)
    assert list(tmp_path.iterdir()) == []


def test_existing_paths(tmp_path, small_recipe, dataset):
    with pytest.raises(OutputError, match="already exists"):
        write_dataset(small_recipe, dataset, progress=False)
    write_dataset(small_recipe.with_overrides(seed=3), dataset, overwrite=True, progress=False)
    assert open_dataset(dataset).manifest["seed"] == 3
    foreign = tmp_path / "notes"
    foreign.mkdir()
    (foreign / "x.txt").write_text("mine")
    with pytest.raises(DatasetError, match="not a pmsr_nn dataset"):
        write_dataset(small_recipe, foreign, overwrite=True, progress=False)
    assert (foreign / "x.txt").read_text() == "mine"


@pytest.mark.parametrize("damage", ["no_manifest", "bad_json", "foreign_json", "no_arrays"])
def test_open_refuses_incomplete_or_foreign(dataset, damage):
    if damage == "no_manifest":
        (dataset / "manifest.json").unlink()
    elif damage == "bad_json":
        (dataset / "manifest.json").write_text("{ truncated")
    elif damage == "foreign_json":
        (dataset / "manifest.json").write_text('{"format": "something-else"}')
    else:
        (dataset / "tracks.h5").unlink()
    with pytest.raises(DatasetError):
        open_dataset(dataset)


@pytest.mark.parametrize("batches", [None, 3])
def test_epoch_shuffler_equals_torch_random_sampler(batches):
    """The training order equals what a shuffled DataLoader with one seeded generator gives epoch
    after epoch (full epochs, or the first ``batches`` of each), in any order of epochs asked."""
    from itertools import islice

    from torch.utils.data import DataLoader

    from pmsr_nn.data.datamodule import EpochShuffler

    n, bs, seed = 50, 8, 7
    loader = DataLoader(list(range(n)), batch_size=bs, shuffle=True, generator=torch.Generator().manual_seed(seed))
    want = []
    for _ in range(5):
        got = list(islice(iter(loader), batches)) if batches else list(loader)
        want.append(torch.cat(got).tolist())
    s = EpochShuffler(n, seed, full_epochs=batches is None)
    for epoch in (0, 1, 2, 3, 4, 2, 0, 4):  # forwards, then back (a resume), then forwards again
        assert s.order(epoch)[: len(want[epoch])].tolist() == want[epoch]
