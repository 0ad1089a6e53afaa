"""``pmsr evaluate --per-block``: a long recording banked one block of runs at a time.

A scenario whose runs take hours (``evaluate/one_sky.yaml``: ~13 core-minutes a run) is recorded
over several sittings or pre-emptible jobs. With ``--per-block`` the blocks of a shard are run one
after another in one process (one untimed warm-up), and each is written, as soon as it is done,
as the one-block shard folder ``OUT/block-NNNN`` (``shard.json`` + ``blocks.npz``, exactly what
``--shard (b+1)/n_blocks`` writes, atomically). Blocks already in ``OUT`` are skipped, so the same
command continues an interrupted recording; ``pmsr merge OUT`` (with any other shard folders
covering the rest) gives the whole run's figures, bit for bit, timings aside. Several processes
may fill one bank at once (one per core, the same command): each claims a block before running
it (``.block-NNNN.claim``, holding its PID) and passes over blocks a live process holds; the claim
of a process that is gone is taken over.

``OUT/bank.json`` names the scenario (its settings and folder) the bank holds blocks of: a
command with another scenario or other settings is refused before anything runs, and a block
folder that is not a complete shard of the bank's scenario is reported, never replaced. A bank
whose ``bank.json`` was deleted (its marker still says ``--per-block`` made it) gets it back when
every block's ``shard.json`` names the command's scenario and settings (a block holds what
``bank.json`` held); otherwise it is refused in one line. ``pmsr merge`` needs no ``bank.json``:
it reads the blocks, which name their scenario themselves.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from ...environment import environment
from ...errors import ConfigError, OutputError
from ...outputs import MARKER, atomic_folder, check_target, make_parents, output_kind, process_alive, write_marker
from .batches import batch_groups, blocks_per_call
from .block_sums import portable_base, read_shard, resolved_base, write_shard
from .blocks import run_blocks
from .runner import Run

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


def made_per_block(path: Path) -> bool:
    """True when our marker says ``pmsr evaluate --per-block`` made folder ``path`` (a bank, with
    its ``bank.json`` or without it)."""
    if output_kind(path) != "evaluate":
        return False
    try:
        return json.loads((Path(path) / MARKER).read_text(encoding="utf-8")).get("per_block") is True
    except (OSError, ValueError, AttributeError):
        return False


def bank_identity(bank: Path) -> dict:
    """``{"scenario", "base_dir"}`` of bank ``bank``: the scenario (as ``Scenario.to_dict`` wrote
    it) and its absolute folder, from its ``bank.json``, or, where that was deleted, from a
    block's ``shard.json``; anything else at ``bank`` is refused in one line."""
    if is_bank(bank):
        meta = Path(bank) / BANK_FILE
    elif made_per_block(bank) and bank_blocks(bank):  # bank.json deleted: every block names the scenario too
        meta = bank_blocks(bank)[0] / "shard.json"
    else:
        raise ConfigError(f"{bank} is not a block bank of 'pmsr evaluate --per-block'")
    return _identity(json.loads(meta.read_text(encoding="utf-8")), meta.parent)


def bank_scenario(bank: Path) -> dict:
    """The scenario that bank ``bank`` runs (:func:`bank_identity`)."""
    return bank_identity(bank)["scenario"]


def bank_blocks(bank: Path) -> list[Path]:
    """The block folders of a bank, in block order (complete ones: a killed block leaves only a
    hidden temporary, which is not listed)."""
    return sorted(p for p in Path(bank).glob("block-[0-9][0-9][0-9][0-9]") if p.is_dir())


def _open_bank(out: Path, identity: dict) -> str | None:
    """Create bank ``out`` for ``identity`` (scenario and base folder), or check an existing one is
    a bank of the same identity (one that lost its ``bank.json`` gets it back from its blocks:
    returns the line that says so); anything else at ``out`` is refused."""
    if out.is_symlink():
        raise OutputError(f"--out {out} is a symbolic link; give the real folder or a new path")
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out} exists and is a file, not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not is_bank(out) and made_per_block(out):  # a bank whose bank.json is gone
            return _rebuild(out, identity)
        if not is_bank(out):
            kind = output_kind(out)
            what = f"the output of 'pmsr {kind}'" if kind else "files pmsr did not write"
            raise OutputError(f"--out {out} holds {what}, not blocks of 'pmsr evaluate --per-block'; choose another "
                              "path")
        if _identity(json.loads((out / BANK_FILE).read_text(encoding="utf-8")), out) != identity:
            raise ConfigError(f"--out {out} holds blocks of another scenario or other settings; give another --out "
                              "(or the same scenario file and options as the bank's first command)")
        return None
    make_parents(out)
    out.mkdir(exist_ok=True)
    # renamed into place, then marked: a process starting beside this one sees no bank or a whole one
    tmp = _bank_file(out, identity)
    os.replace(tmp, out / BANK_FILE)
    write_marker(out, "evaluate", per_block=True)  # lists no contents: the bank grows block by block
    return None


