"""``sharedlink lists`` (vehicle profiles, issue 29): every declaration of a capture, per node
pair in order with types, in the per-pair syntax of the variables preference, read back by
:func:`sharedlink.protocols.varlists.parse_varlists`.

The captures are the real-session vector streams (tests/vectors/sharedlink-real-sessions.json,
shaped like the public jaffe-se/shared_link_bridge sessions: the OCU on 4104 declaring both
lists to the vehicle's port 4000, no CR LF) written as pcap by tests/sl_vectors.py, plus small
streams built here in the same table shape. Expected lists are written out below from the
bridge's declarations, not from the tool."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from sl_cli import run_cli
from sl_vectors import REAL_OCU_LIST, REAL_VEHICLE_LIST, REAL_VEHICLE_TYPED, load_streams, write_stream

from sharedlink.cli import main
from sharedlink.protocols.varlists import parse_varlists

STREAMS = {s["name"]: s for s in load_streams()}
VEHICLE, OCU = REAL_VEHICLE_LIST, REAL_OCU_LIST
TYPED = REAL_VEHICLE_TYPED   # VEHICLE as its declaration reads (svp_enb_eng: the T0 before it)
OCU_ADDR, VEH_ADDR = "10.0.0.1:4104", "10.0.0.2:4000"


def _capture(tmp_path: Path, name: str) -> Path:
    stream = STREAMS[name]
    ext = "pcapng" if stream.get("transport") == "serial" else "pcap"
    return write_stream(stream, tmp_path / f"{name}.{ext}")


def _made(tmp_path: Path, name: str, payloads: list[str], transport: str = "udp") -> Path:
    """A stream of OCU-to-vehicle frames (serial: one direction) in the vector table's shape."""
    if transport == "serial":
        packets = [{"t": i * 0.1, "dir": "out", "payload": p, "frames": []} for i, p in enumerate(payloads)]
    else:
        packets = [{"t": i * 0.1, "src": OCU_ADDR, "dst": VEH_ADDR, "payload": p, "frames": []}
                   for i, p in enumerate(payloads)]
    ext = "pcapng" if transport == "serial" else "pcap"
    return write_stream({"name": name, "transport": transport, "packets": packets}, tmp_path / f"{name}.{ext}")


