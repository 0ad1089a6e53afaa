"""Benchmark: track-steps per second written to disk by `pmsr simulate`, and peak memory.

Each measurement runs in a fresh child process so that its peak resident memory (ru_maxrss) is
its own. Sizes differ by 10x to show that memory stays bounded (chunked generation and writing).
In the same run, a raw write of the same number of bytes (NumPy ``tofile`` in the same chunks)
gives the disk's own speed as a reference, and the ratio is reported.

    python benchmarks/simulate_throughput.py                 # full run (~1 min)
    python benchmarks/simulate_throughput.py --sizes 70 1000 # quick

Prints a Markdown table; with ``--json FILE`` also writes the figures as JSON.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import cpu_model  # noqa: E402


def child(variant: str, tracks: int, out: str) -> dict:
    import numpy as np
    import torch

    from pmsr_nn.data.store import write_dataset
    from pmsr_nn.simulation.recipe import TrackRecipe

    recipe = TrackRecipe(variant=variant, tracks=tracks, seed=0)
    t0 = time.perf_counter()
    manifest = write_dataset(recipe, out, progress=False)
    os.sync()
    seconds = time.perf_counter() - t0
    steps = tracks * recipe.motion.steps
    nbytes = (Path(out) / "tracks.h5").stat().st_size
    # Reference: the same number of bytes written raw, in chunks of the same size.
    chunk_rows = recipe.storage.chunk_tracks * recipe.motion.steps * 15
    block = np.random.default_rng(0).standard_normal(chunk_rows).astype(np.float32)
    ref_path = Path(out).parent / "raw.bin"
    t0 = time.perf_counter()
    written = 0
    with open(ref_path, "wb") as f:
        while written < nbytes:
            block.tofile(f)
            written += block.nbytes
    os.sync()
    raw_seconds = time.perf_counter() - t0
    ref_path.unlink()
    return {
        "variant": variant,
        "tracks": tracks,
        "track_steps": steps,
        "seconds": seconds,
        "track_steps_per_s": steps / seconds,
        "bytes": nbytes,
        "raw_write_seconds": raw_seconds,
        "acceptance": manifest["envelope"]["acceptance"],
        "fraction_left_envelope": manifest["envelope"]["fraction_left"],
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "torch_threads": torch.get_num_threads(),
    }


def normal_sampler_rates(n: int = 10_000_000) -> dict:
    """Standard normals per second from torch's CPU sampler in float64 and in float32 (then cast)."""
    import torch

    from pmsr_nn.rng import standard_normal

    g = torch.Generator().manual_seed(0)
    rates = {}
    for name, fn in (("float64", lambda: torch.randn(n, generator=g, dtype=torch.float64)),
                     ("float32_cast", lambda: standard_normal((n,), g))):
        fn()
        t0 = time.perf_counter()
        fn()
        rates[name] = n / (time.perf_counter() - t0)
    return rates


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[70, 1000, 10000], help="track counts (1000 samples each)")
    ap.add_argument("--variants", nargs="+", default=["envelope", "literal"])
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--child", nargs=3, metavar=("VARIANT", "TRACKS", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]), args.child[2])))
        return
    rows = []
    for variant in args.variants:
        for n in args.sizes:
            with tempfile.TemporaryDirectory(dir=".") as tmp:
                out = subprocess.run([sys.executable, __file__, "--child", variant, str(n), f"{tmp}/d"],
                                     capture_output=True, text=True, check=True)
                rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
                r = rows[-1]
                print(f"# {variant:8s} {n:6d} tracks: {r['track_steps_per_s'] / 1e6:.2f} M steps/s, "
                      f"peak {r['peak_rss_mib']:.0f} MiB", file=sys.stderr)
    info = {
        "date": datetime.date.today().isoformat(),
        "command": "python " + " ".join(sys.argv),
        "machine": f"{cpu_model()}, {os.cpu_count()} cores, {platform.system()}",
        "python": platform.python_version(),
    }
    print(f"Machine: {info['machine']}; Python {info['python']}; date {info['date']}; command `{info['command']}`\n")
    print("| variant | tracks x 1000 s | track-steps/s | wall s | MB on disk | raw write of same bytes, s | ratio to raw write | acceptance | left envelope | peak RSS MiB |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['variant']} | {r['tracks']} | {r['track_steps_per_s'] / 1e6:.2f} M | {r['seconds']:.2f} | "
              f"{r['bytes'] / 1e6:.0f} | {r['raw_write_seconds']:.2f} | {r['seconds'] / max(r['raw_write_seconds'], 1e-9):.1f}x | "
              f"{r['acceptance']:.1%} | {r['fraction_left_envelope']:.1%} | {r['peak_rss_mib']:.0f} |")
    rates = normal_sampler_rates()
    print(f"\nStandard normals (10^7 draws, this process): float64 {rates['float64'] / 1e6:.0f} M/s, "
          f"float32 drawn then cast to float64 {rates['float32_cast'] / 1e6:.0f} M/s "
          f"({rates['float32_cast'] / rates['float64']:.1f}x)")
    if args.json:
        args.json.write_text(json.dumps({"info": info, "rows": rows, "normal_sampler_per_s": rates}, indent=2) + "\n")


if __name__ == "__main__":
    main()
