#!/usr/bin/env python3
"""``make fuzz``: the long fuzz run of the Lua dissectors (under tshark) and of the Python parsers.

tshark ($SHAREDLINK_TSHARK, default tshark), Wireshark's method (tests/fuzz/fuzz_harness.py):
  1. editcap -E 0.02 mutations of every sample capture, --seeds seeds each, headers kept (-o);
  2. every prefix of every frame of every sample capture (shorter datagram and snaplen cut);
  3. random, protocol-alphabet and mutated-frame payloads on every port of ours (UDP and TCP)
     and on a port where only the heuristics can claim them;
  4. 64 KB adversarial payloads, each pattern timed against the same bytes in 4 KB payloads;
  5. issue 31's scaling patterns (every tests/fuzz/scaling_*.py with a PATTERNS table), each at
     its make-fuzz size N and 4N: time and peak memory may grow at most its limit (about 5x).
Python parsers (tests/fuzz/fuzz_codecs.py): atheris, --codec-runs inputs per target (hypothesis
when atheris is not installed).

A failing capture is kept in tests/fuzz/fuzz-regressions/ (replayed by tests/fuzz/test_fuzz_short.py).
Exit status: 0 all clean, 1 a failure, 2 the harness could not run.

How long (docs/testing.md, measured on 2 cores at load 8-17, --jobs 1): the defaults about 3.5 h
(stage 1 about 90 min, 2 about 14, 3 about 70, 4 about 5, 5 about 22, Python parsers about 10);
--seeds 5 --random 500 --codec-runs 5000 took 50 min (stages 2, 4 and 5 have fixed sizes;
--no-scaling skips 5).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import random
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "tests" / "fuzz"))

import fuzz_harness as fh  # noqa: E402

from sharedlink.capture.packets import decode_packet  # noqa: E402
from sharedlink.capture.pcapio import CaptureError, read_records  # noqa: E402


@dataclass
class Stage:
    name: str
    cases: int = 0  # inputs (mutated files, packets, fuzzer inputs)
    runs: int = 0  # tshark or fuzzer processes
    failures: list[str] = field(default_factory=list)
    seconds: float = 0.0
    note: str = ""


def say(msg: str) -> None:
    print(msg, flush=True)


def say_done(stage: Stage) -> None:
    """A stage's time as it ends (a long run shows where its time goes before the table)."""
    say(f"   {stage.name}: {stage.cases} cases, {stage.runs} runs, {len(stage.failures)} failed, "
        f"{stage.seconds:.0f} s ({time.strftime('%H:%M:%S')})")


def run_parallel(jobs: int, items: Iterable[object], fn: Callable[[object], fh.Outcome]) -> list[fh.Outcome]:
    with ThreadPoolExecutor(max_workers=jobs) as ex:
        return list(ex.map(fn, items))


_kept_signatures: set[str] = set()


def signature(outcome: fh.Outcome) -> str:
    """The failure without frame numbers: one kept capture per distinct failure and run."""
    return outcome.mode + ": " + re.sub(r"frame \d+", "frame N", outcome.problems[0])


def record(stage: Stage, outcome: fh.Outcome, label: str, keep: bool) -> None:
    stage.runs += 1
    if not outcome.ok:
        where = ""
        sig = signature(outcome)
        if keep and sig not in _kept_signatures:
            _kept_signatures.add(sig)
            where = f" (kept as {fh.keep_regression(outcome, label).relative_to(REPO)})"
        stage.failures.append(f"{label}: {outcome.describe()}{where}")
        say(f"  FAIL {label}: {outcome.describe()[:400]}{where}")


# --- stages -----------------------------------------------------------------------------------


def stage_editcap(samples: list[Path], work: Path, args: argparse.Namespace) -> Stage:
    st = Stage("editcap -E %.2f mutations" % fh.ERR_PROB)
    cases = [(s, seed) for s in samples for seed in range(args.seed_start, args.seed_start + args.seeds)]
    offsets = {s: fh.header_length(s) for s in samples}

    def one(item: object) -> fh.Outcome:
        s, seed = item  # type: ignore[misc]
        m = fh.mutate(s, work / f"mut-{seed}-{s.name}", seed, offsets[s])
        for mode in args.modes:
            o = fh.run_tshark(m, args.limits, mode=mode)
            if not o.ok:
                return o
        m.unlink()
        return o

    done = 0
    for i in range(0, len(cases), 50):
        batch = cases[i : i + 50]
        for (s, seed), o in zip(batch, run_parallel(args.jobs, batch, one)):
            record(st, o, f"editcap-{s.stem}-seed{seed}", keep=True)
        done += len(batch)
        say(f"  {done}/{len(cases)} mutated files")
    st.cases = len(cases)
    return st


