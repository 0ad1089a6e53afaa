"""What a figure test checks of a written PNG: it decodes, has a usable size and holds a drawing."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def assert_drawn_png(path: Path, min_side: int = 200, min_colours: int = 3) -> np.ndarray:
    """Decode ``path`` as a PNG and check it is at least ``min_side`` pixels on each side and holds
    at least ``min_colours`` distinct colours (a blank or one-colour image fails); returns the
    pixels ``(H, W, channels)``."""
    import matplotlib.image

    img = matplotlib.image.imread(Path(path))
    assert img.ndim == 3 and min(img.shape[:2]) >= min_side, (path, img.shape)
    colours = np.unique(img.reshape(-1, img.shape[-1]), axis=0)
    assert len(colours) >= min_colours, (path, len(colours))
    return img