def _bank_file(out: Path, identity: dict) -> Path:
    """``bank.json`` of ``identity`` for bank ``out``, written to a hidden temporary beside it (returned)."""
    tmp = out / f".{BANK_FILE}.{os.getpid()}"
    held = {"format": BANK_FORMAT, **identity, "base_dir": portable_base(identity["base_dir"], out)}
    try:
        with open(tmp, "x", encoding="utf-8") as f:  # created here or refused: the caller removes only ours
            f.write(json.dumps(held, indent=1) + "\n")
    except FileExistsError:
        raise OutputError(f"--out {out}: the temporary name {tmp} is taken; remove it if it is not yours") from None
    return tmp


def _rebuild(out: Path, identity: dict) -> str:
    """Write the ``bank.json`` that bank ``out`` lost, when every block it holds is a complete
    block of ``identity`` (each block's ``shard.json`` names the scenario and its folder, as
    ``bank.json`` did); refused in one line otherwise. Never written over a file that is there."""
    blocks = bank_blocks(out)
    have = f"--out {out} has {len(blocks)} block(s) of 'pmsr evaluate --per-block'"
    if (out / BANK_FILE).exists() or (out / BANK_FILE).is_symlink():
        raise OutputError(f"{have} and a {BANK_FILE} that is not a bank's (unreadable, or of another format); "
                          "move that file away and run again: the bank's file is then rebuilt from its blocks")
    bad = [b.name for b in blocks if not _matches(b, identity)]
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise ConfigError(f"{have} but no {BANK_FILE}, and {bad[0]}{more} is not a complete block of this "
                          "scenario and settings, so the bank's file cannot be rebuilt: give the scenario file and "
                          "options of the bank's first command, or another --out")
    tmp = _bank_file(out, identity)
    try:
        os.link(tmp, out / BANK_FILE)  # never over a file put there since the look above
    except FileExistsError:
        if not is_bank(out) or _identity(json.loads((out / BANK_FILE).read_text(encoding="utf-8")), out) != identity:
            raise ConfigError(f"--out {out}: a {BANK_FILE} appeared while this command was rebuilding it, and it is "
                              "not this scenario's; give another --out") from None
    finally:
        tmp.unlink(missing_ok=True)
    if not blocks:
        return f"bank {out}: {BANK_FILE} was missing; written again (the bank holds no block yet)"
    return (f"bank {out}: {BANK_FILE} was missing; rebuilt from its {len(blocks)} block(s), which name this "
            "command's scenario and settings")


def _identity(meta: dict, folder: Path) -> dict:
    """The scenario and absolute scenario folder that metadata ``meta`` read from ``folder``
    (``bank.json`` or a block's ``shard.json``) names; a relative folder is resolved against
    ``folder``, so a bank committed with its scenario works from a clone at any path."""
    base = meta.get("base_dir")
    return {"scenario": meta.get("scenario"), "base_dir": resolved_base(base, folder) if isinstance(base, str) else None}


def _holder(claim: Path) -> int | None:
    """The PID a claim file holds (None: gone, or not a claim this package wrote: a PID alone)."""
    try:
        text = claim.read_text(encoding="utf-8")
    except OSError:
        return None
    return int(text) if text.strip().isdigit() and text == f"{int(text)}\n" else None


def _claim(bank: Path, block: int) -> Path | None:
    """Claim ``block`` for this process (a hidden ``.block-NNNN.claim`` holding its PID, created
    whole by a hard link, so two processes never both hold it); a claim of a process that is gone
    is taken over. Returns the claim's path, or None when a live process holds the block."""
    claim = Path(bank) / f".block-{block:04d}.claim"
    mine = Path(bank) / f".block-{block:04d}.claim-{os.getpid()}"
    try:
        with open(mine, "x", encoding="utf-8") as f:  # never over a file someone else put there
            f.write(f"{os.getpid()}\n")
    except FileExistsError:
        if _holder(mine) != os.getpid():  # left by an earlier process with this PID is ours; anything else is not
            return None
    try:
        for _ in range(2):
            try:
                os.link(mine, claim)
                return claim
            except FileExistsError:
                holder = _holder(claim)
                if holder is None or process_alive(holder):  # live, or not a claim of ours: never removed
                    return None
                if _holder(claim) == holder:  # still the dead process's (not one just taken over by another)
                    claim.unlink(missing_ok=True)  # its process is gone (killed, or the session ended)
        return None
    finally:
        mine.unlink(missing_ok=True)


def _matches(folder: Path, identity: dict) -> bool:
    """Whether ``folder`` holds a complete one-block shard of the scenario ``identity`` names."""
    try:
        meta = json.loads((folder / "shard.json").read_text(encoding="utf-8"))
        return (_identity(meta, folder) == identity and (folder / "blocks.npz").is_file()
                and (folder / MARKER).is_file())
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def _complete(folder: Path, identity: dict) -> bool:
    """Whether ``folder`` holds a complete one-block shard of the bank's scenario; a folder that is
    there but is not one is an error (it is never replaced)."""
    if not folder.exists():
        return False
    if not _matches(folder, identity):
        raise OutputError(f"{folder} is not a complete block of this bank's scenario (no readable shard.json, "
                          "blocks.npz or marker); move it away and run again")
    return True


