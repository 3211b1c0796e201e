"""Issue 31, sharedlink.lua: bounded memory and linear time on hostile input.

Each pattern that was quadratic (or unbounded) is written at N and 4N frames and run through tshark
with sharedlink.lua; time and peak memory beyond tshark's start-up may grow at most 5x
(``scaling.check_scaling``, tests/fuzz/scaling.py; a small stand-in below until that helper is
merged). The limits themselves (docs/fields-sharedlink.md "Limits") are checked by their expert
info "Limit exceeded: ..." on small captures.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest
from scaling_sharedlink import (
    LUA_PATTERNS,
    alternating_declarations,
    command,
    far_slot,
    frame,
    new_names,
    write,
)

import tshark_util as tu

try:  # the shared helper (tests/fuzz/scaling.py, from the lua-small branch)
    from scaling import check_scaling
except ImportError:  # pragma: no cover - until it is merged
    _WRAPPER = (
        "import json, resource, subprocess, sys\n"
        "p = subprocess.run(json.loads(sys.argv[1]), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)\n"
        "ru = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
        "print(json.dumps([ru.ru_utime + ru.ru_stime, ru.ru_maxrss, p.returncode]))\n"
    )

    def _measure(cmd: Sequence[str]) -> tuple[float, int]:
        out = subprocess.run([sys.executable, "-c", _WRAPPER, json.dumps(list(cmd))], capture_output=True,
                             text=True, timeout=600, env=tu._clean_env()).stdout
        cpu, kb, rc = json.loads(out)
        assert rc == 0, f"exit {rc}: {cmd}"
        return cpu, kb

    def check_scaling(make: Callable[[int, Path], Sequence[str]], n: int, tmp: Path, *, factor: int = 4,
                      limit: float = 5.0, **_: object) -> str:
        cmds = {k: list(make(k, tmp)) for k in (1, n, factor * n)}
        report = ""
        for _attempt in range(2):
            (c0, m0), (c1, m1), (c2, m2) = (_measure(cmds[k]) for k in (1, n, factor * n))
            tg = (c2 - c0) / max(c1 - c0, 0.25)
            mg = (m2 - m0) / max(m1 - m0, 16 * 1024)
            report = f"N={n}: {c1:.2f} s {m1} KB; {factor}N: {c2:.2f} s {m2} KB; growth time {tg:.1f}x memory {mg:.1f}x"
            if tg <= limit and mg <= limit:
                return report
        raise AssertionError(f"does not scale: {report}")








# --- patterns ---------------------------------------------------------------------------------












# -2 with new names read 4.0-7.4x in time with every name kept, its instructions linear (callgrind,
# 27 November 2026: 1.526 and 1.522 thousand million a 1,000 frames from 1,000 to 2,000 and from
# 2,000 to 4,000 frames): within scaling.TIME_LIMIT, the room time gets for the memory hierarchy
@pytest.mark.long
@pytest.mark.parametrize("name", sorted(LUA_PATTERNS))
def test_sharedlink_scales_linearly(name: str, tmp_path: Path) -> None:
    gen, n, args = LUA_PATTERNS[name]

    def make(size: int, tmp: Path) -> list[str]:
        return command(write(tmp / f"{name}-{size}.pcap", gen(size)), *args)

    tu.ensure_loaded()
    print(name, check_scaling(make, n, tmp_path))


# --- the limits: an expert info "Limit exceeded: ..." where input is dropped ----------------------


def _limited(cap: Path, *args: str) -> list[int]:
    rows = tu.fields(cap, ["frame.number"], extra=list(args), two_pass=False)
    return [int(r["frame.number"][0]) for r in rows
            if any(m.startswith("Limit exceeded:") for m in r["_ws.expert.message"])]


def test_huge_declaration_is_bounded(tmp_path: Path) -> None:
    """``[:AB|N<n>|T0|Qx]`` with n = 2e9 used to fill the list up to n (171 s, 5.9 GB, abort)."""
    cap = write(tmp_path / "decl.pcap", [frame("AB|N2000000000|T0|Qx"), frame("AB|N0|D1|D2")])
    assert _limited(cap) == [1]
    assert _limited(cap, "-2") == [1]


def test_max_slots_preference(tmp_path: Path) -> None:
    cap = write(tmp_path / "slots.pcap", [frame("AB|N7|D1"), frame("AB|N3|D1"), frame("AB|N0|D1")])
    assert _limited(cap, "-o", "sharedlink.max_slots:5") == [1]
    assert _limited(cap) == []


def test_max_names_preference(tmp_path: Path) -> None:
    cap = write(tmp_path / "names.pcap", new_names(4))
    # 3 names in frame 1 (a0, b0, old), then two new ones a frame: the fourth name is refused
    assert _limited(cap, "-o", "sharedlink.max_names:3") == [2, 3, 4]
    rows = tu.fields(cap, ["sharedlink.var.carried"], extra=["-o", "sharedlink.max_names:3"], two_pass=True)
    assert [len(r["sharedlink.var.carried"]) for r in rows] == [0, 2, 2, 2]


def test_max_pending_preference(tmp_path: Path) -> None:
    cap = write(tmp_path / "queries.pcap", [frame(f"AB|Qq{i}") for i in range(5)])
    assert _limited(cap, "-o", "sharedlink.max_pending:3") == [4, 5]
    assert _limited(cap, "-2", "-o", "sharedlink.max_pending:3") == [4, 5]


def test_max_conversations_preference(tmp_path: Path) -> None:
    payloads = [frame(f"{d}B|N0|T2|QLat|D{i}") for i, d in enumerate("ACDEF")]
    cap = write(tmp_path / "dirs.pcap", payloads)
    assert _limited(cap, "-o", "sharedlink.max_conversations:2") == [3, 4, 5]


def test_journal_gives_the_same_carried_values_as_the_records(tmp_path: Path) -> None:
    """A direction with more than 32 names keeps a journal instead of a record per frame: the
    carried names, values and frames must be what a one-pass tree (the current state) shows."""
    payloads = [frame("AB|N0|" + "|".join(f"T4|Qv{k}|D{k}" for k in range(40)))]
    payloads += [frame(f"AB|N0|T4|Qv{i % 40}|Dn{i}|T4|Qw{i}|Dz") for i in range(60)]
    cap = write(tmp_path / "journal.pcap", payloads)
    names = ["sharedlink.kind", "sharedlink.var.name", "sharedlink.var.value", "sharedlink.var.carried_from"]
    one = tu.fields(cap, names, two_pass=False)
    two = tu.fields(cap, names, two_pass=True)
    assert one == two
    assert [r["sharedlink.kind"] for r in two[:2]] == [["full"], ["delta"]]
    assert len(two[-1]["sharedlink.var.name"]) == 40 + 60


def test_linear_patterns_stay_correct(tmp_path: Path) -> None:
    """The scaling patterns decode the same in one and two passes."""
    with tempfile.TemporaryDirectory() as d:
        for gen in (new_names, alternating_declarations, far_slot):
            cap = write(Path(d) / "p.pcap", gen(50))
            lines1 = tu.summary(cap)
            lines2 = tu.summary(cap, two_pass=True)
            assert lines1 == lines2, gen.__name__
    assert os.path.isdir(tmp_path)
