"""Fault census: run every case of tests/faults/cases.py as a subprocess and classify the outcome.

    .venv/bin/python benchmarks/fault_census.py --pmsr-root /tmp/before --json /tmp/census_before.json
    .venv/bin/python benchmarks/fault_census.py --only track/ --jobs 2

Every case runs ``python -m pmsr_nn.cli ARGV`` with the code of ``--pmsr-root`` first on
PYTHONPATH, in a fresh sandbox (a copy of fixtures built once with that checkout's command; see
tests/faults/sandbox.py), cwd = the sandbox's working folder, under a time limit and an address
space cap. The whole sandbox (the working folder and the folder around it) is hashed before and
after. Classes, in order of precedence:

  data_loss      something that existed outside the declared outputs (or anything at all, for
                 a case that must refuse) was changed, replaced or removed
  hang           no exit within the time limit, or the memory cap was hit
  traceback      a Python traceback on stderr, or an exit code other than 0 or 2
                 (signal cases: any non-zero exit code is expected)
  silent_wrong   exit 0 where the case must be refused; a refusal (exit 2) where it must succeed;
                 or an 'ok' case whose output fails its check
  leftover       an otherwise clean refusal (or success) that left .partial / .old- temporaries,
                 a half-written output, or new files outside the declared outputs
  messy_refusal  exit 2 (signal cases: non-zero) but not exactly one stderr line 'pmsr: error: ...'
  clean_refusal  exit 2, one line 'pmsr: error: ...', nothing changed, nothing left behind
  ok             an 'ok' case: exit 0, nothing outside its outputs changed, its output checks out

Progress bars are disabled (TQDM_DISABLE=1) in the subprocesses: they are not part of the error
path under test.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import datetime
import fnmatch
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from faults import sandbox  # noqa: E402
from faults.cases import CASES, COMMANDS, DEFAULT_TIMEOUT, Case  # noqa: E402
from faults.outcome import CLASSES, IS_ROOT, MEMORY_CAP, classify  # noqa: E402




# -- running one case --------------------------------------------------------------------------

def _limits() -> None:
    """In the child: an address-space cap, default signal dispositions, its own process group
    (set by start_new_session)."""
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGPIPE):
        signal.signal(s, signal.SIG_DFL)


def _matches(work: Path, patterns: tuple[str, ...]) -> bool:
    if not patterns or not work.exists():
        return False
    for dirpath, dirnames, filenames in os.walk(work, followlinks=False):
        rel_dir = os.path.relpath(dirpath, work)
        for name in (*dirnames, *filenames):
            rel = os.path.normpath(os.path.join(rel_dir, name))
            if any(fnmatch.fnmatch(rel, p) for p in patterns):
                return True
        if rel_dir.count(os.sep) >= 2:
            dirnames[:] = []
    return False


def run_process(c: Case, work: Path, pmsr_root: Path, python: str, timeout: float, log_dir: Path,
                env: dict) -> dict:
    """Run the case's command; return rc, stdout, stderr, timing, memory, signal facts."""
    slug = c.id.replace("/", "__")
    out_path, err_path = log_dir / f"{slug}.out", log_dir / f"{slug}.err"
    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        t0 = time.monotonic()
        p = subprocess.Popen(sandbox.pmsr_command(c.argv, python), cwd=work, env=env, stdin=subprocess.DEVNULL,
                             stdout=out, stderr=err, preexec_fn=_limits, start_new_session=True)
        status = rusage = None
        timed_out = False
        sig_sent_at = None
        trigger_at = None
        trigger = None
        while True:
            pid, st, ru = os.wait4(p.pid, os.WNOHANG)
            if pid == p.pid:
                status, rusage = st, ru
                break
            now = time.monotonic() - t0
            if c.signal is not None and sig_sent_at is None:
                if trigger_at is None and _matches(work, c.signal_after):
                    trigger_at, trigger = now, "path"
                elif trigger_at is None and now >= c.signal_fallback:
                    trigger_at, trigger = now, "fallback"
                if trigger_at is not None and now >= trigger_at + c.signal[1]:
                    try:
                        os.kill(p.pid, getattr(signal, c.signal[0]))
                        sig_sent_at = now
                    except ProcessLookupError:
                        pass
            if now > timeout:
                timed_out = True
                try:
                    os.killpg(p.pid, signal.SIGKILL)  # the case's own process group
                except ProcessLookupError:
                    pass
                _, status, rusage = os.wait4(p.pid, 0)
                break
            time.sleep(0.05 if now < 5 else 0.2)
        seconds = time.monotonic() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        # anything left in the group (e.g. a worker process) goes with it
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    return {
        "rc": p.returncode, "seconds": round(seconds, 2), "timed_out": timed_out,
        "maxrss_mb": round(rusage.ru_maxrss / 1024, 1) if rusage else None,
        "signal_sent_at": None if sig_sent_at is None else round(sig_sent_at, 2),
        "signal_trigger_at": None if trigger_at is None else round(trigger_at, 2),
        "signal_trigger": trigger,
        "stdout": out_path.read_bytes().decode("utf-8", "replace"),
        "stderr": err_path.read_bytes().decode("utf-8", "replace"),
    }


