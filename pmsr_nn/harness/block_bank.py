"""``pmsr evaluate --per-block``: a long recording banked one block of runs at a time.

A scenario whose runs take hours (``evaluate/one_sky.yaml``: ~13 core-minutes a run) is recorded
over several sittings or pre-emptible jobs. With ``--per-block`` the blocks of a shard are run one
after another in one process (one untimed warm-up), and each is written, as soon as it is done,
as the one-block shard folder ``OUT/block-NNNN`` (``shard.json`` + ``blocks.npz``, exactly what
``--shard (b+1)/n_blocks`` writes, atomically). Blocks already in ``OUT`` are skipped, so the same
command continues an interrupted recording; ``pmsr merge OUT`` (with any other shard folders
covering the rest) gives the whole run's figures, bit for bit, timings aside.

``OUT/bank.json`` names the scenario (its settings and folder) the bank holds blocks of: a
command with another scenario or other settings is refused before anything runs, and a block
folder that is not a complete shard of the bank's scenario is reported, never replaced.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..environment import environment
from ..errors import ConfigError, OutputError
from ..outputs import (MARKER, atomic_folder, check_target, make_parents, output_kind, write_marker)
from .block_sums import shard_blocks, write_shard
from .blocks import run_blocks
from .runner import prepare

BANK_FORMAT = "pmsr_nn.block_bank/1"
BANK_FILE = "bank.json"


def block_folder(bank: Path, block: int) -> Path:
    """Where block ``block`` (0-based) of a bank lives."""
    return Path(bank) / f"block-{block:04d}"


def is_bank(path: Path) -> bool:
    """True when ``path`` is a block bank (a folder with our ``bank.json``)."""
    try:
        return json.loads((Path(path) / BANK_FILE).read_text(encoding="utf-8")).get("format") == BANK_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def bank_blocks(bank: Path) -> list[Path]:
    """The block folders of a bank, in block order (complete ones: a killed block leaves only a
    hidden temporary, which is not listed)."""
    return sorted(p for p in Path(bank).glob("block-[0-9][0-9][0-9][0-9]") if p.is_dir())


def _open_bank(out: Path, identity: dict) -> None:
    """Create bank ``out`` for ``identity`` (scenario and base folder), or check an existing one is
    a bank of the same identity; anything else at ``out`` is refused."""
    if out.is_symlink():
        raise OutputError(f"--out {out} is a symbolic link; give the real folder or a new path")
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out} exists and is a file, not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not is_bank(out):
            kind = output_kind(out)
            what = f"the output of 'pmsr {kind}'" if kind else "files pmsr did not write"
            raise OutputError(f"--out {out} holds {what}, not blocks of 'pmsr evaluate --per-block'; choose another "
                              "path")
        held = json.loads((out / BANK_FILE).read_text(encoding="utf-8"))
        if {k: held.get(k) for k in identity} != identity:
            raise ConfigError(f"--out {out} holds blocks of another scenario or other settings; give another --out "
                              "(or the same scenario file and options as the bank's first command)")
        return
    make_parents(out)
    out.mkdir(exist_ok=True)
    (out / BANK_FILE).write_text(json.dumps({"format": BANK_FORMAT, **identity}, indent=1) + "\n", encoding="utf-8")
    write_marker(out, "evaluate", per_block=True)  # lists no contents: the bank grows block by block


def _complete(folder: Path, identity: dict) -> bool:
    """Whether ``folder`` holds a complete one-block shard of the bank's scenario; a folder that is
    there but is not one is an error (it is never replaced)."""
    if not folder.exists():
        return False
    try:
        meta = json.loads((folder / "shard.json").read_text(encoding="utf-8"))
        ok = (meta["scenario"] == identity["scenario"] and meta["base_dir"] == identity["base_dir"]
              and (folder / "blocks.npz").is_file() and (folder / MARKER).is_file())
    except (OSError, ValueError, KeyError, TypeError):
        ok = False
    if not ok:
        raise OutputError(f"{folder} is not a complete block of this bank's scenario (no readable shard.json, "
                          "blocks.npz or marker); move it away and run again")
    return True


def evaluate_per_block(sc, out: Path, *, shard: tuple[int, int], inputs: list[Path], device: str = "cpu",
                       progress: bool = True, log=print) -> dict:
    """Run the blocks of ``shard`` of scenario ``sc`` (loaded) that bank ``out`` lacks, each written
    when done; returns ``{"blocks": [...run], "skipped": [...], "bank": str(out)}``."""
    out = Path(out)
    check_target(out, inputs=inputs)
    blocks = shard_blocks(sc.n_blocks, shard)
    identity = {"scenario": sc.to_dict(), "base_dir": sc.base_dir}
    setup = prepare(sc, device)  # a method that cannot run is refused before the bank is touched
    env = environment(device)  # the code this process runs: commits made while it works do not change it
    _open_bank(out, identity)
    skipped = [b for b in blocks if _complete(block_folder(out, b), identity)]
    todo = [b for b in blocks if b not in skipped]
    if progress and skipped:
        log(f"bank {out}: {len(skipped)} of shard {shard[0]}/{shard[1]}'s {len(blocks)} block(s) already there")
    for b in todo:
        t0 = time.perf_counter()
        with atomic_folder(block_folder(out, b), command="evaluate", inputs=inputs, allow=("evaluate",)) as tmp:
            bs = run_blocks(setup, range(b, b + 1), progress=progress)
            write_shard(tmp, bs, (b + 1, sc.n_blocks), [b], sc, device, env)
        if progress:
            log(f"block {b + 1}/{sc.n_blocks} -> {block_folder(out, b)} ({time.perf_counter() - t0:.0f} s)")
    done = len(bank_blocks(out))
    if progress:
        log(f"bank {out}: {done} of {sc.n_blocks} block(s); 'pmsr merge {out}' once all are there")
    return {"blocks": todo, "skipped": skipped, "bank": str(out), "banked": done, "n_blocks": sc.n_blocks}