def sample_frames(samples: list[Path]) -> list[fh.Sample]:
    """Every distinct payload in the sample captures, with its transport and ports."""
    seen: dict[bytes, fh.Sample] = {}
    for s in samples:
        try:
            for rec in read_records(s):
                d = decode_packet(rec.linktype, rec.data)
                if d is not None and d.payload and d.payload not in seen:
                    seen[d.payload] = fh.Sample(s.stem, d.payload, d.proto, d.sport, d.dport)
        except CaptureError:
            pass
    for smp in fh.samples_with_endpoints():
        seen.setdefault(smp.payload, smp)
    return list(seen.values())


def stage_truncations(samples: list[Path], work: Path, args: argparse.Namespace) -> Stage:
    st = Stage("every prefix of every sample frame")
    frames = sample_frames(samples)
    files = []
    chunk: list[fh.Sample] = []
    size = 0
    for i, smp in enumerate(frames):
        chunk.append(smp)
        size += 2 * len(smp.payload)
        if size > 20000 or i == len(frames) - 1:
            f = work / f"prefixes-{len(files)}.pcap"
            st.cases += fh.write_truncations(f, chunk)
            files.append(f)
            chunk, size = [], 0
    jobs = [(f, mode) for f in files for mode in args.modes]
    for (f, mode), o in zip(jobs, run_parallel(args.jobs, jobs, lambda j: fh.run_tshark(j[0], args.limits, mode=j[1]))):  # type: ignore[index]
        record(st, o, f"{f.stem}-{mode}", keep=True)
    st.note = f"{len(frames)} distinct frames"
    return st


def stage_random(work: Path, args: argparse.Namespace) -> Stage:
    st = Stage("random payloads on our ports")
    rng = random.Random(args.seed_start)
    pool = [p for _, p in fh.sample_payloads()]
    ports = [*fh.load_dissectors().ports, fh.HEURISTIC_PORT]
    jobs = []
    per_file = 2000
    for transport in ("udp", "tcp"):
        for port in ports:
            for i in range(0, args.random, per_file):
                f = work / f"random-{transport}-{port}-{i // per_file}.pcap"
                payloads = list(fh.random_payloads(rng, min(per_file, args.random - i), pool))
                (fh.write_udp if transport == "udp" else fh.write_tcp)(f, payloads, port=port)
                st.cases += len(payloads)
                jobs += [(f, port, mode) for mode in args.modes]

    def one(item: object) -> fh.Outcome:
        f, port, mode = item  # type: ignore[misc]
        return fh.run_tshark(f, args.limits, require_decoded=port != fh.HEURISTIC_PORT, mode=mode)

    for (f, _, mode), o in zip(jobs, run_parallel(args.jobs, jobs, one)):
        record(st, o, f"{f.stem}-{mode}", keep=True)
    st.note = f"ports {', '.join(map(str, ports))}; UDP and TCP"
    return st


def stage_adversarial(work: Path, args: argparse.Namespace) -> Stage:
    st = Stage("64 KB adversarial payloads (linear time)")
    base_f = work / "adv-base.pcap"
    fh.write_udp(base_f, [b"[:AB|P1|C71]\r\n"])
    base = min(fh.run_tshark(base_f, args.limits).cpu_s for _ in range(3))
    worst, worst_name = 0.0, ""
    for name, unit in fh.adversarial_patterns().items():
        runs = {}
        for size, copies in ((4096, 16), (65507, 1)):
            f = work / f"adv-{name}-{size}.pcap"
            fh.write_udp(f, [fh.adversarial_payload(unit, size)] * copies)
            o = fh.run_tshark(f, args.limits, require_decoded=False)
            record(st, o, f.stem, keep=True)
            st.cases += copies
            runs[size] = o.cpu_s
        small, big = max(runs[4096] - base, 0.05), runs[65507] - base
        if big / small > worst:
            worst, worst_name = big / small, name
        if big > 4 * small + 0.5:
            msg = f"adv-{name}: 64 KB took {big:.2f} s CPU beyond start-up, the same bytes in 4 KB payloads {small:.2f} s"
            st.failures.append(msg)
            say(f"  FAIL {msg}")
    st.note = f"worst 64K/4K time ratio {worst:.1f} ({worst_name}; linear ~1, quadratic ~16)"
    return st


def scaling_patterns() -> dict[str, tuple]:
    """name -> (make, n in make test, n in make fuzz, growth limit, environment), from every
    tests/fuzz/scaling_*.py that has a PATTERNS table (and, optionally, an env() function giving
    the commands' environment; see tests/fuzz/scaling.py)."""
    import importlib

    out: dict[str, tuple] = {}
    for f in sorted((REPO / "tests" / "fuzz").glob("scaling_*.py")):
        mod = importlib.import_module(f.stem)
        env = mod.env() if hasattr(mod, "env") else None
        check = getattr(mod, "check", None)  # the module's rule (scaling_memory: issue 44's), else check_scaling
        for name, pattern in getattr(mod, "PATTERNS", {}).items():
            out[f"{f.stem[8:]}:{name}"] = (*pattern[:4], env, check)
    return out


