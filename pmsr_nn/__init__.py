"""pmsr_nn: target tracking in multistatic passive radar.

Simulators, learned trackers (DFNN / MDFNN / RNN / KalmanNet-style filter, and on detections a
learned JPDA gain), classical filters and bounds, and an
evaluation harness that runs them all on the same Monte Carlo draws.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("pmsr-nn")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

SPEED_OF_LIGHT = 299_792_458.0
"""Speed of light in m/s, used for Doppler and delay conversions."""
