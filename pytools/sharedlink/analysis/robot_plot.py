"""``plot`` for P2OS and blackboard captures (issue 42): the P2OS x/y track (the standard SIPs'
odometry, in the robot's frame: mm, not geographic), the wheel velocities and the battery over
time, and a blackboard message timeline (one row per message type, bad checksums in red).

:class:`RobotPlotData` gathers the :class:`~sharedlink.analysis.sessions.SessionMessage` s of one
streaming pass (series :class:`~sharedlink.analysis.thinned.Thinned`: bounded memory);
:func:`build_robot_figure` draws the panels of the protocols present.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sharedlink.analysis.sessions import Ack, SessionMessage
from sharedlink.analysis.thinned import Thinned
from sharedlink.capture.pcapio import NS
from sharedlink.protocols import blackboard, p2os

#: the blackboard timeline's rows, bottom to top
BB_ROWS = ("set", "ack", "request", "response")
_BB_KIND = {blackboard.SetMessage: "set", Ack: "ack", blackboard.RequestMessage: "request",
            blackboard.ReadResponse: "response"}


@dataclass
class RobotPlotData:
    max_points: int = 5000
    t0_ns: int | None = None
    p2os: int = 0  # packets
    blackboard: int = 0  # messages and answers
    sips: dict[int, Thinned] = field(default_factory=dict)  # session -> (t, x, y, lvel, rvel, volts)
    bb: Thinned | None = None  # (t, row, ok)
    bad: int = 0  # checksum failures (both protocols)

    @property
    def packets(self) -> int:
        return self.p2os + self.blackboard

    def add(self, m: SessionMessage) -> None:
        if self.t0_ns is None:
            self.t0_ns = m.ts_ns
        t = (m.ts_ns - self.t0_ns) / NS
        if m.ok is False:
            self.bad += 1
        if m.protocol == "p2os":
            self.p2os += 1
            s = m.message
            if type(s) is p2os.Sip:
                th = self.sips.get(m.session)
                if th is None:
                    th = self.sips[m.session] = Thinned(self.max_points)
                th.add(t, s.xpos, s.ypos, s.lvel, s.rvel, s.battery / 10)
            return
        self.blackboard += 1
        if self.bb is None:
            self.bb = Thinned(self.max_points)
        kind = _BB_KIND.get(type(m.message))
        if kind is not None:
            self.bb.add(t, BB_ROWS.index(kind), m.ok is not False)


def build_robot_figure(data: RobotPlotData, title: str):
    """The panels: P2OS track, velocities, battery (when SIPs were seen); the blackboard
    timeline (when messages were). Returns the Figure."""
    from matplotlib.figure import Figure

    panels = (["track", "velocity", "battery"] if data.sips else []) + (["timeline"] if data.bb is not None else [])
    if not panels:
        raise ValueError("no P2OS SIP and no blackboard message to plot")
    ratios = {"track": 4.5, "velocity": 1.7, "battery": 1.3, "timeline": 1.6}
    fig = Figure(figsize=(10, 1.5 + sum(ratios[p] for p in panels)), dpi=100, layout="constrained")
    gs = fig.add_gridspec(len(panels), 1, height_ratios=[ratios[p] for p in panels])
    fig.suptitle(f"{title}: {data.p2os} P2OS packets, {data.blackboard} blackboard messages, "
                 f"{data.bad} checksum failures")
    timed = None
    for i, name in enumerate(panels):
        ax = fig.add_subplot(gs[i], sharex=timed if name != "track" else None)
        if name == "track":
            _track(ax, data)
            continue
        timed = timed or ax
        {"velocity": _velocity, "battery": _battery, "timeline": _timeline}[name](ax, data)
        ax.set_xlabel("time since the first packet (s)")
    return fig


def _track(ax, data: RobotPlotData) -> None:
    for session, th in sorted(data.sips.items()):
        t, x, y, *_ = th.columns()
        sc = ax.scatter(x, y, c=t, cmap="viridis", s=6, label=f"session {session}")
        ax.plot(x[:1], y[:1], "go", ms=8)
        ax.plot(x[-1:], y[-1:], "rs", ms=8)
    ax.figure.colorbar(sc, ax=ax, label="time (s)")
    ax.set_title("P2OS odometry track (robot frame; start green, end red)")
    ax.set_xlabel("x (mm, robot odometry frame)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal", adjustable="datalim")


def _velocity(ax, data: RobotPlotData) -> None:
    for session, th in sorted(data.sips.items()):
        t, _x, _y, lv, rv, _v = th.columns()
        ax.plot(t, lv, lw=0.8, label=f"left wheel (session {session})")
        ax.plot(t, rv, lw=0.8, label=f"right wheel (session {session})")
    ax.set_ylabel("velocity (mm/s)")
    ax.legend(loc="upper right", fontsize="small")


def _battery(ax, data: RobotPlotData) -> None:
    for session, th in sorted(data.sips.items()):
        t, *_, volts = th.columns()
        ax.plot(t, volts, lw=0.8, label=f"session {session}")
    ax.set_ylabel("battery (V)")


def _timeline(ax, data: RobotPlotData) -> None:
    assert data.bb is not None
    t, row, ok = data.bb.columns() or ([], [], [])
    good = [(a, b) for a, b, c in zip(t, row, ok) if c]
    bad = [(a, b) for a, b, c in zip(t, row, ok) if not c]
    if good:
        ax.scatter(*zip(*good), marker="|", s=60, color="tab:blue")
    if bad:
        ax.scatter(*zip(*bad), marker="|", s=60, color="tab:red", label="bad checksum")
        ax.legend(loc="upper right", fontsize="small")
    ax.set_yticks(range(len(BB_ROWS)), BB_ROWS)
    ax.set_ylim(-0.5, len(BB_ROWS) - 0.5)
    ax.set_title("blackboard messages")
