"""Every message `export --format mcap` writes, checked against the official Foxglove schemas.

The file is read with the independent `mcap` reader. Protobuf channels are decoded with the
official generated classes of `foxglove-schemas-protobuf` (not with the descriptors stored in
the file), turned into the JSON form Foxglove's JSON encoding uses and validated with
`jsonschema` against the official JSON Schemas of `@foxglove/schemas` 2.1.0 (vendored in
tests/schemas/foxglove with their licence). JSON channels are validated against the JSON Schema
the file itself stores for them (what Foxglove checks them with).
"""

from __future__ import annotations

import json
import math
import sys
from collections import defaultdict
from pathlib import Path

import jsonschema
import pytest

if sys.version_info < (3, 10):  # foxglove-schemas-protobuf (the official classes) needs Python 3.10
    pytest.skip("foxglove-schemas-protobuf needs Python 3.10+", allow_module_level=True)
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf.descriptor import FieldDescriptor
from mcap.reader import make_reader
from sl_cli import run_cli

from sharedlink.generators.beacon import GenOptions, generate_file

SCHEMAS = Path(__file__).resolve().parents[1] / "schemas" / "foxglove"
OFFICIAL = {"foxglove.LocationFix": LocationFix, "foxglove.PoseInFrame": PoseInFrame}
CLI = [sys.executable, "-m", "sharedlink"]


def official_schema(name: str) -> dict:
    return json.loads((SCHEMAS / f"{name.split('.')[1]}.json").read_text())


def _repeated(f: FieldDescriptor) -> bool:
    rep = getattr(f, "is_repeated", None)  # protobuf >= 6 (``label`` is gone in 7)
    return bool(rep) if rep is not None else f.label == FieldDescriptor.LABEL_REPEATED


def as_json(msg) -> dict:
    """A protobuf message in Foxglove's JSON form: every field (defaults too, as a reader
    decoding the bytes sees them), timestamps as ``{sec, nsec}``, enums as numbers; an unset
    field with presence (``optional``, a message) left out."""
    if msg.DESCRIPTOR.full_name == "google.protobuf.Timestamp":
        return {"sec": msg.seconds, "nsec": msg.nanos}
    out = {}
    for f in msg.DESCRIPTOR.fields:
        value = getattr(msg, f.name)
        if _repeated(f):
            out[f.name] = [as_json(v) if f.type == FieldDescriptor.TYPE_MESSAGE else v for v in value]
        elif f.has_presence and not msg.HasField(f.name):
            continue
        elif f.type == FieldDescriptor.TYPE_MESSAGE:
            out[f.name] = as_json(value)
        else:
            out[f.name] = value
    return out


def read_all(path: Path) -> tuple[dict, dict]:
    """topic -> [(schema name, its encoding, schema data, message encoding, log time, message bytes)]
    and the summary's message counts."""
    msgs: dict[str, list] = defaultdict(list)
    with open(path, "rb") as fh:
        r = make_reader(fh)
        for schema, channel, message in r.iter_messages(log_time_order=False):
            msgs[channel.topic].append((schema.name, schema.encoding, schema.data, channel.message_encoding,
                                        message.log_time, message.data))
        summary = r.get_summary()
    by_id = {cid: ch.topic for cid, ch in summary.channels.items()}
    counts = {by_id[cid]: n for cid, n in summary.statistics.channel_message_counts.items()}
    return msgs, counts


def check_file(path: Path) -> dict[str, int]:
    """Validates every message of every channel; messages checked per schema name."""
    msgs, counts = read_all(path)
    assert counts == {t: len(v) for t, v in msgs.items()}
    assert all(counts.values()), f"a channel without messages: {counts}"
    checked: dict[str, int] = defaultdict(int)
    validators: dict[str, jsonschema.protocols.Validator] = {}
    for topic, items in msgs.items():
        for name, schema_encoding, schema_data, encoding, _t, data in items:
            if encoding == "protobuf":
                assert schema_encoding == "protobuf" and name in OFFICIAL, (topic, name)
                msg = OFFICIAL[name].FromString(data)
                doc = as_json(msg)
                v = validators.get(name)
                if v is None:
                    v = validators[name] = jsonschema.Draft7Validator(official_schema(name))
            else:
                assert (encoding, schema_encoding) == ("json", "jsonschema"), (topic, encoding)
                doc = json.loads(data)
                key = f"{topic} {name}"
                v = validators.get(key)
                if v is None:
                    schema = json.loads(schema_data)
                    jsonschema.validators.validator_for(schema).check_schema(schema)
                    v = validators[key] = jsonschema.validators.validator_for(schema)(schema)
            errors = [e.message for e in v.iter_errors(doc)]
            assert not errors, (topic, errors[:3], doc)
            checked[name] += 1
    return dict(checked)