def stage_scaling(work: Path, args: argparse.Namespace) -> Stage:
    from scaling import ScalingError, check_scaling

    st = Stage("scaling patterns at N and 4N (issue 31)")
    worst, worst_name = 0.0, ""
    for name, (make, _n_test, n, limit, env, check) in scaling_patterns().items():
        folder = work / f"scaling-{name.replace(':', '-')}"
        folder.mkdir()
        st.cases += 1
        st.runs += 3
        try:
            rep = (check or check_scaling)(make, n, folder, limit=limit, env=env)
        except ScalingError as exc:
            st.failures.append(f"{name}: {exc}")
            say(f"  FAIL {name}: {str(exc)[:400]}")
            continue
        finally:
            shutil.rmtree(folder, ignore_errors=True)
        say(f"  {name}: {rep}")
        growth = max(getattr(rep, "time_growth", 0.0), getattr(rep, "memory_growth", 0.0))
        if growth > worst:
            worst, worst_name = growth, name
    st.note = f"worst growth {worst:.1f}x ({worst_name}; linear ~4, quadratic ~16)"
    return st


def stage_codecs(work: Path, args: argparse.Namespace) -> Stage:
    import fuzz_codecs

    st = Stage("Python parsers")
    try:
        import atheris  # noqa: F401

        engine = "atheris"
    except ImportError:
        engine = "hypothesis"
    seeds = fuzz_codecs.seeds()
    names = list(fuzz_codecs.targets())
    missing = [m for m in ("p2os", "blackboard") if not any(n.startswith(m + ".") for n in names)]
    py = sys.executable
    for name in names:
        t0 = time.perf_counter()
        if engine == "atheris":
            corpus = work / f"corpus-{name}"
            art = work / f"artifacts-{name}"
            corpus.mkdir()
            art.mkdir()
            for s in seeds.get(name.split(".")[0], []):
                (corpus / hashlib.sha1(s).hexdigest()).write_bytes(s)
            cmd = [py, str(REPO / "tests" / "fuzz" / "fuzz_codecs.py"), name, f"-runs={args.codec_runs}", "-max_len=8192",
                   f"-artifact_prefix={art}/", "-print_final_stats=1", str(corpus)]
        else:
            cmd = [py, str(REPO / "tests" / "fuzz" / "fuzz_codecs.py"), "--hypothesis", name, str(args.codec_runs)]
        env = dict(os.environ, SHAREDLINK_FUZZ_TMP=str(work))
        r = subprocess.run(cmd, capture_output=True, text=True, env=env, errors="replace")
        text = r.stdout + r.stderr
        runs = next((ln.split()[1] for ln in text.splitlines() if ln.startswith("Done ")), "?")
        st.runs += 1
        st.cases += int(runs) if runs.isdigit() else 0
        say(f"  {name}: {runs} inputs in {time.perf_counter() - t0:.1f} s ({engine})" + ("" if r.returncode == 0 else " FAILED"))
        if r.returncode != 0:
            kept = []
            if engine == "atheris":
                for a in sorted(art.iterdir()):
                    fh.REGRESSIONS_DIR.mkdir(exist_ok=True)
                    dst = fh.REGRESSIONS_DIR / f"codec-{name}-{hashlib.sha256(a.read_bytes()).hexdigest()[:12]}.bin"
                    shutil.copyfile(a, dst)
                    kept.append(str(dst.relative_to(REPO)))
            tail = "\n".join(text.splitlines()[-25:])
            st.failures.append(f"{name}: exit {r.returncode}; kept {', '.join(kept) or 'nothing'}\n{tail}")
            say(tail)
    st.note = f"{len(names)} targets, {engine}" + (f"; skipped (module missing): {', '.join(missing)}" if missing else "")
    return st


