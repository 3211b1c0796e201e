"""The one error hierarchy (sharedlink.errors) and cli.main reporting it once, exit 2."""

from __future__ import annotations

import pytest

from sharedlink import errors
from sharedlink.analysis.transform import TransformError
from sharedlink.capture.pcapio import CaptureError, read_records
from sharedlink.capture.serial_import import SerialImportError, read_log
from sharedlink.cli import main
from sharedlink.protocols import blackboard, codec, p2os
from sharedlink.replay import ReplayError


@pytest.mark.parametrize(
    ("cls", "base"),
    [
        (codec.SharedLinkError, errors.DecodeError),
        (p2os.P2osError, errors.DecodeError),
        (blackboard.BlackboardError, errors.DecodeError),
        (CaptureError, errors.InputError),
        (SerialImportError, errors.InputError),
        (TransformError, errors.OutputError),
        (ReplayError, errors.UsageError),
    ],
)
def test_every_error_has_its_place(cls, base):
    assert issubclass(cls, base) and issubclass(cls, errors.Error)


def test_decode_errors_carry_offset_and_reason():
    with pytest.raises(errors.DecodeError) as ei:
        codec.parse_frame(b"[:AB|N0|D1")
    assert isinstance(ei.value, ValueError)  # as they always were
    assert isinstance(ei.value.offset, int) and ei.value.reason and str(ei.value).startswith(f"offset {ei.value.offset}: ")
    for parse, data in ((p2os.parse_packet, b"\xfa\xfb\x03"), (blackboard.parse_message, b"junk")):
        with pytest.raises(errors.DecodeError) as ei:
            parse(data)
        assert isinstance(ei.value.offset, int) and ei.value.reason


def test_input_errors_carry_path_record_and_reason(tmp_path):
    bad = tmp_path / "bad.pcap"
    bad.write_bytes(b"not a capture at all, no magic here")
    with pytest.raises(errors.InputError) as ei:
        list(read_records(bad))
    assert (ei.value.path, ei.value.record) == (str(bad), None) and "magic" in ei.value.reason
    assert str(ei.value) == f"{bad}: file header: {ei.value.reason}"

    log = tmp_path / "bad.txt"
    log.write_text("00000000  5b 3a 41  |[:A|\n00000010  41 42\n")
    with pytest.raises(errors.InputError) as ei:
        read_log(log, "hex")
    assert isinstance(ei.value, SerialImportError) and isinstance(ei.value, ValueError)
    assert ei.value.record == ei.value.line == 2 and str(ei.value) == f"{log}: line 2: {ei.value.reason}"


def test_cli_reports_each_error_once(tmp_path, capsys):
    bad = tmp_path / "bad.pcap"
    bad.write_bytes(b"not a capture at all, no magic here")
    out = tmp_path / "out.pcap"
    for argv in (["stats", str(bad)], ["export", str(bad)], ["compress", str(bad), "-o", str(out)],
                 ["expand", str(bad), "-o", str(out)]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith(f"sharedlink: error: {bad}: file header: not a pcap") and err.count("sharedlink: error:") == 1, (argv, err)
    log = tmp_path / "bad.txt"
    log.write_text("00000000  5b 3a 41  |[:A|\n00000010  41 42\n")
    assert main(["serial", "import", str(log), "-o", str(tmp_path / "x.pcapng"), "--log-format", "hex"]) == 2
    assert capsys.readouterr().err.startswith(f"sharedlink: error: {log}: line 2: ")
    assert main(["replay", str(bad), "--to", "127.0.0.1:9", "--speed", "0"]) == 2  # the one number validator
    err = capsys.readouterr().err
    assert err.endswith("sharedlink: error: argument --speed: 0 is out of range: give a number at least 0.001 and at most "
                        "1e+06 (1e-3: a thousand times slower)\n") and err.count("sharedlink: error:") == 1, err
