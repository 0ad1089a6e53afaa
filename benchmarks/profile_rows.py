"""Profile: one Monte Carlo run of each row of a study, and what bounds it.

For each row (method) of the scenario's first case, on block 0 (one run), after one untimed
warm-up call on the same draws:

1. ``seconds``: the plain call's wall-clock time;
2. ``ops``, ``flops``, ``elements``: every aten operation the call dispatches (a
   ``TorchDispatchMode`` counting them): their number, an arithmetic count (``2 m n k`` per matrix
   product, ``n^3`` per matrix of a factorisation or solve, one per output element otherwise: an
   estimate, not a hardware counter) and the elements they write;
3. ``top``: the call under ``cProfile``, its functions with the most own time (``tottime``).

Beside these, the machine's own figures, measured in the same process (one thread):
``dispatch_us`` (seconds per tiny torch operation: what a Python loop over small tensors pays per
step), ``gflops`` (a large float64 matrix product) and ``gelems`` (a large float64 elementwise
product, elements per second). Each row then gets two floors: ``ops * dispatch_us`` (the row were
it only dispatch overhead) and ``flops / gflops`` (were it only arithmetic at the matrix product's
rate); the larger, against ``seconds``, says how far the row is from what this machine allows and
which of the two bounds it. Time outside torch (numpy, scipy, Python) is in ``top``.

    OMP_NUM_THREADS=1 python benchmarks/profile_rows.py evaluate/one_sky.yaml \\
        --skip "Stone Soup JPDA" --json benchmarks/results/profile_one_sky.json
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import sys
import time
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import median_seconds, write_figures  # noqa: E402
from scenario import first_block  # noqa: E402

from pmsr_nn.harness.run.blocks import call_method  # noqa: E402

MATMUL = {"mm", "bmm", "addmm", "baddbmm", "addbmm", "matmul", "dot", "mv", "addmv", "linear"}
CUBIC = frozenset({"cholesky", "solve", "inv", "inverse", "lu", "eigh", "eigvalsh", "svd", "qr", "det", "slogdet",
                   "logdet", "triangular"})
"""Words of the factorisations' and solves' aten names (``linalg_solve_triangular``, ``_linalg_det``):
matched as whole words, so ``sqrt`` is not a QR and ``detach`` not a determinant."""


def _shape(t) -> tuple[int, ...]:
    return tuple(t.shape) if isinstance(t, torch.Tensor) else ()


def _numel(out) -> int:
    if isinstance(out, torch.Tensor):
        return out.numel()
    if isinstance(out, (tuple, list)):
        return sum(_numel(o) for o in out)
    return 0


def _prod(xs) -> int:
    n = 1
    for x in xs:
        n *= x
    return n


class OpCounter(TorchDispatchMode):
    """Counts aten operations, an arithmetic estimate and the elements they write (see the module)."""

    def __init__(self):
        super().__init__()
        self.ops = 0
        self.flops = 0
        self.elements = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        name = func.__name__.split(".")[0]
        n_out = _numel(out)
        self.ops += 1
        self.elements += n_out
        tensors = [a for a in args if isinstance(a, torch.Tensor)]
        if name in MATMUL and len(tensors) >= 2 and tensors[-1].dim() >= 1:
            k = _shape(tensors[-2])[-1] if tensors[-2].dim() else 1
            self.flops += 2 * n_out * k
        elif not CUBIC.isdisjoint(name.split("_")) and tensors and tensors[0].dim() >= 2:
            shape = _shape(tensors[0])
            self.flops += _prod(shape[:-2]) * shape[-1] ** 3
        else:
            self.flops += n_out
        return out


def machine_figures() -> dict:
    """Seconds per tiny operation, float64 matrix-product GFLOP/s, elementwise G elements/s."""
    a = torch.ones(4, dtype=torch.float64)
    n_tiny = 20000

    def tiny():
        x = a
        for _ in range(n_tiny):
            x = x + a
    dispatch = median_seconds(tiny, 5) / n_tiny
    m = torch.randn(1024, 1024, dtype=torch.float64)
    gflops = 2 * 1024**3 / median_seconds(lambda: m @ m, 5) / 1e9
    v = torch.randn(8_000_000, dtype=torch.float64)
    gelems = v.numel() / median_seconds(lambda: v * v, 5) / 1e9
    return {"dispatch_us": dispatch * 1e6, "gflops": gflops, "gelems": gelems}


def profile_row(setup, spec, case, products, seed, top: int) -> dict:
    call_method(setup, spec, case, products, seed)  # warm-up, untimed
    t0 = time.perf_counter()
    call_method(setup, spec, case, products, seed)
    seconds = time.perf_counter() - t0
    counter = OpCounter()
    with counter:
        call_method(setup, spec, case, products, seed)
    prof = cProfile.Profile()
    prof.enable()
    call_method(setup, spec, case, products, seed)
    prof.disable()
    stats = pstats.Stats(prof, stream=io.StringIO())
    total = stats.total_tt
    rows = sorted(stats.stats.items(), key=lambda kv: kv[1][2], reverse=True)[:top]
    top_rows = [{"function": f"{Path(f).name}:{line}({fn})", "calls": int(nc), "own_s": round(tt, 3),
                 "cumulative_s": round(ct, 3)} for (f, line, fn), (cc, nc, tt, ct, _) in rows]
    return {"seconds": seconds, "profiled_seconds": total, "ops": counter.ops, "flops": counter.flops,
            "elements": counter.elements, "top": top_rows}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--rows", nargs="*", help="only these rows (default: every row the first case runs)")
    ap.add_argument("--skip", nargs="*", default=[], help="rows to leave out")
    ap.add_argument("--top", type=int, default=12, help="functions kept per row")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    sc, setup, case, products = first_block(args.scenario)
    machine = machine_figures()
    print(f"machine: {machine['dispatch_us']:.1f} us per tiny op, {machine['gflops']:.1f} GFLOP/s (matrix product), "
          f"{machine['gelems']:.2f} G elements/s (elementwise)", flush=True)
    rows = {}
    for spec in setup.methods:
        if setup.kinds[spec.name].bound or not case.runs(spec) or spec.name in args.skip:
            continue
        if args.rows and spec.name not in args.rows:
            continue
        r = profile_row(setup, spec, case, products, (sc.seed, 0, 0), args.top)
        r["dispatch_floor_s"] = r["ops"] * machine["dispatch_us"] * 1e-6
        r["arithmetic_floor_s"] = r["flops"] / (machine["gflops"] * 1e9)
        r["bound"] = "dispatch" if r["dispatch_floor_s"] >= r["arithmetic_floor_s"] else "arithmetic"
        rows[spec.name] = r
        print(f"{spec.name}: {r['seconds']:.2f} s, {r['ops'] / 1e3:.0f} k ops ({r['dispatch_floor_s']:.2f} s of "
              f"dispatch), {r['flops'] / 1e9:.2f} GFLOP ({r['arithmetic_floor_s']:.3f} s); top: "
              + "; ".join(f"{t['function']} {t['own_s']} s" for t in r["top"][:3]), flush=True)
    if args.json:
        write_figures({"scenario": str(args.scenario), "machine_figures": machine, "rows": rows}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