def run_case(c: Case, fixtures: Path, cases_dir: Path, log_dir: Path, pmsr_root: Path, python: str,
             timeout: float, env: dict, keep: bool) -> dict:
    slug = c.id.replace("/", "__")
    case_dir = cases_dir / slug
    expect = c.root_expect if (IS_ROOT and c.root_expect) else c.expect
    rec = {"id": c.id, "command": c.command, "argv": list(c.argv), "expect": expect, "klass": c.klass,
           "message": c.message, "root_caveat": bool(IS_ROOT and c.root_expect), "note": c.note}
    try:
        work = sandbox.make_sandbox(fixtures, case_dir)
        if c.setup is not None:
            c.setup(work)
        before = sandbox.snapshot(case_dir)
        res = run_process(c, work, pmsr_root, python, timeout, log_dir, env)
        after = sandbox.snapshot(case_dir)
        changes = sandbox.diff_snapshots(before, after)
        verify_msg = None
        if expect == "ok" and res["rc"] == 0 and c.verify is not None and work.exists():
            try:
                verify_msg = c.verify(work)
            except Exception as exc:  # a broken output is a wrong answer, not a census failure
                verify_msg = f"check failed: {type(exc).__name__}: {exc}"
        klass, reason = classify(c, expect, res, changes, verify_msg)
        err_lines = [ln for ln in res["stderr"].strip().split("\n") if ln.strip()]
        rec.update({
            "class": klass, "reason": reason, "rc": res["rc"], "seconds": res["seconds"],
            "timed_out": res["timed_out"], "maxrss_mb": res["maxrss_mb"],
            "signal": list(c.signal) if c.signal else None, "signal_sent_at": res["signal_sent_at"],
            "signal_trigger": res["signal_trigger"],
            "stderr_lines": len(err_lines), "stderr_head": "\n".join(err_lines[:3])[:1500],
            "stderr_tail": "\n".join(err_lines[-6:])[-1500:],
            "message_found": (c.message.lower() in res["stderr"].lower()) if c.message else None,
            "verify": verify_msg,
            "changes": {k: v[:25] for k, v in changes.items()},
            "n_changes": {k: len(v) for k, v in changes.items()},
            "pwned": (work / "PWNED").exists(),
        })
    except Exception as exc:  # a broken case (setup) is reported, never silently dropped
        import traceback

        rec.update({"class": "census_error", "reason": f"{type(exc).__name__}: {exc}",
                    "traceback": traceback.format_exc()[-2000:]})
    finally:
        if not keep:
            sandbox.rmtree_force(case_dir)
    return rec


# -- the report ---------------------------------------------------------------------------------

