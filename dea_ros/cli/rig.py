"""``dea-ros rig``: bring up the whole rig on mock hardware where only pip is available.

* ``dea-ros rig up``: mock_hardware_node, amplifier_node (autostarted), model_node and, in real
  time, laser_sensor_node reading the emulated ILD1320 over its pseudo-terminal; until Ctrl-C.
* ``dea-ros rig demo``: the main job. The same rig in simulated time (the mock publishes
  ``/clock`` at up to ``--speed`` times real time, every node runs with ``use_sim_time``; model_node
  only with ``--model-node``), plus identifier_node recording a protocol into a bag. Once the bag is
  closed the rig is shut down (0 V: the amplifier ramps down; ``--keep-rig`` keeps it up, its clock
  paused) and this process identifies: bag -> experiments -> identified parameters -> report. On a
  first run (no completed warm-up in the kernel cache, :mod:`dea_ros.identify.warmup`) the
  identification's numba kernels compile in a background process while the protocol runs.
  One live line follows the protocol (segment, simulated time, speed, ETA) and the identification
  (stage, evaluations, elapsed); plain lines every 10 s when stdout is not a terminal; none with
  ``--quiet``. ``--rosbag2-format humble|jazzy`` picks the bag format (default humble: every distro reads it).
  Ends by printing where the bag, the parameters and the plots are, and the time of each phase.

Each node runs in its own process (``python -m dea_ros.nodes.<node> --ros-args ...``), exactly
as ``ros2 run`` would start it; Ctrl-C stops them in order (the amplifier ramps to 0 V first).
On a lab PC with ROS 2 the launch files in ``launch/`` do the same.
"""
from __future__ import annotations

import collections
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from ..sim import free_udp_port
from .progress import ProgressLine, ProtocolProgress, identification_text, parse_progress
from .rig_check import register as register_check

__all__ = ["register", "RigProcesses", "start_rig", "DEFAULT_START_DELAYS_S"]

#: Lines of each node's output kept to explain an exit (:meth:`RigProcesses.check_alive`).
LAST_LINES_KEPT = 25


def _ros_args(params: dict) -> list[str]:
    out = ["--ros-args"]
    for key, value in params.items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        out += ["-p", f"{key}:={value}"]
    return out


class RigProcesses:
    """Start/stop node processes; their output is prefixed with the node name (or quiet)."""

    def __init__(self, namespace: str = "/dea", quiet: bool = False, log_dir: Path | None = None, on_line=None):
        self.namespace = namespace
        self.quiet = quiet
        self.log_dir = log_dir
        self.on_line = on_line  # on_line(node, line) -> True when it showed the line itself
        self.procs: dict[str, subprocess.Popen] = {}
        self.last_lines: dict[str, collections.deque] = {}   # each node's latest output, for check_alive
        self.pumps: dict[str, threading.Thread] = {}          # each node's output reader
        self.env = dict(os.environ)
        self.env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
        self.env["PYTHONUNBUFFERED"] = "1"

    def start(self, node: str, params: dict) -> subprocess.Popen:
        cmd = [sys.executable, "-m", f"dea_ros.nodes.{node}"] + _ros_args(params) + \
            ["-r", f"__ns:={self.namespace}"]
        proc = subprocess.Popen(cmd, env=self.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
        self.procs[node] = proc
        tail = self.last_lines[node] = collections.deque(maxlen=LAST_LINES_KEPT)
        log = open(self.log_dir / f"{node}.log", "w") if self.log_dir else None  # noqa: SIM115

        def pump():
            for line in proc.stdout:
                tail.append(line.rstrip())
                if log:
                    log.write(line)
                    log.flush()
                if self.on_line is not None and self.on_line(node, line):
                    continue
                if not self.quiet or node == "identifier_node" or "ERROR" in line:
                    print(f"[{node}] {line.rstrip()}", flush=True)
            if log:
                log.close()

        self.pumps[node] = threading.Thread(target=pump, daemon=True)
        self.pumps[node].start()
        return proc

    def stop(self, timeout_s: float = 10.0) -> None:
        """SIGINT in reverse start order (the amplifier ramps to 0 V), then SIGKILL stragglers."""
        for name in reversed(list(self.procs)):
            proc = self.procs[name]
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=timeout_s)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()

    def check_alive(self) -> str | None:
        """``None`` while every node but identifier_node runs; else which exited, its exit code and the
        last lines it printed (its reason, also when ``quiet`` kept them off the screen)."""
        for name, proc in self.procs.items():
            if proc.poll() is not None and name != "identifier_node":
                self.pumps[name].join(timeout=1.0)   # until it has read all the node printed
                lines = list(self.last_lines[name])
                said = ("; its last lines:\n  " + "\n  ".join(lines)) if lines else "; it printed nothing"
                return f"{name} exited with code {proc.returncode}{said}"
        return None


