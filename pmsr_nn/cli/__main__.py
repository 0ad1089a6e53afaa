"""``python -m pmsr_nn.cli ARGS``: the ``pmsr`` command (DDP re-runs it this way for its workers)."""

import sys

from . import main

if __name__ == "__main__":  # not when a spawned worker re-imports it as __mp_main__
    sys.exit(main())
