"""Complex baseband channels of an FM passive radar, one coherent processing interval (CPI) at a time.

One receiver listens to one FM broadcast transmitter on two channels (per transmitter-receiver
pair, the batch dimension): the *reference* channel sees the transmitted waveform at high SNR;
the *surveillance* channel sees the direct-path leakage, static multipath clutter and the echoes
of the targets, each in unit-variance complex white Gaussian noise.

The waveform
------------
Programme material ``m(t)`` is band-limited Gaussian noise (flat spectrum up to
``audio_bandwidth_hz``, zero mean, unit RMS), frequency-modulated with RMS deviation
``deviation_hz`` (broadcast FM allows a 75 kHz peak; 25 kHz RMS keeps it about 3 sigma):
``s(t) = exp(j phi(t))`` with ``phi(t) = 2 pi deviation int m``. The samples of a CPI of ``N``
are preceded by ``history`` samples (the surveillance channel's clutter arriving at the start
of the CPI left the transmitter before it) and the message is made periodic over that buffer of
``L`` samples, so the phase is periodic too and a copy delayed by any fractional number of
samples is exact: ``phi(t - d)`` is the inverse FFT of the phase spectrum times
``exp(-j 2 pi k d / L)`` (no interpolation filter, no edge ringing).

Echoes
------
Target ``t`` of pair ``s`` has its excess delay ``(r - baseline) / c`` and Doppler ``f_d`` taken
at the centre of the CPI (range migration within a 1 s CPI is ``|rdot| * 1 s``, at most a third
of a 937 m bin for airliners; ignored), amplitude from ``echo_snr_db`` (per sample, before
integration) and, when ``echo_range_law`` is on, the bistatic radar equation's ``1 / (R_tx R_rx)^2``
relative to ``echo_reference_range_m`` on both legs; ``fluctuation: swerling1`` draws a complex
Gaussian amplitude per CPI (Rayleigh), ``none`` a random phase only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
from scipy.fft import next_fast_len

from .. import SPEED_OF_LIGHT
from ..config import require
from ..rng import standard_normal


@dataclass(frozen=True)
class FMSignalSpec:
    """Waveform and channel of the simulated FM passive radar (all powers relative to the
    surveillance channel's unit noise power per sample).

    ``sample_rate_hz`` (complex baseband), ``cpi_s`` (one CPI per scan); waveform
    ``audio_bandwidth_hz`` and ``deviation_hz`` (RMS); reference channel SNR ``reference_snr_db``;
    surveillance: direct-path-to-noise ``dnr_db``, static multipath at ``multipath_delay_samples``
    with clutter-to-noise ``multipath_cnr_db`` (zero Doppler), target echoes at
    ``echo_snr_db`` (see the module docstring for the range law and fluctuation).
    """

    sample_rate_hz: float = 320e3
    cpi_s: float = 1.0
    audio_bandwidth_hz: float = 15e3
    deviation_hz: float = 25e3
    reference_snr_db: float = 80.0
    dnr_db: float = 60.0
    multipath_delay_samples: tuple[float, ...] = (1.0, 3.0, 6.0, 10.0)
    multipath_cnr_db: tuple[float, ...] = (50.0, 45.0, 40.0, 35.0)
    echo_snr_db: float = -35.0
    echo_range_law: bool = True
    echo_reference_range_m: float = 20_000.0
    fluctuation: Literal["swerling1", "none"] = "swerling1"

    def __post_init__(self) -> None:
        for name in ("sample_rate_hz", "cpi_s", "audio_bandwidth_hz", "deviation_hz", "echo_reference_range_m"):
            v = getattr(self, name)
            require(math.isfinite(v) and v > 0, f"signal {name} must be positive and finite, got {v}")
        for name in ("reference_snr_db", "dnr_db", "echo_snr_db"):
            v = getattr(self, name)
            require(math.isfinite(v), f"signal {name} must be finite, got {v}")
        require(self.audio_bandwidth_hz < self.sample_rate_hz / 2,
                f"signal audio_bandwidth_hz {self.audio_bandwidth_hz:g} must be below half the sample rate")
        require(len(self.multipath_delay_samples) == len(self.multipath_cnr_db),
                "signal multipath_delay_samples and multipath_cnr_db must have the same length")
        require(all(math.isfinite(d) and d > 0 for d in self.multipath_delay_samples),
                f"signal multipath delays must be positive (samples), got {list(self.multipath_delay_samples)}")
        require(all(math.isfinite(c) for c in self.multipath_cnr_db), "signal multipath_cnr_db must be finite")
        require(self.samples >= 16, f"a CPI of {self.cpi_s:g} s at {self.sample_rate_hz:g} Hz has too few samples")

    @property
    def samples(self) -> int:
        """Samples per CPI ``N``."""
        return int(round(self.sample_rate_hz * self.cpi_s))

    @property
    def range_bin_m(self) -> float:
        """Bistatic range of one delay sample ``c / fs`` (m)."""
        return SPEED_OF_LIGHT / self.sample_rate_hz


@dataclass
class CPI:
    """One CPI of ``B`` channel pairs: ``ref (B, N)`` and ``surv (B, N)`` complex128;
    ``echo_power (B, T)`` each target's per-sample echo power (what the map SNR follows)."""

    ref: torch.Tensor
    surv: torch.Tensor
    echo_power: torch.Tensor


def _phase_spectrum(spec: FMSignalSpec, rows: int, L: int, g: torch.Generator | None) -> torch.Tensor:
    """Spectrum ``(rows, L // 2 + 1)`` of the FM phase over a periodic buffer of ``L`` samples:
    the message's band-limited Gaussian coefficients divided by ``j 2 pi k / L`` (integration)."""
    bins = L // 2 + 1
    k = torch.arange(bins, dtype=torch.float64)
    band = (k >= 1) & (k <= spec.audio_bandwidth_hz / spec.sample_rate_hz * L)
    n_band = int(band.sum())
    coef = torch.zeros(rows, bins, dtype=torch.complex128)
    draw = standard_normal((rows, n_band, 2), g) / math.sqrt(2)
    coef[:, band] = torch.complex(draw[..., 0], draw[..., 1])
    # message m[n] = irfft(coef): unit RMS needs sum |coef|^2 ~ L^2 / 2 over the one-sided band
    coef = coef * (L / math.sqrt(2 * max(n_band, 1)))
    # phi[n] = 2 pi dev / fs * cumulative sum of m  ->  divide each harmonic by j 2 pi k / L, times 2 pi dev / fs
    scale = 2 * math.pi * spec.deviation_hz / spec.sample_rate_hz
    integ = torch.where(band, 1j * 2 * math.pi * k / L, torch.ones_like(k, dtype=torch.complex128))
    return coef * scale / integ


def _unit_phasor(phase: torch.Tensor) -> torch.Tensor:
    """``exp(j phase)`` (cos + j sin is about 3x faster than complex exp on the CPU)."""
    return torch.complex(torch.cos(phase), torch.sin(phase))


def _delayed_phase(Phi: torch.Tensor, delay: torch.Tensor, L: int) -> torch.Tensor:
    """Phase ``phi(n - d)`` ``(rows, L)`` for delays ``d (rows,)`` in samples (fractional allowed)."""
    k = torch.arange(Phi.shape[-1], dtype=torch.float64)
    return torch.fft.irfft(Phi * torch.exp(-2j * math.pi * k * delay[:, None] / L), n=L)


def simulate_cpi(spec: FMSignalSpec, delay_s: torch.Tensor, doppler_hz: torch.Tensor, echo_snr_db: torch.Tensor,
                 present: torch.Tensor, g: torch.Generator | None = None) -> CPI:
    """Reference and surveillance channels of one CPI for ``B`` pairs and ``T`` targets.

    ``delay_s (B, T)`` excess bistatic delays (s, ``(r - baseline) / c``), ``doppler_hz (B, T)``,
    ``echo_snr_db (B, T)`` per-sample echo SNRs, ``present (B, T)`` bool (a target that is not
    alive, or whose delay is negative, adds nothing). Every random draw from ``g``.
    """
    B, T = delay_s.shape
    N, fs = spec.samples, spec.sample_rate_hz
    history = int(math.ceil(max([0.0, *spec.multipath_delay_samples]))) + 1
    present = present & torch.isfinite(delay_s) & (delay_s >= 0)
    d_t = torch.where(present, delay_s * fs, 0.0)
    history = max(history, int(math.ceil(float(d_t.max()))) + 1 if T else history)
    L = next_fast_len(N + history)  # a fast FFT size: the extra samples only lengthen the history
    history = L - N
    Phi = _phase_spectrum(spec, B, L, g)
    window = slice(history, history + N)
    direct = _unit_phasor(torch.fft.irfft(Phi, n=L)[:, window])  # the transmitted waveform, unit power
    noise = standard_normal((2, B, N, 2), g, torch.float64) / math.sqrt(2)
    ref = direct * 10 ** (spec.reference_snr_db / 20) + torch.complex(noise[0, ..., 0], noise[0, ..., 1])
    surv = direct * 10 ** (spec.dnr_db / 20) + torch.complex(noise[1, ..., 0], noise[1, ..., 1])
    n = torch.arange(N, dtype=torch.float64)
    for d, cnr in zip(spec.multipath_delay_samples, spec.multipath_cnr_db):
        phase0 = torch.rand(B, generator=g, dtype=torch.float64) * 2 * math.pi
        path = _unit_phasor(_delayed_phase(Phi, torch.full((B,), float(d), dtype=torch.float64), L)[:, window])
        surv = surv + path * (10 ** (cnr / 20) * torch.exp(1j * phase0))[:, None]
    power = torch.where(present, 10 ** (echo_snr_db / 10), 0.0)
    if spec.fluctuation == "swerling1":
        amp = standard_normal((B, T, 2), g, torch.float64) / math.sqrt(2)
        amp = torch.complex(amp[..., 0], amp[..., 1]) * power.sqrt()
    else:
        amp = power.sqrt() * torch.exp(1j * torch.rand(B, T, generator=g, dtype=torch.float64) * 2 * math.pi)
    for t in range(T):
        if not bool(present[:, t].any()):
            continue
        # Doppler referred to the CPI's centre, where the delay is taken
        phase = _delayed_phase(Phi, d_t[:, t], L)[:, window] + 2 * math.pi * doppler_hz[:, t, None] * (n - N / 2) / fs
        surv = surv + amp[:, t, None] * _unit_phasor(phase)
    return CPI(ref, surv, power)


def echo_snr_db(spec: FMSignalSpec, tx_range_m: torch.Tensor, rx_range_m: torch.Tensor) -> torch.Tensor:
    """Per-sample echo SNR (dB) of targets at these transmitter and receiver distances (m):
    ``echo_snr_db`` at ``echo_reference_range_m`` on both legs, falling as ``(R_tx R_rx)^-2`` when
    the range law is on."""
    if not spec.echo_range_law:
        return torch.full_like(tx_range_m, spec.echo_snr_db)
    ref = spec.echo_reference_range_m
    return spec.echo_snr_db - 20 * torch.log10(tx_range_m * rx_range_m / ref**2)