#: ``dea-ros rig demo --command-batch``: commands per voltage_cmd_batch (bench/bench_lockstep.py,
#: docs/benchmarks.md "Issue 22 (session 9)"); amplifier_node's max_command_batch (50) bounds it.
#: 25 by default (x1.9 against one voltage_cmd per update, ``--command-batch 1``). What made it opt-in
#: in session 9 (the identifier started on a backlog of old amplifier outputs, its first batch was refused
#: as stale and the lockstep stalled for good) is fixed in identifier_node: only a current output triggers
#: a command, and a run that hears no output for 1 s commands from its clock again.
DEFAULT_COMMAND_BATCH = 25

#: The mock rig's ``max_ticks_per_clock`` in simulated time: the ticks of one batch of commands per /clock
#: message (amplifier_node runs one update per tick of it; docs/benchmarks.md "Issue 22 (session 16)").
MAX_TICKS_PER_CLOCK = 50

#: When each node of ``dea-ros rig up`` starts, s after the first: the mock first (its emulator and
#: amplifier receiver), the others once it is up.
DEFAULT_START_DELAYS_S = {"mock_hardware_node": 0.0, "amplifier_node": 1.0, "model_node": 1.0,
                          "laser_sensor_node": 1.0}


def start_rig(rig: RigProcesses, membrane: str, sim_time: bool, speed: float, laser_rate_hz: float,
              update_rate_hz: float, true_params: str | None = None, noise_m: float = 1e-6,
              model: bool = True, start_delays_s: dict[str, float] | None = None,
              max_ticks_per_clock: int = MAX_TICKS_PER_CLOCK) -> None:
    """Start the rig's nodes (model_node only with ``model``), each ``start_delays_s[node]`` s after the
    call (default :data:`DEFAULT_START_DELAYS_S`), in the order of their delays: any order must work,
    as on a lab PC where processes start when they start (a sensor that streamed unread meanwhile included).
    ``max_ticks_per_clock``: the mock rig's, in simulated time (1: one /clock message per tick)."""
    port = free_udp_port()
    mock = {"params_file": true_params or membrane, "amplifier_port": port, "noise_m": noise_m,
            "sample_rate_hz": laser_rate_hz}
    link = f"/tmp/dea_ros_mock_laser_{os.getpid()}"
    if sim_time:
        # the clock waits for the identifier's command to reach the amplifier (identifier_node
        # command_trigger applied_voltage: one command per amplifier update, so the amplifier's receipt
        # implies the identifier's tick; its own tick_done would be one more message per tick): every
        # command applied one update later
        mock.update(publish_clock=True, real_time_factor=speed, laser_output="topic", clock_rate_hz=update_rate_hz,
                    lockstep_topics="[amplifier_node/command_received]",
                    pause_when_idle=True, max_ticks_per_clock=max_ticks_per_clock)
    else:
        mock.update(laser_output="emulator", laser_port=link)
    common = {"use_sim_time": sim_time}
    nodes = {
        "mock_hardware_node": mock,
        "amplifier_node": {**common, "params_file": membrane, "backend": "mock", "mock_port": port,
                           "autostart": True, "update_rate_hz": update_rate_hz,
                           "slew_rate_V_per_s": 400000.0, "ramp_down_rate_V_per_s": 20000.0,
                           "watchdog_timeout_s": 0.5},
    }
    if model:
        nodes["model_node"] = {**common, "params_file": membrane, "rate_hz": update_rate_hz}
    if not sim_time:  # plausibility limits from the membrane's model (hardware/laser/plausibility.py)
        nodes["laser_sensor_node"] = {"port": link, "zero_offset_m": 0.002, "measuring_rate_hz": 2000.0,
                                      "params_file": membrane}
    delays = {**DEFAULT_START_DELAYS_S, **(start_delays_s or {})}
    start = time.monotonic()
    for name in sorted(nodes, key=lambda n: delays[n]):
        time.sleep(max(0.0, start + delays[name] - time.monotonic()))
        rig.start(name, nodes[name])