def export(tmp_path: Path, cap: Path) -> Path:
    out = tmp_path / (cap.stem + ".mcap")
    r = run_cli("export", str(cap), "-o", str(out), timeout=120)
    assert r.returncode == 0, r.stderr
    return out


def test_every_beacon_message_is_valid_against_the_official_schemas(tmp_path):
    cap = tmp_path / "drive.pcap"
    generate_file(GenOptions(duration=40, seed=5, compress=True, drop=0.05, bad_checksum=0.05), cap)
    out = export(tmp_path, cap)
    checked = check_file(out)
    assert checked["foxglove.LocationFix"] > 150 and checked["sharedlink.Values"] > 150
    assert checked["sharedlink.Frame"] == checked["sharedlink.Values"]
    # the units the schema states (radians, m/s); the values channel keeps degrees and mph
    msgs, _ = read_all(out)
    fixes = [(m[-2], LocationFix.FromString(m[-1])) for m in msgs["/sharedlink/B_to_A/location"]]
    values = {m[-2]: json.loads(m[-1]) for m in msgs["/sharedlink/B_to_A/values"]}
    for t, f in fixes:
        v = values[t]
        assert f.heading == pytest.approx(math.radians(v["AutoGpsHead"]), abs=1e-12)
        assert math.hypot(f.velocity.x, f.velocity.y) == pytest.approx(v["AutoGpsVel"] * 0.44704, abs=1e-9)
        assert list(f.position_covariance) == [0.0] * 9 and f.position_covariance_type == 0
    assert max(v["AutoGpsHead"] for v in values.values()) > 2 * math.pi  # degrees would not pass for radians
    assert all(0 <= f.heading < 2 * math.pi for _t, f in fixes)


def test_the_old_location_fix_fails_the_official_schema():
    """The check can fail: a fix as export wrote it before (no covariance) is refused."""
    fix = LocationFix(latitude=1.0, longitude=2.0, frame_id="B>A", heading=5.0)
    errors = list(jsonschema.Draft7Validator(official_schema("foxglove.LocationFix")).iter_errors(as_json(fix)))
    assert any("position_covariance" in str(e.path) or "should be non-empty" in e.message
               or "is too short" in e.message for e in errors), [e.message for e in errors]


@pytest.mark.parametrize("protocol, transport", [("p2os", "tcp"), ("p2os", "serial"), ("blackboard", "udp")])
def test_every_session_message_is_valid_against_the_official_schemas(tmp_path, protocol, transport):
    cap = tmp_path / f"{protocol}-{transport}.pcapng"
    r = run_cli("gen", str(cap), "--protocol", protocol, "--transport", transport, "--duration", "6", timeout=120)
    assert r.returncode == 0, r.stderr
    checked = check_file(export(tmp_path, cap))
    if protocol == "p2os":
        assert checked["foxglove.PoseInFrame"] > 10 and checked["p2os.Sip"] == checked["foxglove.PoseInFrame"]
    else:
        assert checked["blackboard.Message"] > 10


def test_a_serial_session_without_a_position_has_no_location_channel(tmp_path):
    """No channel without data: a SharedLink direction whose variables hold no position."""
    cap = tmp_path / "serial.pcapng"
    r = run_cli("gen", str(cap), "--protocol", "sharedlink", "--transport", "serial", "--duration", "4", timeout=120)
    assert r.returncode == 0, r.stderr
    msgs, counts = read_all(export(tmp_path, cap))
    assert all(counts.values()) and counts
    for topic in counts:
        if topic.endswith("/location"):
            assert counts[topic] > 0
    check_file(tmp_path / "serial.mcap")
