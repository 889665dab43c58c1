"""The simulated rig's lockstep: speed vs real time, CPU per tick per process, CPU while idle.

Starts the rig of ``dea-ros rig demo`` (mock_hardware_node, amplifier_node, model_node,
identifier_node, each in its own process as ``ros2 run`` starts them) with a protocol and no
identification, and measures from the identifier's log:

* the protocol's wall time -> speed (simulated s per wall s) and wall time per tick;
* every process's CPU time (user + system, /proc) over the protocol -> CPU ms per tick;
* after the protocol (the identifier exits; the rest of the rig stays up unless the demo's
  shutdown is asked for) every remaining process's CPU over ``--idle-s`` -> % of a core.

``--batch 1,25`` runs identifier_node with ``command_batch`` 1 and 25 in turn (each repeat runs every
value, side by side) and prints the median speed and CPU per tick of each.

Run: python bench/bench_lockstep.py [--protocol paper] [--speed 3] [--idle-s 10] [--repeat 1] [--batch 1,25]
Prints one line per run and the medians (machine and load average included).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import machine  # noqa: E402

from dea_ros.cli.rig import RigProcesses, start_rig  # noqa: E402
from dea_ros.identify.protocols import load_protocol  # noqa: E402
from dea_ros.model import config_dir  # noqa: E402

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU time of a process, s (0 once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def wait_for_line(path: Path, needle: str, timeout_s: float, proc=None) -> float | None:
    """Poll a log file until a line contains ``needle``; the monotonic time it was seen, or None."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if path.is_file() and needle in path.read_text(errors="replace"):
            return time.monotonic()
        if proc is not None and proc.poll() is not None:
            return None
        time.sleep(0.02)
    return None


def run_once(args, run_dir: Path, batch: int = 1) -> dict:
    rig = RigProcesses(namespace=f"/bench{os.getpid()}", quiet=True, log_dir=run_dir)
    protocol = load_protocol(args.protocol)
    sim_s = protocol.schedule(None)[-1].end_s
    truth = str(config_dir() / "rig" / "mock_membrane.yaml")
    load0 = os.getloadavg()
    try:
        start_rig(rig, "A2", sim_time=True, speed=args.speed, laser_rate_hz=args.laser_rate,
                  update_rate_hz=args.rate, true_params=truth, model=args.model_node)  # the demo's rig
        ident = rig.start("identifier_node", {
            "use_sim_time": True, "protocol": args.protocol, "output_dir": str(run_dir), "run_name": "run",
            "exit_when_done": True, "command_rate_hz": args.rate, "command_trigger": "applied_voltage",
            "membrane": "A2", "identify": False, "command_batch": batch})
        log = run_dir / "identifier_node.log"
        t_start = wait_for_line(log, "protocol started", 120.0, ident)
        if t_start is None:
            raise RuntimeError(f"the protocol did not start; see {run_dir}")
        cpu_start = {name: cpu_s(p.pid) for name, p in rig.procs.items()}
        t_end = wait_for_line(log, "protocol complete", 20 * sim_s + 120.0, ident)
        if t_end is None:
            raise RuntimeError(f"the protocol did not complete; see {run_dir}")
        cpu_end = {name: cpu_s(p.pid) for name, p in rig.procs.items()}
        ident.wait(timeout=60)
        time.sleep(1.0)  # the clock pauses (or not) once the identifier is gone
        idle0 = {name: cpu_s(p.pid) for name, p in rig.procs.items() if p.poll() is None}
        time.sleep(args.idle_s)
        idle1 = {name: cpu_s(p.pid) for name, p in rig.procs.items() if p.poll() is None}
    finally:
        rig.stop()
    wall = t_end - t_start
    ticks = sim_s * args.rate
    return {"sim_s": sim_s, "wall_s": wall, "speed": sim_s / wall, "ticks": ticks,
            "wall_ms_per_tick": 1e3 * wall / ticks,
            "cpu_ms_per_tick": {n: 1e3 * (cpu_end[n] - cpu_start[n]) / ticks for n in cpu_start},
            "idle_pct": {n: 100.0 * (idle1[n] - idle0[n]) / args.idle_s for n in idle1 if n in idle0},
            "load": (load0, os.getloadavg()), "batch": batch}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", default="paper")
    ap.add_argument("--speed", type=float, default=3.0)
    ap.add_argument("--rate", type=float, default=250.0)
    ap.add_argument("--laser-rate", type=float, default=500.0)
    ap.add_argument("--idle-s", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--batch", default="1",
                    help="identifier_node command_batch values, comma-separated: each repeat runs them in turn "
                         "(side by side, e.g. 1,25)")
    ap.add_argument("--model-node", action="store_true", help="with model_node (the demo's --model-node)")
    args = ap.parse_args()
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    print(f"machine: {machine()}")
    rows = []
    batches = [int(b) for b in args.batch.split(",")]
    for k, batch in ((k, b) for k in range(args.repeat) for b in batches):
        with tempfile.TemporaryDirectory(prefix="bench_lockstep_") as tmp:
            r = run_once(args, Path(tmp), batch)
        rows.append(r)
        cpu = ", ".join(f"{n.replace('_node', '')} {v:.2f}" for n, v in r["cpu_ms_per_tick"].items())
        idle = ", ".join(f"{n.replace('_node', '')} {v:.1f} %" for n, v in r["idle_pct"].items())
        print(f"run {k + 1}, K = {batch}: {r['sim_s']:.1f} s simulated in {r['wall_s']:.1f} s wall = "
              f"x{r['speed']:.2f}; "
              f"{r['wall_ms_per_tick']:.2f} ms wall per tick; CPU ms per tick: {cpu}; idle CPU: {idle}; "
              f"load {r['load'][0][0]:.1f} -> {r['load'][1][0]:.1f}", flush=True)
    for batch in batches:
        speeds = sorted(r["speed"] for r in rows if r["batch"] == batch)
        cpu = sorted(sum(r["cpu_ms_per_tick"].values()) for r in rows if r["batch"] == batch)
        print(f"K = {batch}: median speed x{speeds[len(speeds) // 2]:.2f} over {len(speeds)} runs "
              f"({', '.join(f'x{v:.2f}' for v in speeds)}); median CPU {cpu[len(cpu) // 2]:.2f} ms per tick (sum)")


if __name__ == "__main__":
    main()
