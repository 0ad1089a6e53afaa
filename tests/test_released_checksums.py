"""``models/released/SHA256SUMS`` lists every released checkpoint with its SHA-256, and nothing else.

The sums are of file bytes the repository ships (not of floats a run computes), so an exact
comparison is the right one: a checkpoint re-trained or re-saved must be re-listed.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

RELEASED = Path(__file__).resolve().parents[1] / "models" / "released"
NOT_RELEASED = {"README.md", "SHA256SUMS"}


def _listed() -> dict[str, str]:
    sums = {}
    for line in (RELEASED / "SHA256SUMS").read_text(encoding="utf-8").splitlines():
        digest, name = line.split(maxsplit=1)
        name = name.lstrip("*")  # sha256sum's binary-mode mark
        assert name not in sums, f"{name} is listed twice"
        sums[name] = digest
    return sums


def test_every_released_file_is_listed_once_and_every_listed_file_exists():
    files = {p.name for p in RELEASED.iterdir() if p.is_file()} - NOT_RELEASED
    assert files, "no released checkpoints found"
    assert set(_listed()) == files


def test_each_listed_sum_is_its_files():
    for name, digest in _listed().items():
        assert hashlib.sha256((RELEASED / name).read_bytes()).hexdigest() == digest, name