def cmd_rig_up(args) -> int:
    rig = RigProcesses()
    start_rig(rig, args.membrane, sim_time=False, speed=1.0, laser_rate_hz=2000.0, update_rate_hz=1000.0)
    print("rig on mock hardware is up: topics /dea/voltage_cmd, /dea/voltage, /dea/displacement, "
          "/dea/displacement_predicted. Ctrl-C to stop.", flush=True)
    try:
        while True:
            problem = rig.check_alive()
            if problem:
                print(f"dea-ros rig: {problem}", file=sys.stderr)
                return 1
            time.sleep(0.5)
    except KeyboardInterrupt:
        return 0
    finally:
        rig.stop()


def resolve_true_params(value: str, membrane: str) -> str:
    """The simulated membrane: 'same', a path, or a path relative to the package's config/."""
    from ..model.parameters import config_dir

    if value in (None, "", "same"):
        return membrane
    if Path(value).is_file():
        return str(Path(value).resolve())
    candidate = config_dir() / value
    if candidate.is_file():
        return str(candidate)
    raise FileNotFoundError(f"--true-params: no file {value!r} (nor {candidate})")


def _start_kernel_warmup(quiet: bool, log_file: Path):
    """First run (no completed warm-up in the kernel cache): compile the identification's kernels in a
    background process at low priority while the protocol runs; None when they are cached."""
    from ..identify.warmup import kernels_cached, warmup_running

    if kernels_cached():
        return None
    if not quiet:
        what = ("the set-up's compilation of the identification's kernels goes on in the background"
                if warmup_running() else "compiling the identification's kernels in the background")
        print(f"dea-ros rig demo: first run with these kernels: {what} while the protocol runs (cached for "
              "later runs)", flush=True)
    with open(log_file, "w") as log:
        return subprocess.Popen([sys.executable, "-m", "dea_ros.identify.warmup"], stdout=log,
                                stderr=subprocess.STDOUT, preexec_fn=lambda: os.nice(10))


def _run_protocol(args, rig: RigProcesses, out: Path, run_name: str, line) -> int | None:
    """Start the rig and identifier_node (recording only) and wait until the bag is closed. Returns the
    identifier's exit code, or None when a rig process died (reported)."""
    start_rig(rig, args.membrane, sim_time=True, speed=args.speed, laser_rate_hz=args.laser_rate,
              update_rate_hz=args.rate, true_params=args.true_params, noise_m=args.noise, model=args.model_node)
    ident = rig.start("identifier_node", {
        "use_sim_time": True, "protocol": args.protocol, "output_dir": str(out), "run_name": run_name,
        "exit_when_done": True, "command_rate_hz": args.rate, "command_trigger": "applied_voltage",
        "membrane": args.membrane, "identify": False, "rosbag2_format": args.rosbag2_format,
        "progress_period_s": 1.0, "command_batch": args.command_batch,
    })
    while ident.poll() is None:
        problem = rig.check_alive()
        if problem:
            line.print(f"dea-ros rig demo: {problem}; see {out / run_name / 'logs'}")
            ident.send_signal(signal.SIGINT)
            ident.wait(timeout=30)
            return None
        time.sleep(0.2)
    line.end()
    return ident.returncode


