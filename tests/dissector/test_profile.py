"""`sharedlink plugins install --profile` (issue 43) against a temporary HOME, checked with the
real tshark: `tshark -C SharedLink` shows the profile's SharedLink columns (from, to, kind,
checksum status, outage duration) on a generated capture with a planted outage, and `uninstall`
removes the profile again."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli

from tshark_util import TSHARK_CMD, check_stderr

pytestmark = pytest.mark.skipif(TSHARK_CMD != [shutil.which("tshark") or "/usr/bin/tshark"],
                                reason="needs the machine's own tshark")
sys.path.insert(0, str(Path(__file__).parent))
from tshark_util import env_for  # noqa: E402


def cli(home: Path, *args: object) -> subprocess.CompletedProcess:
    return run_cli(*args, check=True, env=env_for(home))


def test_profile_install_columns_uninstall(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    cap = tmp_path / "o.pcap"
    cli(home, "gen", "-o", cap, "--duration", 20, "--outage", "5:3")
    out = cli(home, "plugins", "install", "--profile").stdout
    assert "SharedLink configuration profile" in out and "I/O graphs in the columns of Wireshark 3.6-4.4" in out
    prof = Path(cli(home, "plugins", "path", "--json").stdout.split('"profile": "')[1].split('"')[0])
    assert sorted(p.name for p in prof.iterdir()) == ["colorfilters", "dfilter_buttons", "io_graphs", "preferences"]
    r = subprocess.run([*TSHARK_CMD, "-n", "-C", "SharedLink", "-r", str(cap), "-Y", "sharedlink.outage"],
                       capture_output=True, text=True, env=env_for(home), timeout=120)
    assert r.returncode == 0, r.stderr
    check_stderr(r.stderr)
    (line,) = r.stdout.splitlines()
    cols = line.split()
    assert cols[:1] == ["26"] and "B" in cols and "A" in cols and "full" in cols and "3.2" in cols, line
    out = cli(home, "plugins", "uninstall").stdout
    assert "removed the SharedLink configuration profile" in out and not prof.exists()
