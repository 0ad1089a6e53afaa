"""The process-wide torch settings a training run changes, given back when it ends.

A training may set torch's thread count (``threads`` in its config) and Lightning's
``deterministic=True`` switches on torch's deterministic algorithms. Both are process-wide, so a
training called in-process (``pmsr demo``, a notebook, the tests) used to leave them set for
everything that ran afterwards: two pytest workers that had each trained a set tracker (removed
since, under issue 56) with ``threads: 2`` then ran every later test on four threads over two
cores, several times slower.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch


@contextmanager
def restored_torch_settings(threads: int | None = None) -> Iterator[None]:
    """Run the block with ``threads`` torch threads (None: as they are), then give the process back
    its own thread count and deterministic-algorithms setting, also when the block raises."""
    own_threads = torch.get_num_threads()
    own_deterministic = torch.are_deterministic_algorithms_enabled()
    own_warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    try:
        if threads:
            torch.set_num_threads(threads)
        yield
    finally:
        torch.set_num_threads(own_threads)
        torch.use_deterministic_algorithms(own_deterministic, warn_only=own_warn_only)