def _identify(args, run_dir: Path, summary: dict, warmup, line) -> None:
    """Identification in this process (the rig is down unless --keep-rig), with a live line."""
    from ..identify.from_bag import identify_bag

    t0 = time.monotonic()
    if warmup is not None and warmup.poll() is None:
        while warmup.poll() is None:
            line.update(f"identifying: waiting for the kernels' first compilation, {time.monotonic() - t0:.0f} s")
            time.sleep(0.5)
    summary["phases_s"]["kernel_wait"] = time.monotonic() - t0
    if warmup is not None and warmup.returncode != 0:
        line.print(f"dea-ros rig demo: the kernel warm-up failed (see {run_dir / 'logs' / 'kernel_warmup.log'}); "
                   "the identification compiles them")
    t_fit = time.monotonic()
    try:
        result = identify_bag(Path(summary["bag"]), run_dir, membrane=args.membrane or None,
                              events=lambda e: line.update(identification_text(e, t0)))
    except Exception as exc:  # noqa: BLE001 - report, keep the bag
        summary.update(state="error", error=f"identification failed: {exc}; the bag is kept at {summary['bag']}")
    else:
        summary.update(result)
        summary["identification_wall_time_s"] = time.monotonic() - t_fit
    line.end()


def _print_summary(summary: dict, wall: float, as_json: bool) -> None:
    if as_json:
        print(json.dumps({**summary, "wall_time_s": wall}, indent=2, default=str))
        return
    print()
    phases = ", ".join(f"{name} {seconds:.0f} s" for name, seconds in summary.get("phases_s", {}).items()
                       if name in ("protocol", "identification"))
    print(f"done in {wall:.0f} s (wall clock: {phases}); state: {summary.get('state')}")
    if summary.get("error"):
        print(f"error: {summary['error']}")
    print(f"  bag:        {summary.get('bag')}")
    for key, label in (("params_file", "parameters"), ("report_file", "report"), ("report_dir", "plots")):
        if summary.get(key):
            print(f"  {label + ':':<11} {summary[key]}")
    for text in summary.get("headline", []):
        print(f"  {text}")


def _protocol_lines(line, verbose: bool):
    """The rig's output hook: identifier_node's progress lines drive the live line; other lines are shown
    only with --verbose, warnings and errors always."""
    view = ProtocolProgress()

    def on_line(node: str, text: str) -> bool:
        status = parse_progress(text)
        if status is not None:
            shown = view.text(status)
            if shown:
                line.update(shown)
            return True
        if verbose:
            line.end()
            return False
        if "ERROR" in text or "WARN" in text:
            line.print(f"[{node}] {text.rstrip()}")
        return True
    return on_line


def cmd_rig_demo(args) -> int:
    out = Path(args.out).resolve()
    args.true_params = resolve_true_params(args.true_params, args.membrane)
    run_name = args.run_name or time.strftime("demo_%Y%m%d_%H%M%S")
    run_dir = out / run_name
    (run_dir / "logs").mkdir(parents=True, exist_ok=True)
    # --json: stdout carries the JSON document only; the rig's warnings go to stderr
    line = ProgressLine(stream=sys.stderr if args.json else sys.stdout, quiet=args.quiet or args.json)
    rig = RigProcesses(quiet=True, log_dir=run_dir / "logs", on_line=_protocol_lines(line, args.verbose))
    t_start = time.monotonic()
    if not (args.quiet or args.json):
        print(f"dea-ros rig demo: mock rig simulating {args.true_params}; identification from the nominal "
              f"{args.membrane}; protocol '{args.protocol}', simulated time up to x{args.speed:g}; "
              f"logs in {run_dir / 'logs'}", flush=True)
    warmup_log = run_dir / "logs" / "kernel_warmup.log"
    warmup = None if args.no_identify else _start_kernel_warmup(args.quiet or args.json, warmup_log)
    try:
        code = _run_protocol(args, rig, out, run_name, line)
        t_protocol = time.monotonic() - t_start
        if not args.keep_rig:
            rig.stop()  # 0 V (the amplifier ramps down), every node down before the identification
        summary_file = run_dir / "summary.json"
        if code is None or not summary_file.is_file():
            print(f"dea-ros rig demo: no summary written (identifier exit code {code}); see {run_dir / 'logs'}",
                  file=sys.stderr)
            return 1
        summary = json.loads(summary_file.read_text())
        summary["phases_s"] = {"protocol": t_protocol}  # (timings_s: the identification's own)
        if summary.get("state") == "done" and not args.no_identify:
            t_ident = time.monotonic()
            _identify(args, run_dir, summary, warmup, line)
            summary["phases_s"]["identification"] = time.monotonic() - t_ident
            summary_file.write_text(json.dumps(summary, indent=2, default=str))
    except KeyboardInterrupt:
        line.end()
        print("dea-ros rig demo: interrupted; the bag keeps what was recorded", file=sys.stderr)
        return 130
    finally:
        rig.stop()
        if warmup is not None and warmup.poll() is None:
            warmup.terminate()
    _print_summary(summary, time.monotonic() - t_start, args.json)
    return 0 if summary.get("state") == "done" and not summary.get("error") else 1


