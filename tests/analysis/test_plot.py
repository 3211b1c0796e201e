"""`sharedlink plot`: a real PNG with the track (viridis colours), start/end, gap and checksum
markers, and one panel per variable."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.image as mpimg  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib import colormaps  # noqa: E402
from sl_cli import run_cli

from sharedlink.analysis.plot import BAD_COLOUR, Thinned, build_figure, collect, figure_for_capture  # noqa: E402
from sharedlink.generators.beacon import GenOptions, generate_file  # noqa: E402

BEACON = ["AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel"]

VARIANTS = {
    "named": dict(),
    "named-compressed": dict(compress=True, drop=0.05, bad_checksum=0.05),
    "positional": dict(form="positional"),
    "positional-compressed": dict(form="positional", compress=True, bad_checksum=0.05),
}


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("plot")
    out = {}
    for name, kw in VARIANTS.items():
        out[name] = d / f"{name}.pcap"
        generate_file(GenOptions(duration=90, seed=6, **kw), out[name])
    return out


def panels(fig) -> list:
    return [ax for ax in fig.axes if ax.get_label() not in ("<colorbar>", "<link quality>")]


def viridis_pixels(img: np.ndarray) -> int:
    """Pixels within a small distance of one of 16 viridis colours."""
    rgb = img[..., :3].reshape(-1, 3)
    ref = colormaps["viridis"](np.linspace(0.1, 0.9, 9))[:, :3]
    d = np.min(np.linalg.norm(rgb[:, None, :] - ref[None, :, :], axis=2), axis=1)
    return int((d < 0.03).sum())


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_figure_has_track_and_one_panel_per_variable(captures, variant):
    data = collect(captures[variant])
    assert data.variables == BEACON
    fig = build_figure(data, elapsed=True)
    axes = panels(fig)
    assert len(axes) == 2 + len(BEACON) and axes[-1].get_label() == "events"
    assert axes[0].get_title(loc="left") == "GPS track"
    assert [ax.get_ylabel().split("\n")[0] for ax in axes[1:-1]] == BEACON
    # the track: a scatter coloured with viridis, by speed, start and end markers
    scatter = [c for c in axes[0].collections if c.get_array() is not None]
    assert scatter and scatter[0].get_cmap().name == "viridis"
    assert len(scatter[0].get_offsets()) > 300
    labels = axes[0].get_legend_handles_labels()[1]
    assert "start" in labels and "end" in labels
    if VARIANTS[variant].get("bad_checksum"):
        assert any(lb.startswith("bad checksums (") for lb in labels)
        assert data.checksum_failures > 0
    if VARIANTS[variant].get("drop"):
        assert any(lb.startswith("frames dropped (") for lb in labels) and data.gaps > 0
    else:
        assert data.gaps == 0
    # every variable panel has its line, ending at the last value sent
    # (then a red vertical line per checksum failure)
    for ax in axes[1:-1]:
        line, *marks = ax.get_lines()
        assert len(line.get_xdata()) > 10
        assert max(line.get_xdata()) <= data.duration_s + 1e-9
        assert len(marks) == data.checksum_failures
        assert all(m.get_color() == BAD_COLOUR for m in marks)


def test_vars_picks_panels(captures):
    fig = figure_for_capture(captures["named"], ["AutoGpsVel", "AutoGpsHead"])
    axes = panels(fig)
    assert len(axes) == 4 and [ax.get_ylabel() for ax in axes[1:-1]] == ["AutoGpsVel\n(mph)", "AutoGpsHead\n(°)"]
    with pytest.raises(ValueError, match="Nope"):
        figure_for_capture(captures["named"], ["Nope"])


def test_png_is_a_real_image(captures, tmp_path):
    out = tmp_path / "drive.png"
    r = run_cli("plot", captures["named-compressed"], "-o", out)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = mpimg.imread(str(out))
    h, w = img.shape[:2]
    assert (w, h) == (1000, 1480)  # 10 in x (6.8 + 4 * 1.7 + 1.2: the link-quality strip) in at 100 dpi
    assert viridis_pixels(img) > 2000  # the track's colours are there
    # the marker colours too: red crosses (checksum failures), orange rings (dropped frames)
    rgb = img[..., :3]
    red = np.array(matplotlib.colors.to_rgb(BAD_COLOUR))
    assert (np.linalg.norm(rgb - red, axis=2) < 0.08).sum() > 50
    # fewer panels, a shorter image; positional captures plot the same way
    out2 = tmp_path / "pos.png"
    r = run_cli("plot", captures["positional"], "-o", out2, "--vars", "AutoGpsVel", "--json")
    assert r.returncode == 0, r.stderr
    assert '"panels": 2' in r.stdout
    img2 = mpimg.imread(str(out2))
    assert img2.shape[:2] == (970, 1000) and viridis_pixels(img2) > 2000


def test_plot_bad_input(captures, tmp_path):
    r = run_cli("plot", captures["named"], "-o", tmp_path / "x.png", "--vars", "Nope")
    assert r.returncode == 2 and "Nope" in r.stderr and "Traceback" not in r.stderr
    r = run_cli("plot", tmp_path / "none.pcap", "-o", tmp_path / "x.png")
    assert r.returncode == 2 and "no such file" in r.stderr
    r = run_cli("plot", captures["named"], "-o", tmp_path / "x.txt")
    assert r.returncode == 2
    assert not (tmp_path / "x.png").exists()


def test_thinned_keeps_a_bounded_even_sample():
    t = Thinned(100)
    for i in range(100_000):
        t.add(float(i), float(i))
    xs = t.columns()[0]
    assert 100 <= len(xs) < 200
    steps = {b - a for a, b in zip(xs, xs[1:])}
    assert len(steps) == 1  # evenly spaced
    assert xs[0] == 0.0 and xs[-1] > 99_000 - 2 * next(iter(steps))
