"""One live progress line for long commands (``dea-ros rig demo``): rewritten in place on a terminal,
plain lines (at most one per ``plain_period_s``) when stdout is not a terminal (CI logs), nothing when quiet.

The demo's two phases feed it: :func:`protocol_text` reads identifier_node's ``progress {json}`` log
lines (segment i/N, kind and frequency, simulated time, speed vs real time, ETA) and
:func:`identification_text` the fits' events (stage, evaluations, elapsed).
"""
from __future__ import annotations

import json
import shutil
import sys
import time

__all__ = ["ProgressLine", "ProtocolProgress", "identification_text", "parse_progress"]


class ProgressLine:
    """A line rewritten in place (TTY), or printed as plain lines at most every ``plain_period_s``."""

    def __init__(self, stream=None, quiet: bool = False, plain_period_s: float = 10.0):
        self.stream = stream or sys.stdout
        self.quiet = quiet
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.plain_period_s = plain_period_s
        self.last_plain = -float("inf")
        self.shown = False

    def update(self, text: str, force: bool = False) -> None:
        if self.quiet:
            return
        if self.tty:
            width = max(20, shutil.get_terminal_size((100, 20)).columns - 1)
            self.stream.write("\r" + text[:width].ljust(width))
            self.stream.flush()
            self.shown = True
        elif force or time.monotonic() - self.last_plain >= self.plain_period_s:
            self.last_plain = time.monotonic()
            print(text, file=self.stream, flush=True)

    def print(self, text: str) -> None:
        """A line of its own (a warning, a result) above the live line."""
        self.end()
        print(text, file=self.stream, flush=True)

    def end(self) -> None:
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()
            self.shown = False


def _fmt_s(seconds: float) -> str:
    seconds = max(0.0, seconds)
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


class ProtocolProgress:
    """The protocol's live line from identifier_node's ``progress {json}`` lines: speed is simulated s per
    wall s since the protocol started, the ETA the remaining simulated time at that speed."""

    def __init__(self):
        self.t_wall0: float | None = None
        self.pass_number = 1

    def text(self, status: dict) -> str | None:
        elapsed, total = status.get("elapsed_s"), status.get("duration_s") or 0.0
        if status.get("state") == "planning":
            return "protocol: pass 1 done; 0 V while the first fit runs and plans the second pass"
        if status.get("state") != "running" or elapsed is None:
            return f"protocol: {status.get('state', '?')}"
        now = time.monotonic()
        if self.t_wall0 is None or elapsed <= 0.0 or status.get("pass", 1) != self.pass_number:
            self.t_wall0 = now - 1e-9
            self.pass_number = status.get("pass", 1)
        wall = now - self.t_wall0
        speed = elapsed / wall if wall > 0.5 else float("nan")
        eta = (total - elapsed) / speed if speed and speed == speed and speed > 0 else float("nan")
        what = status.get("kind", "")
        for key, unit in (("frequency_Hz", "Hz"), ("voltage_V", "V"), ("final_V", "V")):
            if key in status:
                what += f" {status[key]:g} {unit}"
                break
        speed_text = f"x{speed:.2f} real time" if speed == speed else "x? real time"
        eta_text = _fmt_s(eta) if eta == eta else "?"
        planned = " (pass 2, planned)" if self.pass_number == 2 else ""
        return (f"protocol{planned}: segment {status.get('segment')}/{status.get('segments')} {what}, simulated "
                f"{elapsed:.1f}/{total:.1f} s, {speed_text}, ETA {eta_text}")


def parse_progress(line: str) -> dict | None:
    """The JSON of an identifier_node ``progress {json}`` log line, or None."""
    at = line.find("]: progress {")
    if at < 0:
        return None
    try:
        return json.loads(line[at + len("]: progress "):])
    except ValueError:
        return None


def identification_text(event: dict, t_start: float) -> str:
    """The identification's live line from a fit event (stage, evaluations, elapsed wall time)."""
    stage = event.get("stage", "?")
    count = event.get("evaluation", event.get("evaluations", event.get("iteration")))
    what = f", evaluation {count}" if count is not None else ""
    cost = event.get("cost")
    cost_text = f", cost {cost:.4g}" if isinstance(cost, (int, float)) else ""
    return f"identifying: {stage}{what}{cost_text}, {time.monotonic() - t_start:.0f} s"
