"""Options shared by several commands mean one thing everywhere: one ``--variables`` parser."""

from __future__ import annotations

import pytest

from sharedlink.analysis import decode
from sharedlink.capture import stream
from sharedlink.cli import main
from sharedlink.protocols.codec import TYPE_NAMES
from sharedlink.protocols.state import parse_variables


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("Lat:2,Lon:2,Name:4,Count", [("Lat", 2), ("Lon", 2), ("Name", 4), ("Count", None)]),
        ("A:2,B,", [("A", 2), ("B", None)]),  # empty items are skipped
        (" A , ,B:0 ", [("A", None), ("B", 0)]),
        ("A:", [("A", None)]),  # an empty type is no type
    ],
)
def test_parse_variables(text, expected):
    assert parse_variables(text) == expected


@pytest.mark.parametrize(("text", "words"), [("A:x", "bad type 'x' for A"), ("a|b", "bad variable name"),
                                             (":2", "bad variable name"), (",, ,", "empty variable list")])
def test_parse_variables_rejects(text, words):
    with pytest.raises(ValueError, match=words):
        parse_variables(text)


def test_one_parser_and_one_set_of_type_codes():
    assert decode.parse_variables is parse_variables and stream.parse_variable_list is parse_variables
    with pytest.raises(ValueError) as ei:
        parse_variables("A:x")
    assert all(f"{code} {name}" in str(ei.value) for code, name in TYPE_NAMES.items())


def test_every_command_reads_variables_alike(tmp_path, capsys):
    cap = tmp_path / "b.pcap"
    assert main(["gen", str(cap), "--frames", "6", "--form", "positional"]) == 0
    out = tmp_path / "o.pcap"
    commands = {
        "stats": ["stats", str(cap)],
        "export": ["export", str(cap), "-o", str(tmp_path / "o.csv")],
        "plot": ["plot", str(cap), "-o", str(tmp_path / "o.png")],
        "compress": ["compress", str(cap), str(out)],
        "expand": ["expand", str(cap), str(out)],
        "diff": ["diff", str(cap), str(cap), "--single-process"],
    }
    for name, argv in commands.items():
        capsys.readouterr()
        assert main([*argv, "--variables", "AutoGpsLat:2,AutoGpsLon:2,"]) == 0, (name, capsys.readouterr().err)
        capsys.readouterr()
        assert main([*argv, "--variables", "A:x"]) == 2, name
        assert capsys.readouterr().err == (
            "sharedlink: error: --variables: bad type 'x' for A (0 long, 2 double, 4 string)\n"), name
