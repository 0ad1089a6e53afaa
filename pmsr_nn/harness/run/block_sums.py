"""Raw per-block sums of a run or shard (:class:`BlockSums`), and which blocks a shard runs.

Takes what :func:`~.blocks.run_blocks` adds per case, method and block (the sums of
:mod:`.scoring`, seconds, run 0's estimates); gives them stacked over the blocks, written to and
read from a shard's ``blocks.npz`` arrays (:func:`write_shard` and :func:`read_shard`: a shard
folder), and shards' sums concatenated in block order (what
:func:`~pmsr_nn.harness.results.finalise.finalise` reduces). A shard ``I/N`` runs a contiguous
slice of the blocks (:func:`shard_blocks`).
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import ConfigError
from . import scoring

SHARD_FORMAT = "pmsr_nn.evaluation_shard/1"
"""``shard.json``'s format: what ``pmsr evaluate --shard`` (and each block of ``--per-block``) writes."""

FRONT_END = "@front_end"
"""Key of a signal chain's sums and examples in :class:`BlockSums` (beside the methods')."""


def parse_shard(text: str) -> tuple[int, int]:
    """``"I/N"`` (1-based shard I of N) -> ``(I, N)``, with a one-line error for anything else."""
    try:
        index, count = (int(v) for v in text.split("/"))
    except ValueError:
        raise ConfigError(f"shard must look like I/N (e.g. 1/4), got {text!r}") from None
    if not 1 <= index <= count:
        raise ConfigError(f"shard {text}: need 1 <= I <= N")
    return index, count


