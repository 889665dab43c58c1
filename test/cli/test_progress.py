"""The demo's live line (dea_ros.cli.progress): in place on a terminal, plain throttled lines otherwise,
nothing when quiet; the texts a person reads during the protocol and the identification."""
import io
import json

from dea_ros.cli.progress import ProgressLine, ProtocolProgress, identification_text, parse_progress


class Tty(io.StringIO):
    def isatty(self):
        return True


def test_a_terminal_gets_one_line_rewritten_in_place():
    out = Tty()
    line = ProgressLine(stream=out)
    line.update("protocol: segment 1/3")
    line.update("protocol: segment 2/3")
    line.end()
    text = out.getvalue()
    assert text.count("\r") == 2 and text.count("\n") == 1 and text.rstrip().endswith("segment 2/3")


def test_a_log_gets_plain_lines_at_most_every_period_and_nothing_when_quiet():
    out = io.StringIO()
    line = ProgressLine(stream=out, plain_period_s=3600.0)
    for k in range(50):
        line.update(f"protocol: segment {k}")
    line.update("identifying: report", force=True)
    assert out.getvalue().splitlines() == ["protocol: segment 0", "identifying: report"]
    assert "\r" not in out.getvalue()
    quiet = io.StringIO()
    ProgressLine(stream=quiet, quiet=True).update("x", force=True)
    assert quiet.getvalue() == ""


def test_protocol_line_from_the_identifier_log():
    status = {"state": "running", "segment": 12, "segments": 25, "elapsed_s": 0.0, "duration_s": 199.7,
              "kind": "sine", "frequency_Hz": 9.5, "amplitude_V": 2500.0}
    log = "[INFO] [1795646000.1] [dea.identifier_node]: progress " + json.dumps(status)
    parsed = parse_progress(log)
    assert parsed == status
    assert parse_progress("[INFO] [1.0] [dea.identifier_node]: segment 3/25: static") is None
    view = ProtocolProgress()
    first = view.text(parsed)
    assert first.startswith("protocol: segment 12/25 sine 9.5 Hz, simulated 0.0/199.7 s")
    view.t_wall0 -= 10.0  # ten wall seconds later, 30 simulated seconds on
    text = view.text({**parsed, "elapsed_s": 30.0})
    assert "x3.00 real time" in text and "ETA 0:56" in text, text
    assert view.text({"state": "waiting"}) == "protocol: waiting"
    # an adaptive protocol: the first fit at 0 V, then the planned pass with its own clock
    assert "first fit" in view.text({"state": "planning"})
    second = view.text({**parsed, "pass": 2, "elapsed_s": 3.0})
    assert second.startswith("protocol (pass 2, planned): segment 12/25") and "x? real time" in second


def test_identification_line_names_stage_evaluations_and_elapsed():
    text = identification_text({"stage": "dynamic", "evaluation": 17, "cost": 1.25e-9}, t_start=0.0)
    assert text.startswith("identifying: dynamic, evaluation 17, cost 1.25e-09, ")
    assert identification_text({"stage": "report"}, t_start=0.0).startswith("identifying: report, ")