def open_bank(run: Run) -> str | None:
    """Open the bank of ``run`` (target ``bank``) without running a block: create it, or check
    that the one there is this scenario's (a foreign one is refused in one line); returns the line
    that says a lost ``bank.json`` was rebuilt, if one was."""
    sc = run.scenario
    return _open_bank(run.out, {"scenario": sc.to_dict(), "base_dir": sc.base_dir})


def run_bank(run: Run, log=print) -> dict:
    """Run the blocks of ``run`` (a :class:`~.runner.Run` with target ``bank``: its shard's blocks)
    that its bank lacks and no live process holds, each written when done; returns the blocks it
    ran (``blocks``), found done (``skipped``) and left to other processes (``others``), the bank's
    path and how many blocks of ``n_blocks`` it holds now (``banked``)."""
    sc, out, shard, inputs, progress = run.scenario, run.out, run.shard, list(run.inputs), run.progress
    blocks, setup = run.blocks, run.setup
    identity = {"scenario": sc.to_dict(), "base_dir": sc.base_dir}
    env = environment(run.device)  # the code this process runs: commits made while it works do not change it
    note = _open_bank(out, identity)
    if note:
        log(note)
    skipped = [b for b in blocks if _complete(block_folder(out, b), identity)]
    if progress and skipped:
        log(f"bank {out}: {len(skipped)} of shard {shard[0]}/{shard[1]}'s {len(blocks)} block(s) already there")
    ran, others = [], []
    todo = [b for b in blocks if b not in skipped]
    for group in batch_groups(todo, blocks_per_call(run.batch_runs, sc.block_runs)):
        claims = {}
        try:
            for b in group:
                claim = _claim(out, b)
                if claim is None:  # another process is running it
                    others.append(b)
                elif _complete(block_folder(out, b), identity):  # finished by another process since the look above
                    claim.unlink(missing_ok=True)
                    skipped.append(b)
                else:
                    claims[b] = claim
            if not claims:
                continue
            mine = sorted(claims)
            t0 = time.perf_counter()
            bs = run_blocks(setup, mine, progress=progress, batch_runs=run.batch_runs)
            parts = bs.split([len(sc.block_runs_range(b)) for b in mine]) if len(mine) > 1 else [bs]
            for b, part in zip(mine, parts):
                with atomic_folder(block_folder(out, b), command="evaluate", inputs=inputs, allow=("evaluate",)) as tmp:
                    write_shard(tmp, part, (b + 1, sc.n_blocks), [b], identity, env)
                ran.append(b)
                if progress:
                    log(f"block {b + 1}/{sc.n_blocks} -> {block_folder(out, b)} "
                        f"({(time.perf_counter() - t0) / len(mine):.0f} s)")
        finally:
            for claim in claims.values():
                claim.unlink(missing_ok=True)
    done = len(bank_blocks(out))
    if progress:
        busy = f"; {len(others)} being run by other processes" if others else ""
        log(f"bank {out}: {done} of {sc.n_blocks} block(s){busy}; 'pmsr merge {out}' once all are there")
    return {"blocks": ran, "skipped": skipped, "others": others, "bank": str(out), "banked": done,
            "n_blocks": sc.n_blocks}


def file_shard(shard: Path, bank: Path) -> list[int]:
    """File the blocks of shard folder ``shard`` (``pmsr evaluate --shard``) into bank ``bank`` as
    one-block folders, as if the bank had run them (the sums, timings and the shard's environment
    unchanged; ``environment.filed_from`` names the shard); blocks the bank holds already are left
    as they are. The bank is made if it does not exist. Returns the blocks filed."""
    meta, bs = read_shard(Path(shard))
    identity = {"scenario": meta["scenario"], "base_dir": meta["base_dir"]}
    runs, per_block = int(meta["scenario"]["mc_runs"]), int(meta["scenario"]["block_runs"])
    n_blocks = -(-runs // per_block)
    bank = Path(bank)
    check_target(bank, inputs=[shard])
    _open_bank(bank, identity)
    filed = []
    counts = [min(runs, (b + 1) * per_block) - b * per_block for b in bs.blocks]
    for b, part in zip(bs.blocks, bs.split(counts)):
        if _complete(block_folder(bank, b), identity):
            continue
        env = {**meta.get("environment", {}), "filed_from": str(shard)}
        with atomic_folder(block_folder(bank, b), command="evaluate", inputs=[shard], allow=("evaluate",)) as tmp:
            write_shard(tmp, part, (b + 1, n_blocks), [b], identity, env)
        filed.append(b)
    return filed