def table(records: list[dict]) -> str:
    classes = list(CLASSES) + sorted({r["class"] for r in records} - set(CLASSES))
    counts = Counter(r["class"] for r in records)
    out = [f"cases: {len(records)}", "", "| class | cases |", "|---|---:|"]
    out += [f"| {k} | {counts.get(k, 0)} |" for k in classes]
    out += ["", "| command | " + " | ".join(classes) + " | total |", "|---|" + "---:|" * (len(classes) + 1)]
    for cmd in COMMANDS:
        rs = [r for r in records if r["command"] == cmd]
        if not rs:
            continue
        cc = Counter(r["class"] for r in rs)
        out.append(f"| {cmd} | " + " | ".join(str(cc.get(k, 0) or ".") for k in classes) + f" | {len(rs)} |")
    refusals = [r for r in records if r["class"] == "clean_refusal" and r.get("message")]
    if refusals:
        hit = sum(1 for r in refusals if r.get("message_found"))
        out += ["", f"clean refusals naming the expected key/file/argument: {hit} of {len(refusals)}"]
    bad = [r for r in records if r["class"] not in ("clean_refusal", "ok")]
    out += ["", f"non-clean cases ({len(bad)}):"]
    for r in sorted(bad, key=lambda r: (CLASSES.index(r["class"]) if r["class"] in CLASSES else -1, r["id"])):
        extra = " [root: permissions not enforced]" if r.get("root_caveat") else ""
        if r.get("signal") and r.get("signal_sent_at") is None:
            extra += " [signal never sent]"
        elif r.get("signal_trigger") == "fallback":
            extra += " [signal sent on the fallback timer]"
        out.append(f"  {r['class']:<13} {r['id']:<52} {r.get('reason', '')[:150]}{extra}")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pmsr-root", type=Path, default=REPO, help="checkout whose pmsr_nn runs (default: this one)")
    ap.add_argument("--python", default=sys.executable, help="interpreter (default: this one, the .venv)")
    ap.add_argument("--only", action="append", default=[], metavar="SUBSTRING",
                    help="run only cases whose id contains SUBSTRING (repeatable)")
    ap.add_argument("--jobs", type=int, default=2, help="cases run in parallel (default 2)")
    ap.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT,
                    help=f"time limit of a case without its own (default {DEFAULT_TIMEOUT:.0f} s)")
    ap.add_argument("--json", type=Path, help="also write every result as JSON here")
    ap.add_argument("--workdir", type=Path, help="where sandboxes and logs go (default: a new temporary folder)")
    ap.add_argument("--fixtures", type=Path, help="fixture cache folder (default: WORKDIR/../fault-census-fixtures)")
    ap.add_argument("--keep", action="store_true", help="keep every sandbox (default: removed after its case)")
    ap.add_argument("--list", action="store_true", help="list the selected cases and exit")
    args = ap.parse_args(argv)

    pmsr_root = args.pmsr_root.resolve()
    if not (pmsr_root / "pmsr_nn" / "cli" / "__init__.py").is_file():
        ap.error(f"--pmsr-root {pmsr_root} has no pmsr_nn/cli/ (not a pmsr_nn checkout)")
    selected = [c for c in CASES if not args.only or any(s in c.id for s in args.only)]
    if args.list:
        for c in selected:
            print(f"{c.id:<55} {c.expect:<7} {c.klass:<13} pmsr {' '.join(a if a else repr(a) for a in c.argv)[:120]}")
        print(f"{len(selected)} case(s)")
        return 0
    if not selected:
        ap.error("no case matches --only")

    workdir = (args.workdir or Path(tempfile.mkdtemp(prefix="fault-census-"))).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    fixture_cache = (args.fixtures or Path(tempfile.gettempdir()) / "fault-census-fixtures").resolve()
    cases_dir, log_dir = workdir / "cases", workdir / "logs"
    cases_dir.mkdir(exist_ok=True)
    log_dir.mkdir(exist_ok=True)

    t_start = time.monotonic()
    print(f"pmsr root   {pmsr_root}\nworkdir     {workdir}\nfixtures    {fixture_cache}", flush=True)
    fixtures = sandbox.build_fixtures(fixture_cache, pmsr_root, args.python,
                                      log=lambda m: print(m, flush=True))
    fixtures_before = sandbox.snapshot(fixtures)
    env = sandbox.pmsr_env(pmsr_root, fixture_cache)
    if IS_ROOT:
        print("running as root: permission bits are not enforced; cases with root_expect use it", flush=True)

    def slow(c: Case) -> int:
        return 0 if (c.signal or c.klass == "hang" or c.timeout > DEFAULT_TIMEOUT
                     or (c.expect == "ok" and c.command in ("train", "select"))) else 1

    order = sorted(selected, key=slow)
    records: list[dict] = []
    lock = threading.Lock()
    print(f"running {len(order)} case(s) with {args.jobs} job(s)", flush=True)
    with cf.ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futs = {pool.submit(run_case, c, fixtures, cases_dir, log_dir, pmsr_root, args.python,
                            c.timeout if c.timeout != DEFAULT_TIMEOUT else args.timeout, env, args.keep): c
                for c in order}
        for fut in cf.as_completed(futs):
            r = fut.result()
            with lock:
                records.append(r)
                print(f"[{len(records):>3}/{len(order)}] {r['class']:<13} {r.get('seconds', 0):>6.1f}s  {r['id']}",
                      flush=True)
    elapsed = time.monotonic() - t_start
    records.sort(key=lambda r: [c.id for c in CASES].index(r["id"]))

    if sandbox.snapshot(fixtures) != fixtures_before:
        print("WARNING: the shared fixtures changed during the census (a case wrote outside its sandbox?)", flush=True)

    report = table(records)
    print()
    print(report)
    print(f"\ncensus took {elapsed / 60:.1f} min ({len(records)} cases, {args.jobs} jobs)")
    if args.json:
        meta = {"pmsr_root": str(pmsr_root), "git": _git(pmsr_root), "python": args.python,
                "started": datetime.datetime.now().isoformat(timespec="seconds"), "seconds": round(elapsed, 1),
                "jobs": args.jobs, "default_timeout_s": args.timeout, "memory_cap_bytes": MEMORY_CAP,
                "root": IS_ROOT, "cases": len(records),
                "counts": dict(Counter(r["class"] for r in records)),
                "by_command": {cmd: dict(Counter(r["class"] for r in records if r["command"] == cmd)) for cmd in COMMANDS}}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"meta": meta, "results": records}, indent=1) + "\n")
        print(f"json        {args.json}")
    return 0


def _git(root: Path) -> str | None:
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return rev.stdout.strip() + ("+dirty" if dirty else "") if rev.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


if __name__ == "__main__":
    sys.exit(main())
