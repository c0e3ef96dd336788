"""The GUI panels of one viewer (``client.gui``): status, live plots of the joint angles
(uPlot), the range of motion against AAOS normal values, the repetition count of the
current exercise, and view options. Angles are shown in degrees, time in seconds.

viser's markdown renders raw HTML, so every text a user or a kit controls (the patient's
name in the heading, status lines naming kits, processing errors) goes in as plain text
through ``markdown_text``; only this module writes markdown syntax."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

import numpy as np
from armtrack.estimator.arm.joints import NORMAL_RANGE_DEG, REPORTED_ANGLES
from armtrack.server.reports.words import exercise_words

from .pose import Rom
from .rom import degrees, pretty

#: Seconds of angles in the plot.
PLOT_WINDOW_S = 20.0

#: The plotted angles and their colours.
PLOT_COLOURS = {
    "shoulder_flexion": "#1f77b4", "shoulder_abduction": "#ff7f0e",
    "shoulder_rotation": "#2ca02c", "shoulder_elevation": "#9467bd",
    "elbow_flexion": "#d62728", "forearm_pronation": "#8c564b",
    "wrist_flexion": "#e377c2", "wrist_deviation": "#17becf",
}
ROM_ANGLES = tuple(k for k in REPORTED_ANGLES if k in NORMAL_RANGE_DEG)

#: Outside the normal range by more than this is flagged [deg] (noise stays unflagged).
BEYOND_DEG = 5.0

DISCLAIMER = "*armtrack supports therapy; it is not a diagnostic device.*"

_PUNCTUATION = re.compile(r"""([!"#$%&'()*+,\-./:;<=>?@\[\\\]^_`{|}~])""")
_BREAKS = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]+")


def markdown_text(text: str) -> str:
    """``text`` as markdown that shows exactly that text: every ASCII punctuation character
    backslash-escaped (CommonMark: a literal character, so no tag, entity, emphasis,
    link, code or math can start), line breaks and other control characters as one
    space (no block can start)."""
    return _PUNCTUATION.sub(r"\\\1", _BREAKS.sub(" ", str(text)))


class Panels:
    """The panels; ``gui`` is the viewer's ``client.gui``.

    The viewer is mostly seen embedded in the session page (an iframe of about 640×480 px)
    beside the page's own angles and status, so the control panel is small, floats at
    the top right and starts minimised to its title bar, which names the stream's state
    (live, ``live``) or "Replay controls"; opened, a replay shows its controls first, the
    other folders closed."""

    def __init__(self, gui, heading: str, *, live: bool = True):
        self.gui = gui
        gui.configure_theme(control_width="small", show_logo=False, show_share_button=False,
                            dark_mode=False)
        main = gui.main_panel
        main.float(x=-8, y=8)
        main.minimize()  # its title bar only: the scene stays clear (open it with its +)
        self.set_label("Waiting for the kit" if live else "Replay controls")
        self.heading = markdown_text(heading)
        self.status = gui.add_markdown(f"**{self.heading}**\n\nwaiting for data…\n\n"
                                       f"{DISCLAIMER}")
        self.replay_folder = gui.add_folder("Replay", expand_by_default=True)
        self.replay_folder.visible = False
        with gui.add_folder("Joint angles [deg]", expand_by_default=False):
            series = [{"label": "t [s]"}] + [
                {"label": pretty(k), "stroke": PLOT_COLOURS[k], "width": 1.5}
                for k in PLOT_COLOURS]
            empty = tuple(np.zeros(1) for _ in series)
            self.plot = gui.add_uplot(
                data=empty, series=tuple(series), aspect=1.3,
                scales={"x": {"time": False}, "y": {"auto": True}},
                legend={"show": True, "live": False})
        with gui.add_folder("Range of motion (AAOS normal)", expand_by_default=False):
            self.rom = gui.add_markdown("no movement yet")
        with gui.add_folder("Repetitions", expand_by_default=live):
            self.repetitions = gui.add_markdown("—")
        with gui.add_folder("View", expand_by_default=False):
            self.sensor_frames = gui.add_checkbox("Sensor frames", initial_value=False)
            self.arcs = gui.add_checkbox("Range-of-motion arcs", initial_value=True)

    def set_label(self, text: str) -> None:
        """The panel's title (where viser would say "Connected", which is only its own
        socket's state): the stream's state when live, what the panel holds in a
        replay. Sent when it changes."""
        if text != getattr(self, "label", None):
            self.label = text
            self.gui.set_panel_label(text)

    def show_status(self, lines: list[str]) -> None:
        """Plain-text ``lines`` under the heading (shown as written)."""
        self.status.content = "\n\n".join([f"**{self.heading}**",
                                            *map(markdown_text, lines), DISCLAIMER])

    def show_plot(self, t: np.ndarray, angles_deg: Mapping[str, np.ndarray]) -> None:
        """The angles [deg] at times ``t`` [s] (the last ``PLOT_WINDOW_S``)."""
        if len(t) < 2:
            return
        self.plot.data = (np.asarray(t, float), *(
            np.asarray(angles_deg[k], float) for k in PLOT_COLOURS))

    def show_rom(self, rom: Rom, now_deg: Mapping[str, float]) -> None:
        self.rom.content = rom_table(rom, now_deg)

    def show_repetitions(self, name: str | None, count: int, total: int | None = None) -> None:
        if name is None:
            self.repetitions.content = "no exercise movement yet"
            return
        of = f" of {total}" if total is not None else ""
        self.repetitions.content = f"**{exercise_words(name)}**: {count}{of} repetitions"


def rom_table(rom: Rom, now_deg: Mapping[str, float]) -> str:
    """A markdown table: per angle the current value and the least and greatest so far
    [deg], the AAOS normal range, and the range as a percentage of the normal one (⚠: more
    than ``BEYOND_DEG`` outside the normal range)."""
    rows = ["| angle | now | min | max | normal | % |", "|:--|--:|--:|--:|--:|--:|"]
    for name in ROM_ANGLES:
        lo_n, hi_n = NORMAL_RANGE_DEG[name]
        if name in rom:
            lo, hi = rom[name]
            beyond = lo < lo_n - BEYOND_DEG or hi > hi_n + BEYOND_DEG
            percent = f"{round(100 * (hi - lo) / (hi_n - lo_n))}" + (" ⚠" if beyond else "")
            cells = f"{degrees(lo)} | {degrees(hi)}"
        else:
            percent, cells = "–", "– | –"
        rows.append(f"| {pretty(name)} | {degrees(now_deg.get(name, math.nan))} | {cells} | "
                    f"{round(lo_n)}…{round(hi_n)} | {percent} |")
    return "\n".join(rows)


def exercise_angle(label: str | None, rom: Rom) -> str | None:
    """The angle whose repetitions are counted: the current exercise's, when it is named
    after an angle (``exercise:elbow_flexion``), else the one of largest range so far."""
    if label and label.startswith("exercise:") and label[9:] in ROM_ANGLES:
        return label[9:]
    moved = {k: hi - lo for k, (lo, hi) in rom.items() if k in ROM_ANGLES and hi - lo >= 10}
    return max(moved, key=moved.__getitem__) if moved else None
