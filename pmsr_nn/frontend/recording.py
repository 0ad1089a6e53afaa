"""``pmsr front-end``: the signal chain on recorded (or exported) I/Q samples.

A recording is an HDF5 file with two complex datasets, ``ref`` and ``surv`` (reference and
surveillance channels, the same shape: ``(samples,)`` or ``(cpis, samples per CPI)``) and the
attribute ``sample_rate_hz``. The chain's settings are a :class:`~.chain.FrontEndSpec` in YAML
(the ``front_end:`` block of a scenario; its ``signal`` part gives the sample rate and CPI length
the recording must match; only the processing settings are used). The output folder gets
``maps.h5`` (power after cancellation, the CFAR's detections, per CPI) and ``detections.csv``
(one row per centroided detection: CPI, excess bistatic range, Doppler, SNR and their
deviations), written atomically: a bad file or an interrupt leaves nothing behind.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import torch

from ..config import from_dict, load_yaml
from ..errors import ConfigError, DatasetError
from ..outputs import atomic_folder
from .chain import FrontEndSpec, process_cpi

RECORDING_COMMANDS = ("front-end",)


def load_front_end_spec(path: Path) -> FrontEndSpec:
    """A :class:`FrontEndSpec` from YAML: the file itself, or a scenario's ``detections.front_end:``
    block (or a ``front_end:`` block at the top)."""
    data = load_yaml(Path(path))
    if isinstance(data, dict) and isinstance(data.get("detections"), dict) and "front_end" in data["detections"]:
        data = data["detections"]["front_end"]
    elif isinstance(data, dict) and "front_end" in data:
        data = data["front_end"]
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected the front end's settings (a mapping), got {type(data).__name__}")
    return from_dict(FrontEndSpec, data, where=str(path))


def read_recording(path: Path, spec: FrontEndSpec) -> tuple[np.ndarray, np.ndarray]:
    """``ref, surv (cpis, N)`` complex128 from an HDF5 recording, checked against ``spec``."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise DatasetError(f"{path} is not a readable HDF5 file ({exc})") from None
    with f:
        missing = [k for k in ("ref", "surv") if k not in f]
        if missing:
            raise DatasetError(f"{path} lacks the dataset(s) {missing}: a recording holds complex 'ref' and 'surv'")
        rate = f.attrs.get("sample_rate_hz")
        if rate is None:
            raise DatasetError(f"{path} has no 'sample_rate_hz' attribute")
        if not math.isclose(float(rate), spec.signal.sample_rate_hz, rel_tol=1e-9):
            raise ConfigError(f"{path} was sampled at {float(rate):g} Hz; the settings expect "
                              f"{spec.signal.sample_rate_hz:g} Hz (front_end.signal.sample_rate_hz)")
        ds_ref, ds_surv = f["ref"], f["surv"]
        if ds_ref.shape != ds_surv.shape or ds_ref.ndim not in (1, 2):
            raise DatasetError(f"{path}: 'ref' {ds_ref.shape} and 'surv' {ds_surv.shape} must have one shape, "
                               "(samples,) or (cpis, samples)")
        if not (np.iscomplexobj(np.empty(0, ds_ref.dtype)) and np.iscomplexobj(np.empty(0, ds_surv.dtype))):
            raise DatasetError(f"{path}: 'ref' and 'surv' must be complex samples, got {ds_ref.dtype} / {ds_surv.dtype}")
        ref, surv = np.asarray(ds_ref, dtype=np.complex128), np.asarray(ds_surv, dtype=np.complex128)
    N = spec.signal.samples
    if ref.ndim == 1:
        cpis = ref.shape[0] // N
        ref, surv = ref[: cpis * N].reshape(cpis, N), surv[: cpis * N].reshape(cpis, N)
    if ref.shape[0] == 0 or ref.shape[1] != N:
        raise ConfigError(f"{path}: {ref.shape[-1]:,} samples per CPI; a {spec.signal.cpi_s:g} s CPI at "
                          f"{spec.signal.sample_rate_hz:g} Hz needs {N:,} (and at least one CPI)")
    for name, a in (("ref", ref), ("surv", surv)):
        bad = ~np.isfinite(a.view(np.float64))
        if bad.any():
            where = np.argwhere(bad.reshape(a.shape[0], -1))[0]
            raise ConfigError(f"{path}: '{name}' holds non-finite samples (first in CPI {int(where[0])}, sample "
                              f"{int(where[1]) // 2:,})")
    return ref, surv


def process_recording(recording: Path, settings: Path, out: Path, *, overwrite: bool = False) -> dict:
    """Run the chain on every CPI of ``recording``; write ``out``; return a summary."""
    spec = load_front_end_spec(settings)
    ref, surv = read_recording(Path(recording), spec)
    D, U = spec.map_shape
    rows, power, dets, depth = [], [], [], []
    for lo in range(0, ref.shape[0], spec.chunk_rows):  # CPIs of a chunk processed as one batch
        hi = min(ref.shape[0], lo + spec.chunk_rows)
        res = process_cpi(spec, torch.from_numpy(ref[lo:hi]), torch.from_numpy(surv[lo:hi]))
        c = res.centroids
        f0, df = float(res.doppler_hz[0]), float(res.doppler_hz[1] - res.doppler_hz[0])
        i, j = torch.nonzero(c.valid, as_tuple=True)
        rows.append(torch.stack([(i + lo).to(torch.float64), c.range_bin[i, j] * spec.signal.range_bin_m,
                                 f0 + c.doppler_bin[i, j] * df, c.snr_db[i, j],
                                 c.sd_range_bin[i, j] * spec.signal.range_bin_m, c.sd_doppler_bin[i, j] * df], -1))
        power.append(res.power.to(torch.float32).numpy())
        dets.append(res.detections.numpy())
        depth.append(res.depth_db.numpy())
        doppler_hz = res.doppler_hz.numpy()
    rows = torch.cat(rows).tolist()
    for r in rows:
        r[0] = int(r[0])
    with atomic_folder(Path(out), command="front-end", overwrite=overwrite, inputs=[Path(recording), Path(settings)],
                       allow=RECORDING_COMMANDS) as tmp:
        import h5py

        with h5py.File(tmp / "maps.h5", "w") as f:
            f.attrs["format"] = "pmsr_nn.front_end_maps/1"
            f.create_dataset("power_after", data=np.concatenate(power), compression="gzip")
            f.create_dataset("cfar_detections", data=np.concatenate(dets), compression="gzip")
            f.create_dataset("doppler_hz", data=doppler_hz)
            f.create_dataset("excess_range_m", data=np.arange(U) * spec.signal.range_bin_m)
            f.create_dataset("cancellation_depth_db", data=np.concatenate(depth))
        with open(tmp / "detections.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["cpi", "excess_range_m", "doppler_hz", "snr_db", "sd_range_m", "sd_doppler_hz"])
            w.writerows(rows)
    return {"cpis": ref.shape[0], "detections": len(rows), "map": [D, U],
            "cancellation_depth_db": float(np.concatenate(depth).mean())}