def register(subparsers) -> None:
    p = subparsers.add_parser("rig", help="the whole rig on mock hardware (up, demo)")
    sub = p.add_subparsers(dest="rig_command", metavar="ACTION")
    sub.required = True
    up = sub.add_parser("up", help="start the mock rig in real time until Ctrl-C")
    up.add_argument("--membrane", default="A2", help="preset or parameters YAML")
    up.set_defaults(func=cmd_rig_up)
    demo = sub.add_parser("demo", help="main job: protocol on the mock rig -> bag -> identified parameters + plots")
    demo.add_argument("--membrane", default="A2", help="membrane of the rig (preset or YAML; geometry for the fit)")
    demo.add_argument("--true-params", default="rig/mock_membrane.yaml",
                      help="parameters of the simulated membrane: a YAML (relative paths: in the package's "
                           "config/), or 'same' for --membrane (default: rig/mock_membrane.yaml, A2 with "
                           "different material parameters)")
    demo.add_argument("--protocol", default="paper", help="protocol in config/protocols (paper, quick) or a YAML")
    demo.add_argument("--speed", type=float, default=10.0,
                      help="upper bound of simulated seconds per wall-clock second (lockstep may be slower; "
                           "on 2 cores the 'paper' protocol runs at ~x6-8)")
    demo.add_argument("--rate", type=float, default=250.0,
                      help="command/amplifier/clock rate, Hz (simulated; sines are fitted against the applied "
                           "waveform, so its zero-order hold does not bias the fit)")
    demo.add_argument("--laser-rate", type=float, default=500.0, help="displacement sample rate, Hz (simulated)")
    demo.add_argument("--command-batch", type=int, default=DEFAULT_COMMAND_BATCH, metavar="K",
                      help="the protocol is open loop: send the commands of K amplifier updates per message (each "
                           "still applied at its own update through every limit); the lockstep waits on the "
                           "identifier once per K ticks (1: every tick)")
    demo.add_argument("--noise", type=float, default=1e-6, help="laser noise sigma, m")
    demo.add_argument("--out", default="runs", help="folder of the runs")
    demo.add_argument("--run-name", help="folder name of this run (default: demo_<date>)")
    demo.add_argument("--no-identify", action="store_true", help="record only")
    demo.add_argument("--rosbag2-format", choices=("auto", "humble", "jazzy"), default="auto",
                      help="bag format: humble (metadata version 5: Humble and newer read it), jazzy (version 9: "
                           "Jazzy and newer) or auto: humble, which every supported distro reads (default: auto). "
                           "`dea-ros bag convert` changes it later")
    demo.add_argument("--verbose", action="store_true", help="print every node's log")
    demo.add_argument("--model-node", action="store_true",
                      help="run model_node too and record its displacement_predicted (not used by the "
                           "identification; ~20 %% of the lockstep's CPU)")
    demo.add_argument("--quiet", action="store_true", help="no progress line: only the result (and errors)")
    demo.add_argument("--keep-rig", action="store_true",
                      help="keep the rig's nodes up during the identification (default: 0 V, rig shut down, "
                           "then identify)")
    demo.add_argument("--json", action="store_true", help="print the summary as JSON")
    demo.set_defaults(func=cmd_rig_demo)
    register_check(sub)