def shard_blocks(n_blocks: int, shard: tuple[int, int]) -> range:
    """The contiguous blocks shard ``(I, N)`` (1-based shard I of N) runs."""
    index, count = shard
    if count > n_blocks:
        raise ConfigError(f"{count} shards but only {n_blocks} block(s) of Monte Carlo runs; use at most {n_blocks} "
                          "shards, more runs, or a smaller block_runs")
    return range((index - 1) * n_blocks // count, index * n_blocks // count)


@dataclass
class BlockSums:
    """Raw per-block results of a shard: ``sums[case][method][q]`` stacks the blocks' sums of
    quantity ``q`` (:mod:`.scoring` and the kinds' metrics; those kept per run, :func:`.scoring.per_run`,
    concatenate the runs),
    ``seconds[case][method]`` ``(blocks,)``, ``example[case][method]`` run 0's position
    estimates ``(K, N, 2)`` (only a shard holding block 0 has them; ``truth`` too)."""

    blocks: list[int]
    sums: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    example: dict = field(default_factory=dict)

    def add(self, case: str, method: str, values: dict[str, np.ndarray], seconds: float) -> None:
        """One block's sums ``values`` of a method in a case, and its seconds."""
        per = self.sums.setdefault(case, {}).setdefault(method, {})
        for q, v in values.items():
            per.setdefault(q, []).append(np.asarray(v, dtype=np.float64))
        self.seconds.setdefault(case, {}).setdefault(method, []).append(seconds)

    def stacked(self) -> "BlockSums":
        """Lists of blocks joined into arrays (sums stacked, per-run quantities concatenated)."""
        out = BlockSums(self.blocks, example=self.example)
        for c, per in self.sums.items():
            for m, qs in per.items():
                out.sums.setdefault(c, {})[m] = {q: (np.concatenate(v) if scoring.per_run(q) else np.stack(v))
                                                 if isinstance(v, list) else v for q, v in qs.items()}
                s = self.seconds[c][m]
                out.seconds.setdefault(c, {})[m] = np.asarray(s, dtype=np.float64)
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat ``"sums/case/method/q"``-keyed arrays (a shard's ``blocks.npz``)."""
        bs = self.stacked()
        out = {"blocks": np.asarray(bs.blocks, dtype=np.int64)}
        for c, per in bs.sums.items():
            for m, qs in per.items():
                for q, a in qs.items():
                    out[f"sums/{c}/{m}/{q}"] = a
                out[f"seconds/{c}/{m}"] = bs.seconds[c][m]
        for c, per in bs.example.items():
            for m, a in per.items():
                out[f"example/{c}/{m}"] = a
        return out

    @classmethod
    def from_arrays(cls, arrays) -> "BlockSums":
        """The sums :meth:`to_arrays` wrote."""
        bs = cls([int(b) for b in arrays["blocks"]])
        for key in arrays:
            kind, *rest = key.split("/")
            if kind == "sums":
                c, m, q = rest
                bs.sums.setdefault(c, {}).setdefault(m, {})[q] = np.asarray(arrays[key])
            elif kind in ("seconds", "example"):
                c, m = rest
                getattr(bs, kind).setdefault(c, {})[m] = np.asarray(arrays[key])
        return bs

    def split(self, runs: list[int]) -> list["BlockSums"]:
        """One :class:`BlockSums` per block of this (stacked) one, ``runs[i]`` the runs of block
        ``i`` (the per-run quantities' rows); :meth:`concatenate` of the parts gives it back. Run
        0's examples go with block 0."""
        if len(runs) != len(self.blocks):
            raise ValueError(f"{len(runs)} run counts for {len(self.blocks)} blocks")
        starts = np.concatenate([[0], np.cumsum(runs)])
        parts = []
        for i, b in enumerate(self.blocks):
            part = BlockSums([b], example=self.example if b == 0 else {})
            for c, per in self.sums.items():
                for m, qs in per.items():
                    part.sums.setdefault(c, {})[m] = {q: a[starts[i]:starts[i + 1]] if scoring.per_run(q) else a[i:i + 1]
                                                      for q, a in qs.items()}
                    part.seconds.setdefault(c, {})[m] = self.seconds[c][m][i:i + 1]
            parts.append(part)
        return parts

    @classmethod
    def concatenate(cls, parts: list["BlockSums"]) -> "BlockSums":
        """Shards (each :meth:`stacked`) in block order into one."""
        parts = sorted(parts, key=lambda p: p.blocks[0] if p.blocks else -1)
        out = cls([b for p in parts for b in p.blocks])
        for p in parts:
            for c, per in p.sums.items():
                for m, qs in per.items():
                    dst = out.sums.setdefault(c, {}).setdefault(m, {})
                    for q, a in qs.items():
                        dst[q] = a if q not in dst else np.concatenate([dst[q], a])
                    sec = out.seconds.setdefault(c, {})
                    sec[m] = p.seconds[c][m] if m not in sec else np.concatenate([sec[m], p.seconds[c][m]])
            for c, per in p.example.items():
                out.example.setdefault(c, {}).update(per)
        return out


def portable_base(base_dir: str, folder: Path) -> str:
    """A scenario's folder ``base_dir`` (absolute) as a folder's metadata records it: relative to
    ``folder`` (POSIX), so a repository that holds both, cloned to any path, still finds it."""
    return Path(os.path.relpath(Path(base_dir).resolve(), Path(folder).resolve())).as_posix()


def resolved_base(base_dir: str, folder: Path) -> str:
    """The absolute scenario folder a ``base_dir`` recorded in ``folder``'s metadata names: relative
    ones (:func:`portable_base`) are resolved against ``folder``; absolute ones (shards of earlier
    releases) are taken as they are."""
    p = Path(base_dir)
    return str(p if p.is_absolute() else (Path(folder).resolve() / p).resolve())


def write_shard(folder: Path, bs: BlockSums, shard: tuple[int, int], blocks: list[int], identity: dict,
                env: dict) -> dict:
    """A shard's ``shard.json`` and ``blocks.npz`` into ``folder`` (an existing, empty folder) for
    the blocks ``blocks``; ``identity``: the scenario's ``{"scenario": to_dict(), "base_dir": ...}``
    (its folder is recorded relative to ``folder``), ``env``: the environment to record. Returns
    shard.json's content."""
    identity = {**identity, "base_dir": portable_base(identity["base_dir"], folder)}
    meta = {"format": SHARD_FORMAT, "shard": list(shard), "blocks": blocks, **identity, "environment": env}
    np.savez_compressed(folder / "blocks.npz", **bs.to_arrays())
    (folder / "shard.json").write_text(json.dumps(meta, indent=1) + "\n")
    return meta


def read_shard(folder: Path) -> tuple[dict, BlockSums]:
    """A shard folder's ``shard.json`` content (``base_dir`` resolved to an absolute path) and its
    sums, with a one-line :class:`ConfigError` for a folder that is not a readable shard."""
    d = Path(folder)
    if not d.is_dir():
        raise ConfigError(f"{d} is not a folder; give the shard folders 'pmsr evaluate --shard' wrote")
    try:
        meta = json.loads((d / "shard.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise ConfigError(f"{d} is not a shard folder of 'pmsr evaluate --shard' (no readable shard.json)") from None
    if not isinstance(meta, dict) or meta.get("format") != SHARD_FORMAT:
        raise ConfigError(f"{d}/shard.json is not a {SHARD_FORMAT} file")
    if not isinstance(meta.get("scenario"), dict) or not isinstance(meta.get("base_dir"), str):
        raise ConfigError(f"{d}/shard.json lacks its scenario (corrupted?)")
    meta["base_dir"] = resolved_base(meta["base_dir"], d)
    try:
        with np.load(d / "blocks.npz", allow_pickle=False) as f:
            bs = BlockSums.from_arrays({k: f[k] for k in f.files})
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, TypeError, IndexError) as exc:
        first_line = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:120]
        raise ConfigError(f"{d}/blocks.npz is missing or corrupted ({first_line})") from None
    return meta, bs