def _run(capsys: pytest.CaptureFixture[str], *args: str | Path) -> tuple[int, str, str]:
    rc = main(["lists", *map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


def _decl(names: list[tuple[str, int | None]], letter: str = "N", ordinal: int = 0) -> str:
    return f"{letter}{ordinal}|" + "|".join(f"T{t}|Q{n}" if t is not None else f"Q{n}" for n, t in names)


def test_declarations_in_order_with_types(tmp_path, capsys):
    cap = _capture(tmp_path, "real-declaration-replaces-the-list")
    rc, out, err = _run(capsys, cap)
    assert rc == 0 and err == ""
    lines = out.splitlines()
    assert lines[0] == f"# {cap}: 3 declarations, 1 node pair"
    # each declaration: a comment naming the frame, then the pair's list after it
    heads = [x for x in lines if x.startswith("# frame ")]
    assert heads == [f"# frame {n}: L0 from {OCU_ADDR} to {VEH_ADDR}, {k} names, checksum good" for n, k in
                     ((1, 28), (4, 7), (7, 3))]
    lists = [x for x in lines if x.startswith("B>A: ")]
    assert [parse_varlists(x)["B>A"] for x in lists] == [
        TYPED, TYPED[:7], [("AutoGpsHead", 2), ("AutoGpsVel", 2), ("VehicleName", 4)],
        [("AutoGpsHead", 2), ("AutoGpsVel", 2), ("VehicleName", 4)],  # the lists at the end
    ]
    assert "svp_enb_eng:0," in lists[0]  # declared with no T of its own: the T0 before it (issue 40)
    # the whole output reads back as the lists at the end
    assert parse_varlists(out) == {"B>A": [("AutoGpsHead", 2), ("AutoGpsVel", 2), ("VehicleName", 4)]}


def test_both_directions_of_a_connect(tmp_path, capsys):
    """What the bridge sends at CONNECT: commands, MUI/MUO, the N0 list of its 10 controls (A>B)
    and the L0 list of the vehicle's 28 values (B>A), no CR LF; L?/N? requests and data are no
    declarations."""
    cap = _made(tmp_path, "connect", [
        "[:BA|ELink|D0, SetIP, 10.0.0.1:4104, 4000|C??]", "[:BA|ELink|D0, outbound, on|C??]", "[:BA|MUI|C??]",
        "[:BA|MUO|C??]", f"[:BA|{_decl(OCU)}|C??]", f"[:BA|{_decl(VEHICLE, 'L')}|C??]", "[:BA|MW|C??]",
        "[:BA|L?|C??]", "[:BA|N?|C??]", "[:BA|N0|D0|D0|D1|D0|D0|D0|D0|D100|D0|D0|C??]", "[:BA|QAutoGpsVel|C??]",
    ])
    rc, out, _ = _run(capsys, cap)
    assert rc == 0
    assert [x for x in out.splitlines() if x.startswith("# frame ")] == [
        f"# frame 5: N0 from {OCU_ADDR} to {VEH_ADDR}, 10 names, checksum good",
        f"# frame 6: L0 from {OCU_ADDR} to {VEH_ADDR}, 28 names, checksum good",
    ]
    assert out.splitlines()[-1] == "A>B: " + ",".join(f"{n}:{t}" for n, t in OCU) + "; B>A: " + ",".join(
        f"{n}:{t}" if t is not None else n for n, t in TYPED)
    assert parse_varlists(out) == {"A>B": OCU, "B>A": TYPED}


def test_json(tmp_path, capsys):
    cap = _capture(tmp_path, "real-inbound-list-per-receiver")
    rc, out, _ = _run(capsys, "--json", cap)
    assert rc == 0
    (res,) = json.loads(out)["captures"]
    assert res["capture"] == str(cap) and res["error"] is None
    decls = res["declarations"]
    assert [(d["frame"], d["pair"], d["field"], d["ordinal"], d["src"], d["dst"], d["applied"]) for d in decls] == [
        (1, "B>A", "L", 0, OCU_ADDR, VEH_ADDR, True), (2, "B>A", "L", 0, "10.0.0.3:4104", VEH_ADDR, True)]
    assert decls[0]["names"] == [{"name": "AutoGpsHead", "type": 2}, {"name": "AutoGpsVel", "type": 2}]
    assert decls[1]["names"] == [{"name": "AutoGpsHead", "type": None}, {"name": "AutoGpsVel", "type": 2}]
    assert res["lists"] == {"B>A": decls[1]["list"]}
    assert parse_varlists(res["variables"]) == {"B>A": [("AutoGpsHead", None), ("AutoGpsVel", 2)]}


def test_a_bad_checksum_changes_no_list(tmp_path, capsys):
    cap = _made(tmp_path, "bad", [f"[:BA|{_decl(OCU)}|C??]", "[:BA|N0|T2|QOther|C!!]", "[:BA|N0|T4|QLast]"])
    rc, out, _ = _run(capsys, cap)
    assert rc == 0
    lines = out.splitlines()
    i = lines.index(f"# frame 2: N0 from {OCU_ADDR} to {VEH_ADDR}, 1 name, checksum bad")
    assert lines[i + 1] == "#   bad checksum: not applied"
    assert lines[i + 2].startswith("#   (the list stays) A>B: video_mux1:0,")
    # no checksum field counts as good (the decoding rules)
    assert f"# frame 3: N0 from {OCU_ADDR} to {VEH_ADDR}, 1 name, checksum missing" in lines
    assert parse_varlists(out) == {"A>B": [("Last", 4)]}


def test_a_declaration_at_an_ordinal_keeps_the_slots_before_it(tmp_path, capsys):
    cap = _made(tmp_path, "ordinal", [
        "[:BA|N2|T2|QC|T9|QD|C??]",  # nothing before slot 2; T9 is no type of the list syntax
        f"[:BA|{_decl([('A', 0), ('B', 4), ('X', 2), ('Y', 2)])}|C??]",
        "[:BA|L1|T2|QV|C??]",
        "[:BA|N3|T0|QZ|C??]",
    ])
    rc, out, _ = _run(capsys, "--json", cap)
    assert rc == 0
    (res,) = json.loads(out)["captures"]
    got = [[(x["name"], x["type"]) for x in d["list"]] for d in res["declarations"]]
    assert got == [
        [("#0", None), ("#1", None), ("C", 2), ("D", None)],
        [("A", 0), ("B", 4), ("X", 2), ("Y", 2)],
        [("#0", None), ("V", 2)],  # B>A: the L list of A, nothing before it
        [("A", 0), ("B", 4), ("X", 2), ("Z", 0)],
    ]
    assert res["declarations"][0]["notes"] == ["type T9 of D is not 0, 2 or 4: untyped"]
    rc, text, _ = _run(capsys, cap)
    assert parse_varlists(text) == {"A>B": [("A", 0), ("B", 4), ("X", 2), ("Z", 0)], "B>A": [("#0", None), ("V", 2)]}


def test_a_name_the_syntax_cannot_carry_becomes_its_slot(tmp_path, capsys):
    cap = _made(tmp_path, "names", ["[:BA|N0|T2|Qa,b|T4|QOk|Qx:y|C??]"])
    rc, out, _ = _run(capsys, cap)
    assert rc == 0
    assert parse_varlists(out) == {"A>B": [("#0", 2), ("Ok", 4), ("#2", 4)]}  # x:y: the T4 before it
    assert "#   name 'a,b' cannot be written in a list: shown as #0" in out.splitlines()


def test_a_serial_capture(tmp_path, capsys):
    cap = _made(tmp_path, "serial", [f"[:BA|{_decl(OCU)}|C??]\r\n", "[:BA|N0|D1|D1|D1|D1|D1|D1|D1|D1|D1|D1|C??]\r\n"],
                transport="serial")
    rc, out, _ = _run(capsys, "--json", cap)
    assert rc == 0
    (d,) = json.loads(out)["captures"][0]["declarations"]
    assert (d["frame"], d["pair"], d["src"]) == (1, "A>B", "serial outbound")


def test_several_captures_and_none_declared(tmp_path, capsys):
    first = _capture(tmp_path, "real-reply-from-the-vehicle-source-port")
    none = _capture(tmp_path, "real-vehicle-frames-with-no-list")
    last = _capture(tmp_path, "real-inbound-list-per-receiver")
    rc, out, _ = _run(capsys, first, none, last)
    assert rc == 0
    assert f"# {none}: no declarations" in out.splitlines()
    assert [x for x in out.splitlines() if x.startswith("# /")] == [
        f"# {first}: 1 declaration, 1 node pair", f"# {none}: no declarations", f"# {last}: 2 declarations, 1 node pair"]
    # read as one profile: each pair's last list
    assert parse_varlists(out) == {"A>B": OCU, "B>A": [("AutoGpsHead", None), ("AutoGpsVel", 2)]}


def test_bad_input(tmp_path, capsys):
    rc, out, err = _run(capsys, tmp_path / "missing.pcap")
    assert rc == 2 and out == "" and err.strip() == f"sharedlink: error: {tmp_path / 'missing.pcap'}: no such file"
    # a damaged capture: the declarations before the damage, then one line, exit 2
    cap = _capture(tmp_path, "real-declaration-replaces-the-list")
    data = cap.read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[: len(data) - 40])
    rc, out, err = _run(capsys, cut)
    assert rc == 2
    assert "# frame 1: L0" in out and "# frame 7:" in out
    assert err.count("\n") == 1 and err.startswith(f"sharedlink: error: {cut}: record 8: ")
    assert err.rstrip().endswith("(the declarations before it are listed)")


def test_a_profile_from_one_capture_names_another(tmp_path, capsys):
    profile = _made(tmp_path, "profile", [f"[:BA|{_decl(OCU)}|C??]", f"[:BA|{_decl(VEHICLE, 'L')}|C??]"])
    _, text, _ = _run(capsys, profile)
    variables = text.splitlines()[-1]
    rc = main(["stats", "--json", "--variables", variables, str(_capture(tmp_path, "real-vehicle-frames-with-no-list"))])
    out = capsys.readouterr().out
    assert rc == 0
    names = {(v["pair"], v["name"]) for v in json.loads(out)["variables"]}
    empty = {"svp_enb_eng", "veh_obstacle"}  # the two slots the vehicle leaves empty: no value to count
    assert {("B>A", n) for n, _ in VEHICLE if n not in empty} | {("A>B", n) for n, _ in OCU} <= names
    assert not [n for _, n in names if n.startswith("#")]  # every slot of both pairs named


def test_the_vehicle_answering_list_requests(tmp_path, capsys):
    """A ProntoAdapter-style client asks L? and N?; the vehicle answers from 1033 with its own N0
    list (its outbound list: B>A) and its L0 list (its inbound list, the OCU's: A>B)."""
    cap = _capture(tmp_path, "real-list-requests-answered-by-declarations")
    rc, out, _ = _run(capsys, "--json", cap)
    assert rc == 0
    (res,) = json.loads(out)["captures"]
    assert [(d["frame"], d["field"], d["pair"], d["src"], d["dst"]) for d in res["declarations"]] == [
        (2, "N", "B>A", "10.0.0.2:1033", OCU_ADDR), (4, "L", "A>B", "10.0.0.2:1033", OCU_ADDR)]
    assert parse_varlists(res["variables"]) == {"B>A": TYPED, "A>B": OCU}


def test_declarations_past_the_listed_limit_are_counted_and_applied(tmp_path, capsys, monkeypatch):
    from sharedlink.analysis import lists

    monkeypatch.setattr(lists, "MAX_LISTED", 2)
    cap = _made(tmp_path, "many", [f"[:BA|N0|T0|Qv{i}|C??]" for i in range(5)])
    rc, out, _ = _run(capsys, cap)
    assert rc == 0
    lines = out.splitlines()
    assert lines[0] == f"# {cap}: 5 declarations, 1 node pair"
    assert lines[1] == "# Limit exceeded: only the first 2 are listed; the 3 after them are in the lists at the end"
    assert len([x for x in lines if x.startswith("# frame ")]) == 2
    assert parse_varlists(out) == {"A>B": [("v4", 0)]}
    rc, out, _ = _run(capsys, "--json", cap)
    (res,) = json.loads(out)["captures"]
    assert res["omitted"] == 3 and len(res["declarations"]) == 2


PER_PAIR = ("B>A: " + ",".join(f"{n}:{t}" if t is not None else n for n, t in VEHICLE)
            + "; A>B: " + ",".join(f"{n}:{t}" for n, t in OCU))


@pytest.mark.parametrize("command", ["stats", "export", "diff", "compress", "expand", "plot", "ingest"])
def test_every_command_takes_per_pair_lists(tmp_path, command):
    """``--variables`` reads the per-pair syntax in every command that takes it, and the lists
    name the vehicle's 28-slot frames and the OCU's 10-slot frames (no ``#i`` left)."""

    cap = _capture(tmp_path, "real-vehicle-frames-with-no-list")
    out = tmp_path / "out"
    args = {"stats": ["--json"], "export": ["--changes", "--format", "jsonl", "-o", f"{out}.jsonl"],
            "diff": [cap, "--json"], "compress": ["-o", f"{out}.pcap"], "expand": ["-o", f"{out}.pcap"],
            "plot": ["-o", f"{out}.png"], "ingest": ["-o", out]}[command]
    r = run_cli(command, str(cap), *map(str, args), "--variables", PER_PAIR, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    if command == "stats":
        names = {(v["pair"], v["name"]) for v in json.loads(r.stdout)["variables"]}
        assert ("B>A", "AutoGpsHead") in names and ("A>B", "veh_throttle") in names
        assert not [n for _, n in names if n.startswith("#")]
    elif command == "export":
        rows = [json.loads(x) for x in Path(f"{out}.jsonl").read_text().splitlines()]
        assert {(r["src"], r["name"]) for r in rows if r["name"] in ("AutoGpsHead", "veh_throttle")} == {
            ("B", "AutoGpsHead"), ("A", "veh_throttle")}
        assert not [r for r in rows if r["name"].startswith("#")]
