"""gen: frames per second of `sharedlink gen` against a plain scapy loop making the same frames."""

from __future__ import annotations

import time
from pathlib import Path

from bench import Result
from sharedlink.generators.beacon import GenOptions, beacon_payloads, generate_file

GEN_FRAMES = 200_000
SCAPY_FRAMES = 4_000


def scapy_loop(payloads: list[tuple[int, bytes]], path: Path) -> None:
    """What a user would write: build Ether/IP/UDP/Raw per frame, then write it."""
    from scapy.all import IP, UDP, Ether, PcapWriter, Raw

    w = PcapWriter(str(path), nano=True, sync=False)
    for i, (ts, p) in enumerate(payloads):
        pkt = (
            Ether(dst="ff:ff:ff:ff:ff:ff", src="02:00:00:00:00:02")
            / IP(src="192.168.1.12", dst="255.255.255.255", id=i + 1, flags="DF")
            / UDP(sport=7013, dport=7013)
            / Raw(p)
        )
        pkt.time = ts / 1e9
        w.write(pkt)
    w.close()


def run(work: Path) -> list[Result]:
    import logging

    logging.getLogger("scapy").setLevel(logging.ERROR)
    # the scapy loop gets its payloads ready-made: it is timed on packet building and writing only
    payloads = [(ts, p) for ts, p, _ in beacon_payloads(GenOptions(frames=SCAPY_FRAMES))]
    best_scapy = best_gen = 0.0
    for _ in range(2):  # interleaved, best of two each, so load on the machine hits both alike
        t = time.perf_counter()
        scapy_loop(payloads, work / "scapy.pcap")
        best_scapy = max(best_scapy, SCAPY_FRAMES / (time.perf_counter() - t))
        t = time.perf_counter()
        generate_file(GenOptions(frames=GEN_FRAMES), work / "gen.pcap")
        best_gen = max(best_gen, GEN_FRAMES / (time.perf_counter() - t))
    ratio = best_gen / best_scapy
    return [
        Result(
            "gen frames/s vs scapy loop",
            f"{best_gen:,.0f} frames/s",
            f"{best_scapy:,.0f} frames/s",
            ratio,
            ">= 100x",
            ratio >= 100,
        )
    ]
