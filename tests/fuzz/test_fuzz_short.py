"""A short fuzz run of the Lua dissectors under the real tshark ($SHAREDLINK_TSHARK).

The long run is ``make fuzz`` (scripts/fuzz.py); both use tests/fuzz/fuzz_harness.py. Here: a few
editcap seeds per sample capture, every prefix of every sample frame, random payloads on our
ports over UDP and TCP, 64 KB adversarial payloads (linear time), and the kept regressions.
The first tests prove the harness itself fails when it must.
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import fuzz_harness as fh
import pytest

#: editcap's mutation seeds: the first in make test, the others in make test-long (each is about
#: 3.5 s of CPU on the samples; make fuzz runs hundreds)
SEEDS = (1, pytest.param(2, marks=pytest.mark.long), pytest.param(3, marks=pytest.mark.long))
RANDOM_PAYLOADS = 1500


@pytest.fixture(scope="module")
def work() -> Iterator[Path]:
    d = fh.readable_tmpdir("slfuzz-short-")
    yield d
    shutil.rmtree(d, ignore_errors=True)


@pytest.fixture(scope="module")
def samples(work: Path) -> list[Path]:
    return fh.make_samples(work / "samples")


def _assert_clean(outcomes: list[fh.Outcome]) -> None:
    bad = [o.describe() for o in outcomes if not o.ok]
    assert not bad, f"{len(bad)} of {len(outcomes)} runs failed under {fh.tshark_version()}:\n" + "\n".join(bad)


# --- the harness fails when it must -----------------------------------------------------------


def test_dissectors_load_and_register_their_protocols():
    d = fh.load_dissectors()
    filters = {p.filter for p in d.protocols}
    assert "sharedlink" in filters, d
    assert 7013 in d.ports


def test_a_run_that_decodes_nothing_fails(work: Path):
    p = work / "other-port.pcap"
    fh.write_udp(p, [b"no protocol of ours here"] * 3, port=9)
    o = fh.run_tshark(p)
    assert o.frames == 3 and o.decoded == 0
    assert not o.ok and "decoded none" in o.problems[-1]
    o = fh.run_tshark(p, mode="fields")
    assert (o.frames, o.decoded, o.ok) == (3, 0, False), o


def test_a_lua_error_fails(work: Path):
    bad = work / "broken.lua"
    bad.write_text(
        'local p = Proto("fuzzbroken", "Broken")\n'
        "function p.dissector(tvb, pinfo, tree) tree:add(p, tvb()); return tvb(tvb:len() + 1, 2):uint() end\n"
        'DissectorTable.get("udp.port"):add(9, p)\n'
    )
    bad.chmod(0o644)
    p = work / "to-broken.pcap"
    fh.write_udp(p, [b"x"] * 2, port=9)
    for mode in fh.MODES:
        o = fh.run_tshark(p, require_decoded=False, extra=["-X", f"lua_script:{bad}"], mode=mode)
        assert [f for f, _ in o.lua_errors] == [1, 2], o.describe()
        assert not o.ok


def test_a_run_past_its_cpu_limit_fails(work: Path):
    spin = work / "spin.lua"
    spin.write_text(
        'local p = Proto("fuzzspin", "Spin")\n'
        "function p.dissector(tvb, pinfo, tree) local i = 0; while true do i = i + 1 end end\n"
        'DissectorTable.get("udp.port"):add(9, p)\n'
    )
    spin.chmod(0o644)
    p = work / "to-spin.pcap"
    fh.write_udp(p, [b"x"], port=9)
    o = fh.run_tshark(p, fh.Limits(cpu_s=1, wall_s=30), require_decoded=False, extra=["-X", f"lua_script:{spin}"])
    assert not o.ok and ("CPU limit" in o.describe() or o.timed_out), o.describe()


# --- fuzzing ----------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", fh.MODES)
def test_samples_decode_cleanly(samples: list[Path], mode: str):
    outcomes = [fh.run_tshark(p, mode=mode) for p in samples]
    _assert_clean(outcomes)
    for o in outcomes:
        if o.path.name in {n for n, _ in fh.SAMPLE_OPTIONS}:
            assert o.decoded == o.frames, o  # every beacon frame is SharedLink


@pytest.mark.parametrize("seed", SEEDS)
def test_editcap_mutations(samples: list[Path], work: Path, seed: int):
    outcomes = []
    for p in samples:
        m = fh.mutate(p, work / f"mut-{seed}-{p.name}", seed)
        outcomes.append(fh.run_tshark(m, mode=fh.MODES[seed % len(fh.MODES)]))
    _assert_clean(outcomes)


@pytest.mark.parametrize("mode", fh.MODES)
def test_every_prefix_of_every_sample_frame(work: Path, mode: str):
    p = work / f"prefixes-{mode}.pcap"
    n = fh.write_truncations(p, fh.samples_with_endpoints())
    o = fh.run_tshark(p, mode=mode)
    assert o.frames == n
    _assert_clean([o])


@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_random_payloads_on_our_ports(work: Path, transport: str):
    rng = random.Random(f"short-{transport}")
    samples = [payload for _, payload in fh.sample_payloads()]
    ports = [*fh.load_dissectors().ports, fh.HEURISTIC_PORT]
    outcomes = []
    for port in ports:
        p = work / f"random-{transport}-{port}.pcap"
        payloads = fh.random_payloads(rng, RANDOM_PAYLOADS // len(ports), samples)
        (fh.write_udp if transport == "udp" else fh.write_tcp)(p, payloads, port=port)
        mode = fh.MODES[port % len(fh.MODES)]
        outcomes.append(fh.run_tshark(p, require_decoded=port != fh.HEURISTIC_PORT, mode=mode))
    _assert_clean(outcomes)


@pytest.mark.long
def test_64k_adversarial_payloads_take_linear_time(work: Path):
    """All patterns at 4 KB x 16 copies and at 64 KB x 1: the same bytes, so linear code takes
    the same time for both; quadratic code would take 16 times as long for the 64 KB file."""
    patterns = fh.adversarial_patterns()
    base_p = work / "adv-base.pcap"
    fh.write_udp(base_p, [b"[:AB|P1|C" + b"%02X" % fh.codec.checksum(b":AB|P1|C") + b"]\r\n"])
    base = min(fh.run_tshark(base_p).cpu_s for _ in range(2))
    runs = {}
    for size, copies in ((4096, 16), (65507, 1)):
        p = work / f"adv-{size}.pcap"
        fh.write_udp(p, [fh.adversarial_payload(u, size) for u in patterns.values() for _ in range(copies)])
        runs[size] = fh.run_tshark(p, fh.Limits(cpu_s=60, wall_s=180), require_decoded=False)
    _assert_clean(list(runs.values()))
    small, big = (max(runs[s].cpu_s - base, 0.05) for s in (4096, 65507))
    assert big <= 4 * small + 0.5, f"64 KB payloads: {big:.2f} s of CPU beyond start-up vs {small:.2f} s for the same bytes in 4 KB payloads"


def test_kept_regressions_stay_fixed():
    caps = fh.regression_captures()
    if not caps:
        pytest.skip("no kept fuzz regressions (tests/fuzz/fuzz-regressions/ is empty)")
    _assert_clean([fh.run_tshark(p, require_decoded=False, mode=m) for p in caps for m in fh.MODES])


def test_kept_parser_inputs_stay_fixed():
    """Every kept parser input (``codec-TARGET-*.bin``, written by ``make fuzz``) and every seed
    input of the targets goes through its target again: the replay always runs (no kept input
    yet is no reason to skip it), and a kept input naming no target fails instead of being
    passed over."""
    import fuzz_codecs

    targets = fuzz_codecs.targets()
    kept = sorted(fh.REGRESSIONS_DIR.glob("codec-*.bin")) if fh.REGRESSIONS_DIR.is_dir() else []
    unknown = [p.name for p in kept if p.name[len("codec-") :].rsplit("-", 1)[0] not in targets]
    assert not unknown, f"kept inputs of no target: {unknown}"
    seeds = fuzz_codecs.seeds()
    untried = []
    for name, target in targets.items():
        inputs = [p.read_bytes() for p in kept if p.name[len("codec-") :].rsplit("-", 1)[0] == name]
        inputs += seeds.get(name.split(".")[0], [])
        for data in inputs:
            target(data)
        if not inputs:
            untried.append(name)
    assert not untried, f"targets with no input to replay: {untried}"


# --- the root filesystem wrapper (when `make rootfs` has built the roots) ----------------------

WRAPPER = fh.REPO / "scripts" / "tshark-in-rootfs"


def _built_suites() -> list[str]:
    return [s for s in ("trixie", "sid") if subprocess.run([str(fh.REPO / "scripts" / "rootfs.sh"), "path", s],
                                                          capture_output=True).returncode == 0]


@pytest.mark.parametrize("suite", ["trixie", "sid"])
def test_wrapper_runs_unprivileged_with_paths_unchanged_and_leaves_no_mount(suite: str, tmp_path: Path):
    if os.geteuid() != 0 or suite not in _built_suites():
        pytest.skip(f"the {suite} root filesystem is not built (make rootfs, as root)")
    private = tmp_path / "private"
    private.mkdir(mode=0o700)
    (private / "x.txt").write_text("readable\n")
    (private / "x.txt").chmod(0o600)
    mounts_before = open("/proc/self/mountinfo").read().count("sharedlink")
    script = f"id -u; cat {private / 'x.txt'}; pwd; touch {private / 'w'} 2>/dev/null && echo wrote; exit 7"
    r = subprocess.run([str(WRAPPER), "--program", "sh", suite, "-c", script], capture_output=True, text=True, cwd=fh.REPO)
    assert r.returncode == 7, r.stderr
    uid, text, cwd, *rest = r.stdout.splitlines()
    assert uid != "0" and text == "readable" and cwd == str(fh.REPO)
    assert rest == []  # it reads root-only files but cannot write there
    assert open("/proc/self/mountinfo").read().count("sharedlink") == mounts_before
