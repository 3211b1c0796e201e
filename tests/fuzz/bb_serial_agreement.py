"""Random blackboard exchanges on a serial line through both decoders, record by record (the
figures of the serial blackboard commits of issue 40's last round): each seed writes a capture of
4-10 events (a set or request from either side, the answer it is owed, right or a wrong ack,
line noise), each event cut into 1-3 records, and compares tshark's messages (p2os.lua,
blackboard.lua, serial.lua) with the Python session reader's (tests/sl_robot_frames.py).

``.venv/bin/python tests/fuzz/bb_serial_agreement.py FIRST_SEED COUNT [DIR]``: prints each
differing seed (records and differences) and ``differing N of COUNT``. Not a test: some seeds
still differ (docs/serial-capture-format.md, "Blackboard answers", the known limit)."""

from __future__ import annotations

import random
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sl_robot_frames import differences, lua_frames, python_frames  # noqa: E402
from sl_robots import write_serial  # noqa: E402

from sharedlink.capture.serial_format import DIR_IN, DIR_OUT  # noqa: E402
from sharedlink.protocols import blackboard as bbc  # noqa: E402

NOISE = (b"x", b"\r\n", b"zz", b":01", b"\x00")


def _message(rng: random.Random) -> bbc.Message:
    if rng.random() < 0.5:
        return bbc.SetMessage(rng.randrange(65536), rng.randrange(256),
                              bytes(rng.randrange(256) for _ in range(rng.randint(0, 4))))
    return bbc.RequestMessage(rng.randrange(65536), rng.randrange(256), rng.randint(0, 5))


def _answer(rng: random.Random, m: bbc.Message) -> bytes:
    if isinstance(m, bbc.SetMessage):
        return bytes([m.checksum if rng.random() < 0.8 else rng.randrange(256)])
    data = bytes(rng.randrange(256) for _ in range(m.count))
    return data + bytes([bbc.response_checksum(m, data)])


def records(seed: int) -> list[tuple[bytes, int]]:
    """One seed's capture records: (bytes, direction)."""
    rng = random.Random(seed)
    owed: dict[int, bbc.Message | None] = {DIR_OUT: None, DIR_IN: None}
    events = []
    for _ in range(rng.randint(4, 10)):
        d = rng.choice([DIR_OUT, DIR_IN])
        k = rng.random()
        if k < 0.45:
            m = _message(rng)
            events.append((d, bbc.build_message(m)))
            owed[DIR_IN if d == DIR_OUT else DIR_OUT] = m
        elif k < 0.85 and owed[d] is not None:
            events.append((d, _answer(rng, owed[d])))  # type: ignore[arg-type]
            owed[d] = None
        else:
            events.append((d, rng.choice(NOISE)))
    out = []
    for d, b in events:
        cuts = sorted(rng.sample(range(1, len(b)), min(len(b) - 1, rng.randint(0, 2)))) if len(b) > 1 else []
        a = 0
        for c in [*cuts, len(b)]:
            out.append((b[a:c], d))
            a = c
    return out


def main(first: int, count: int, directory: Path) -> int:
    bad = 0
    for seed in range(first, first + count):
        recs = records(seed)
        cap = write_serial(directory / f"bb-serial-{seed}.pcapng", recs)
        diff = differences(lua_frames(cap), python_frames(cap))
        if diff:
            bad += 1
            print("seed", seed, diff)
            print("   ", [("O" if d == DIR_OUT else "I", b) for b, d in recs])
    print(f"differing {bad} of {count}")
    return bad


if __name__ == "__main__":
    args = sys.argv[1:]
    with tempfile.TemporaryDirectory() as tmp:
        main(int(args[0]), int(args[1]), Path(args[2]) if len(args) > 2 else Path(tmp))