# --- main -------------------------------------------------------------------------------------


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=100, help="editcap seeds per sample capture (default 100)")
    ap.add_argument("--seed-start", type=int, default=1, help="first seed (default 1)")
    ap.add_argument("--random", type=int, default=10000, help="random payloads per port and transport (default 10000)")
    ap.add_argument("--codec-runs", type=int, default=100_000, help="inputs per Python parser (default 100000)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 2, help="tshark runs in parallel (default: CPUs)")
    ap.add_argument("--cpu", type=int, default=60, help="CPU seconds per tshark run (ulimit -t, default 60)")
    ap.add_argument("--vmem", type=int, default=fh.Limits().vmem_kb, help="KiB of address space per tshark run (ulimit -v)")
    ap.add_argument("--only", choices=("tshark", "codecs"), help="run only one half")
    ap.add_argument("--no-scaling", action="store_true",
                    help="skip stage 5, the scaling patterns (fixed sizes: no option makes it shorter)")
    ap.add_argument("--modes", default=",".join(fh.MODES),
                    help="how tshark runs: tree (-nVxr) and/or fields (-T fields: the sparse tree of filters); default both")
    ap.add_argument("--check", action="store_true",
                    help="only check that tshark loads every dissector and decodes the sample captures")
    args = ap.parse_args(argv)
    for name in ("seeds", "random", "codec_runs", "jobs", "cpu", "vmem"):
        if getattr(args, name) < (1 if name in ("jobs", "cpu", "vmem") else 0):
            ap.error(f"--{name.replace('_', '-')} is out of range")
    args.modes = [m for m in args.modes.split(",") if m]
    if not args.modes or any(m not in fh.MODES for m in args.modes):
        ap.error(f"--modes: a comma-separated list of {', '.join(fh.MODES)}")
    args.limits = fh.Limits(cpu_s=args.cpu, vmem_kb=args.vmem, wall_s=max(120.0, 3.0 * args.cpu))
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.check:
        return check(args)
    stages: list[Stage] = []
    work = fh.readable_tmpdir("slfuzz-")
    t_all = time.perf_counter()
    try:
        if args.only != "codecs":
            try:
                d = fh.load_dissectors()
            except fh.HarnessError as exc:
                print(f"fuzz: {exc}", file=sys.stderr)
                return 2
            say(f"{d.version}\n  dissectors: {', '.join(p.filter for p in d.protocols)}; ports {', '.join(map(str, d.ports))}")
            say(f"  limits per run: {args.cpu} s CPU, {args.vmem} KiB address space; {args.jobs} in parallel")
            samples = fh.make_samples(work / "samples")
            say(f"  {len(samples)} sample captures")
            for fn in (stage_editcap, stage_truncations):
                t0 = time.perf_counter()
                say(f"== {fn.__name__[6:]}")
                stages.append(fn(samples, work, args))
                stages[-1].seconds = time.perf_counter() - t0
                say_done(stages[-1])
            for fn2 in (stage_random, stage_adversarial) + (() if args.no_scaling else (stage_scaling,)):
                t0 = time.perf_counter()
                say(f"== {fn2.__name__[6:]}")
                stages.append(fn2(work, args))
                stages[-1].seconds = time.perf_counter() - t0
                say_done(stages[-1])
        if args.only != "tshark" and args.codec_runs:
            t0 = time.perf_counter()
            say("== Python parsers")
            stages.append(stage_codecs(work, args))
            stages[-1].seconds = time.perf_counter() - t0
            say_done(stages[-1])
    except fh.HarnessError as exc:
        print(f"fuzz: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fuzz: interrupted", file=sys.stderr)
        return 130
    finally:
        shutil.rmtree(work, ignore_errors=True)
    report(stages, time.perf_counter() - t_all)
    return 1 if any(s.failures for s in stages) else 0


def check(args: argparse.Namespace) -> int:
    """Fail loudly unless tshark loads the dissectors and decodes every sample capture cleanly."""
    work = fh.readable_tmpdir("slfuzz-check-")
    try:
        d = fh.load_dissectors()
        samples = fh.make_samples(work)
        outcomes = [fh.run_tshark(s, args.limits, mode=m) for s in samples for m in fh.MODES]
        bad = [f"{o.describe()} ({o.mode} mode)" for o in outcomes if not o.ok]
    except fh.HarnessError as exc:
        print(f"fuzz: {exc}", file=sys.stderr)
        return 2
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"{d.version}: loaded {', '.join(p.filter for p in d.protocols)} from {len(fh.dissector_scripts())} scripts")
    for b in bad:
        print(f"  FAIL {b}", file=sys.stderr)
    return 2 if bad else 0


def report(stages: list[Stage], seconds: float) -> None:
    rows = [(s.name, str(s.cases), str(s.runs), str(len(s.failures)), f"{s.seconds:.0f}", s.note) for s in stages]
    total = sum(s.cases for s in stages)
    head = ("stage", "cases", "runs", "failed", "s", "note")
    if sys.stdout.isatty():
        from rich.console import Console
        from rich.table import Table

        t = Table(title=f"fuzz: {total} cases in {seconds:.0f} s")
        for h in head:
            t.add_column(h, justify="right" if h in ("cases", "runs", "failed", "s") else "left")
        for r in rows:
            t.add_row(*r)
        Console().print(t)
    else:
        for r in rows:
            print("  ".join(f"{h}={v}" for h, v in zip(head, r)))
        print(f"fuzz: {total} cases in {seconds:.0f} s")
    failed = sum(len(s.failures) for s in stages)
    print("fuzz: FAILED, %d failure(s)" % failed if failed else "fuzz: all clean")


if __name__ == "__main__":
    sys.exit(main())
