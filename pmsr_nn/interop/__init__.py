"""Bridges to other tracking tools, each an optional extra imported only when asked for.

* :mod:`.stonesoup`: our bistatic measurement model and motion models as Stone Soup models, our
  truth, measurements and detections as Stone Soup objects, Stone Soup tracks as our
  :class:`~pmsr_nn.trackers.base.Estimates` (``pip install "pmsr-nn[stonesoup]"``).

Importing this package imports none of them.
"""
