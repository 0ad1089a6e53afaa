"""Settings of the FM front end (:mod:`.chain`): clutter cancellation, the OS-CFAR and the whole
chain of one receiver and its transmitters (map extent, 2D-CCF batches, truth gates, chunks), each
checked on construction with a one-line message."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ..config import require
from ..errors import ConfigError
from .fm_signals import FMSignalSpec


@dataclass(frozen=True)
class CancellationSpec:
    """Direct-path and static clutter cancellation: ``method`` ``eca`` (least squares over
    ``range_bins`` delays and the integer ``doppler_bins``, in ``batches`` sub-blocks: ECA-B when
    more than one), ``nlms`` (``range_bins`` taps, step ``mu``, weights updated every ``block``
    samples) or ``none``."""

    method: Literal["eca", "nlms", "none"] = "eca"
    range_bins: int = 16
    doppler_bins: tuple[int, ...] = (0,)
    batches: int = 1
    mu: float = 0.5
    block: int = 64

    def __post_init__(self) -> None:
        require(self.range_bins >= 1, f"cancellation range_bins must be at least 1, got {self.range_bins}")
        require(self.batches >= 1 and self.block >= 1, "cancellation batches and block must be at least 1")
        require(0 < self.mu < 2, f"cancellation mu must be in (0, 2) for NLMS to converge, got {self.mu}")


@dataclass(frozen=True)
class CfarSpec:
    """2-D OS-CFAR: half-widths of the ``guard`` and ``train`` regions in (Doppler, range) bins,
    the order statistic's ``rank`` (a fraction of the training cells) and ``pfa``.
    ``alpha_factor``: multiplies Eq. 2's scale factor; 1 assumes independent cells, which an FM
    reference's range correlation breaks (1.25x ``pfa`` on the scenario's maps); the value for a
    reference is measured on noise-only maps by ``evaluate/fm_cfar_false_alarms.py``
    (:func:`~.cfar.calibrate_alpha_factor`; 1.027 for the scenario's FM reference and Hamming taper)."""

    guard: tuple[int, int] = (2, 1)
    train: tuple[int, int] = (8, 4)
    rank: float = 0.75
    pfa: float = 1e-4
    alpha_factor: float = 1.0

    def __post_init__(self) -> None:
        require(len(self.guard) == 2 and len(self.train) == 2 and min(*self.guard, *self.train) >= 0,
                f"cfar guard and train are two non-negative half-widths (Doppler, range), got {self.guard} / {self.train}")
        require(0 < self.pfa < 1, f"cfar pfa must be in (0, 1), got {self.pfa}")
        require(0 < self.rank <= 1, f"cfar rank is a fraction of the training cells in (0, 1], got {self.rank}")
        require(math.isfinite(self.alpha_factor) and self.alpha_factor > 0,
                f"cfar alpha_factor must be positive and finite, got {self.alpha_factor}")

    def window(self) -> tuple[int, int]:
        """Full window (Doppler, range) in bins."""
        return 2 * (self.guard[0] + self.train[0]) + 1, 2 * (self.guard[1] + self.train[1]) + 1


@dataclass(frozen=True)
class FrontEndSpec:
    """The signal chain of one receiver and its transmitters: the simulated ``signal``, the map
    out to ``max_range_m`` of excess bistatic range (delay bins of ``c / fs``) and
    ``+-max_doppler_hz`` (below the batches' ambiguity ``fs / (2 batch_len)``: the map is not
    circular in Doppler and the CFAR does not wrap), the 2D-CCF's ``batch_len`` (batches
    algorithm: 640 samples at 320 kHz span +-250 Hz, 2.4 dB straddle loss at 200 Hz) and its
    Doppler ``window``,
    ``cancellation`` and ``cfar``; ``gate_cells`` (Doppler, range bins) for the truth labels of the
    statistics; ``chunk_rows`` (run, pair) rows processed at once; ``example_scans``: scans whose maps
    run 0 keeps for the figures and ``maps.h5``."""

    signal: FMSignalSpec = FMSignalSpec()
    max_range_m: float = 48_000.0
    max_doppler_hz: float = 200.0
    batch_len: int = 640
    window: str = "hamming"
    cancellation: CancellationSpec = CancellationSpec()
    cfar: CfarSpec = CfarSpec()
    gate_cells: tuple[float, float] = (3.0, 2.0)
    chunk_rows: int = 12
    example_scans: tuple[int, ...] = (0,)

    def __post_init__(self) -> None:
        s = self.signal
        require(self.max_range_m > 0 and math.isfinite(self.max_range_m), "front_end max_range_m must be positive")
        require(self.range_bins >= 2, f"a sample rate of {s.sample_rate_hz:g} Hz gives {s.range_bin_m:.0f} m delay bins: it "
                                      f"can not resolve the requested max_range_m {self.max_range_m:g} (fewer than 2 bins)")
        carson = 2 * (3 * s.deviation_hz + s.audio_bandwidth_hz)
        require(carson <= s.sample_rate_hz, f"a sample rate of {s.sample_rate_hz:g} Hz can not hold the FM signal (Carson "
                                            f"bandwidth 2 (3 x {s.deviation_hz:g} + {s.audio_bandwidth_hz:g}) = {carson:g} Hz)")
        require(s.samples > max(self.range_bins, self.cancellation.range_bins),
                f"the CPI of {s.samples} samples is shorter than the longest delay ({max(self.range_bins, self.cancellation.range_bins)} bins)")
        require(self.batch_len >= self.range_bins and s.samples % self.batch_len == 0,
                f"front_end batch_len {self.batch_len} must divide the CPI's {s.samples} samples and be at least the "
                f"{self.range_bins} range bins")
        # below the batches' Doppler ambiguity fs / (2 batch_len), where +f and -f are one bin
        require(0 < self.max_doppler_hz < s.sample_rate_hz / (2 * self.batch_len),
                f"front_end max_doppler_hz must be in (0, fs / (2 batch_len) = {s.sample_rate_hz / (2 * self.batch_len):g})")
        require(self.chunk_rows >= 1, "front_end chunk_rows must be at least 1")
        require(all(g > 0 for g in self.gate_cells), "front_end gate_cells must be positive")
        require(all(k >= 0 for k in self.example_scans), "front_end example_scans must be scan indices")
        D, U = self.map_shape
        w = self.cfar.window()
        if w[0] > D or w[1] > U:
            raise ConfigError(f"the CFAR window of {w[0]} x {w[1]} (Doppler x range) bins is larger than the "
                              f"{D} x {U} map")

    @property
    def range_bins(self) -> int:
        """Delay bins of the map, 0..U-1 (bin 0: the direct path)."""
        return int(self.max_range_m // self.signal.range_bin_m) + 1

    @property
    def doppler_bin_hz(self) -> float:
        return 1.0 / self.signal.cpi_s

    @property
    def map_shape(self) -> tuple[int, int]:
        """(Doppler bins, range bins) of one map."""
        D = 2 * int(math.floor(self.max_doppler_hz / self.doppler_bin_hz + 1e-9)) + 1
        return D, self.range_bins
