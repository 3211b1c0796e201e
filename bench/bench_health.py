"""Link health's costs (issue 43's limits), side by side in one run, in CPU time (user + sys of
each command in its own process, the best of ``ROUNDS`` interleaved runs: wall time on a shared
machine moves with the other processes, CPU time much less) and, where valgrind exists, in
instructions a frame (callgrind: no noise at all):

* ``sharedlink stats`` with link health against ``stats`` before it (the package at
  :data:`BASE`, the last commit without link health, taken out of this checkout's git history
  and run by the same Python): at most 1.10x, on the 200,000-frame compressed capture;
* the dissectors' summary pass and ``-2`` against tshark's syslog dissector on the same port
  (``bench_dissector``'s lines: 2.5x and 3.0x), on a drive with outages (200,000 frames, an
  outage of 3 s every 200 s: the sharedlink.outage expert and its field on 200 frames);
* instructions a frame, summary and ``-2``, on that drive: the dissectors now against syslog
  (information) and against the dissectors at :data:`BASE` (information: what link health adds).

Without the git history (a copy of the files), the lines against :data:`BASE` are skipped with
a note. ``python bench/bench_health.py`` runs these lines alone.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import tarfile
from pathlib import Path

from bench import Result, load_now, load_since

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
import bench_dissector as bd  # noqa: E402

#: the last commit without link health (before b8d379a, issue 43)
BASE = "a30cdfd"
FRAMES = int(os.environ.get("SHAREDLINK_BENCH_FRAMES", "200000"))
ROUNDS = int(os.environ.get("SHAREDLINK_BENCH_ROUNDS", "3"))
STATS_TARGET = 1.10
#: (pass, tshark options, target against syslog)
PASSES = [("summary", [], 2.5), ("-2", ["-2"], 3.0)]


def base_tree(work: Path, paths: list[str]) -> Path | None:
    """``paths`` of :data:`BASE` extracted under ``work/base`` (None: no such commit here)."""
    r = subprocess.run(["git", "-C", str(REPO), "archive", BASE, *paths], capture_output=True)
    if r.returncode != 0:
        return None
    dest = work / "base"
    with tarfile.open(fileobj=io.BytesIO(r.stdout)) as tf:
        if hasattr(tarfile, "data_filter"):
            tf.extractall(dest, filter="data")
        else:  # (before 3.11.4)
            tf.extractall(dest)  # noqa: S202
    return dest


def outage_drive(path: Path, frames: int) -> Path:
    from sharedlink.generators.beacon import GenOptions, generate_file

    span = frames // 5  # (5 Hz)
    generate_file(GenOptions(frames=frames, outages=tuple((float(t), 3.0) for t in range(100, span, 200))), path)
    return path


def _cpu(cmds: dict[str, tuple[list[str], dict[str, str]]]) -> dict[str, bd.Measure]:
    best: dict[str, bd.Measure] = {}
    for _ in range(ROUNDS):
        for name, (cmd, env) in cmds.items():
            best[name] = bd.measure(cmd, env).best(best.get(name))
    return best


def stats_lines(work: Path, base: Path | None) -> list[Result]:
    from sharedlink.generators.beacon import GenOptions, generate_file

    if base is None:
        return [Result(f"stats with link health vs stats at {BASE}: skipped, no git history with {BASE}", "-", "-",
                       0.0, "(info)", True)]
    cap = work / "health-stats.pcap"
    generate_file(GenOptions(frames=FRAMES, compress=True), cap)
    started = load_now()
    env = dict(os.environ)
    old = dict(env, PYTHONPATH=os.pathsep.join([str(base / "pytools"), env.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    cli = [sys.executable, "-m", "sharedlink", "stats", str(cap)]
    m = _cpu({"now": (cli, env), "base": (cli, old)})
    r = m["now"].cpu / m["base"].cpu
    cap.unlink()
    return [Result(f"stats with link health vs stats at {BASE} ({FRAMES:,} compressed frames, CPU)",
                   f"{m['now'].cpu:.2f} s CPU", f"{m['base'].cpu:.2f} s CPU", r, f"<= {STATS_TARGET:.2f}x",
                   r <= STATS_TARGET, load_since(started))]


def dissector_lines(work: Path, base: Path | None) -> list[Result]:
    drive = outage_drive(work / "health-outages.pcap", FRAMES)
    homes = {"all": bd.make_home(work / "home-all", bd.DISSECTORS), "none": bd.make_home(work / "home-none", [])}
    bd.check_loaded(homes["all"], [s.name for s in bd.DISSECTORS])
    if base is not None:
        homes["base"] = bd.make_home(work / "home-base", sorted((base / "dissector").glob("*.lua")))
    started = load_now()
    cmds = {}
    for name, opts, _t in PASSES:
        base_cmd = [bd.TSHARK, "-n", "-r", str(drive), *opts]
        cmds[f"lua {name}"] = (base_cmd, homes["all"])
        cmds[f"syslog {name}"] = ([*base_cmd, *bd.SYSLOG], homes["none"])
        if "base" in homes:
            cmds[f"base {name}"] = (base_cmd, homes["base"])
    m = _cpu(cmds)
    out = []
    for name, _opts, target in PASSES:
        ours, theirs = m[f"lua {name}"], m[f"syslog {name}"]
        r = ours.cpu / theirs.cpu
        out.append(Result(f"dissectors {name} vs syslog, a drive with outages ({FRAMES // 1000}k frames, CPU)",
                          f"{ours.cpu:.2f} s CPU", f"{theirs.cpu:.2f} s CPU", r, f"<= {target:g}x", r <= target,
                          load_since(started)))
        if "base" in homes:  # (information: link health's own cost in time, beside the ratio's noise)
            old = m[f"base {name}"]
            out.append(Result(f"dissectors {name} vs the dissectors at {BASE}, the same drive (CPU)",
                              f"{ours.cpu:.2f} s CPU", f"{old.cpu:.2f} s CPU", ours.cpu / old.cpu, "(info)", True,
                              load_since(started)))
    drive.unlink()
    if bd.VALGRIND is None or os.environ.get("SHAREDLINK_BENCH_NO_COUNT"):
        return [*out, Result("instructions a frame with link health: skipped, no valgrind (or SHAREDLINK_BENCH_NO_COUNT)",
                             "-", "-", 0.0, "(info)", True)]
    return out + instruction_lines(work, homes)


def instruction_lines(work: Path, homes: dict[str, dict[str, str]]) -> list[Result]:
    """(count on 5,000 frames - count on 1,000) / 4,000 of the outage drive, each pass."""
    from concurrent.futures import ThreadPoolExecutor

    small, large = 1_000, 5_000
    started = load_now()
    caps = {n: outage_drive(work / f"health-instr-{n}.pcap", n) for n in (small, large)}
    whos = ["lua", "syslog", *(["base"] if "base" in homes else [])]
    jobs = {}
    for name, opts, _t in PASSES:
        for who in whos:
            for n in (small, large):
                jobs[name, who, n] = ([bd.TSHARK, "-n", "-r", str(caps[n]), *opts, *(bd.SYSLOG if who == "syslog" else [])],
                                      homes["none" if who == "syslog" else "all" if who == "lua" else "base"])
    with ThreadPoolExecutor(max_workers=2) as pool:
        counts = dict(zip(jobs, pool.map(lambda j: bd.instructions(*j), jobs.values())))
    per = {(name, who): (counts[name, who, large] - counts[name, who, small]) / (large - small)
           for name, _o, _t in PASSES for who in whos}
    out = []
    for name, _opts, _t in PASSES:
        ours = per[name, "lua"]
        for who, label in (("syslog", "syslog"), ("base", f"the dissectors at {BASE}")):
            if (name, who) in per:
                ref = per[name, who]
                out.append(Result(f"instructions a frame, {name}, outage drive, vs {label} (callgrind)",
                                  f"{ours:,.0f}", f"{ref:,.0f}", ours / ref, "(info)", True, load_since(started)))
    return out


def run(work: Path) -> list[Result]:
    base = base_tree(work, ["pytools", "dissector"])
    return stats_lines(work, base) + dissector_lines(work, base)


if __name__ == "__main__":
    import tempfile

    from bench import line

    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        base = base_tree(Path(tmp), ["pytools", "dissector"])
        for lines in (stats_lines, dissector_lines):  # (each group printed as it ends)
            for r in lines(Path(tmp), base):
                print(line(r), flush=True)
