"""Fuzz the dea-ros command line: random and garbage arguments and files, never a traceback.

Every subcommand (its options read from the real parser) gets random values from a pool of
slips: garbage strings, zero, negative, NaN, huge and tiny numbers, and files that are binary,
empty, deeply nested YAML, CSVs with text or kV values, corrupt or truncated bags, folders,
missing paths. The exit code must be 0 or 2 (argparse's usage errors are 2 as well), stderr must
hold no traceback and no "internal error" (the CLI's report of an unexpected exception). A run
that is still going after a few seconds was accepted as valid input and is stopped there.
``rig`` (starts ROS processes) and ``replay`` of a valid bag are left out; ``replay`` gets the
garbage files only.
"""
import argparse
import random
import signal

import pytest

from dea_ros.bag import BagWriter
from dea_ros.cli import build_parser, main

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGALRM"), reason="needs SIGALRM")

SECONDS_PER_RUN = 4
SKIPPED = {("rig",)}


class _Stopped(BaseException):
    """Raised by the alarm: the command accepted its input and was still working."""


def _commands(parser: argparse.ArgumentParser, prefix=()):
    """(path of subcommand names, its parser) for every leaf subcommand."""
    subparsers = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subparsers:
        yield prefix, parser
        return
    for name, sub in subparsers[0].choices.items():
        yield from _commands(sub, prefix + (name,))


@pytest.fixture(scope="module")
def garbage(tmp_path_factory):
    root = tmp_path_factory.mktemp("garbage")
    files = {
        "binary.yaml": bytes(range(256)) * 8,
        "empty.csv": b"",
        "deep.yaml": ("membrane: " + "[" * 600 + "]" * 600 + "\n").encode(),
        "wrong_types.yaml": b"thickness_m: abc\nprestretch: [1, 2]\nmass_kg: -3\n",
        "list.yaml": b"- 1\n- 2\n",
        "text.csv": b"time_s,voltage_V\n0,zero\n1,one\n",
        "kv.csv": b"time_s,voltage_V\n0,0\n1,2.5\n",
        "one_row.csv": b"time_s,voltage_V\n0,2500\n",
        "huge.csv": b"time_s,voltage_V\n0,1e300\n1,1e308\n",
        "no_header.csv": b"1,2\n3,4\n",
    }
    paths = []
    for name, content in files.items():
        (root / name).write_bytes(content)
        paths.append(str(root / name))
    folder = root / "experiments"
    folder.mkdir()
    (folder / "manifest.yaml").write_bytes(b"format: dea_ros.experiments/1\nexperiments:\n- kind: static\n"
                                           b"  file: static.csv\n")
    (folder / "static.csv").write_bytes(b"mass_kg,voltage_V,displacement_m\n0.003,abc,1e-3\n")
    bag = root / "bag"
    with BagWriter(bag, chunk_size_bytes=512, flush_period_s=None) as writer:
        writer.add_topic("/dea/voltage", "std_msgs/msg/Float64")
        for i in range(100):
            writer.write("/dea/voltage", {"data": float(i)}, 1_000_000 + i)
    mcap = bag / "bag_0.mcap"
    data = bytearray(mcap.read_bytes())
    corrupt = root / "corrupt_bag"
    corrupt.mkdir()
    (corrupt / "metadata.yaml").write_bytes((bag / "metadata.yaml").read_bytes())
    data[len(data) // 2] ^= 0x40
    (corrupt / "corrupt_bag_0.mcap").write_bytes(bytes(data))
    truncated = root / "truncated_bag"
    truncated.mkdir()
    (truncated / "truncated_bag_0.mcap").write_bytes(bytes(data[: len(data) // 3]))
    not_mcap = root / "not_a_bag"
    not_mcap.mkdir()
    (not_mcap / "x_0.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(200)))
    paths += [str(folder), str(bag), str(corrupt), str(truncated), str(not_mcap), str(root / "missing" / "x"),
              str(root), "/dev/null"]
    unreadable = paths[:3] + [str(corrupt), str(not_mcap), str(root / "missing" / "x"), str(root)]
    return {"files": paths, "unreadable": unreadable}


def _value(rng: random.Random, action, garbage) -> str:
    numbers = ["0", "-1", "nan", "inf", "-inf", "1e308", "1e-300", "100000", "3", "0.5", "2500", "-0"]
    strings = ["abc", "", "--", "A9", "LP1", "a,b", "1,,2", "../", "\x00", "é" * 3]
    if action.choices is not None and rng.random() < 0.7:
        return str(rng.choice(list(action.choices)))
    if action.type in (int, float) and rng.random() < 0.9:
        pool = [v for v in numbers if action.type is float or v.lstrip("-").isdigit()]
    else:
        pool = rng.choice([strings, garbage["files"], garbage["files"]])
    value = rng.choice(pool)
    return value.replace("\x00", "nul")  # a NUL byte cannot be passed on a real command line


def _random_argv(rng: random.Random, path, parser, garbage):
    argv = list(path)
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if not action.option_strings:  # positional: always given
            if path == ("replay",):  # only unreadable bags: a readable one would really be replayed
                argv.append(rng.choice(garbage["unreadable"]))
            else:
                argv.append(_value(rng, action, garbage))
            continue
        if not action.required and rng.random() < 0.6:
            continue
        option = rng.choice(action.option_strings)
        if action.nargs == 0:
            argv.append(option)
        elif action.nargs in ("+", "*"):
            argv += [option] + [_value(rng, action, garbage) for _ in range(rng.randint(1, 3))]
        else:
            argv += [option, _value(rng, action, garbage)]
    return argv


def _run(argv, capsys):
    def stop(_signum, _frame):
        raise _Stopped()

    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(SECONDS_PER_RUN)
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse usage errors
        code = exc.code
    except _Stopped:
        code = "stopped"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("seed", range(int(__import__("os").environ.get("DEA_FUZZ_SEEDS", "4"))))
def test_random_arguments_and_files_never_give_a_traceback(capsys, garbage, seed, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # whatever a command writes lands here
    rng = random.Random(seed)
    commands = [(path, sub) for path, sub in _commands(build_parser()) if path[:1] not in {p[:1] for p in SKIPPED}]
    assert {path[0] for path, _ in commands} >= {"equilibrium", "simulate", "sweep", "synth", "identify", "bag",
                                                 "replay"}
    failures = []
    reached = 0  # runs that got past argparse into the command itself
    for path, sub in commands:
        for _ in range(4):
            argv = _random_argv(rng, path, sub, garbage)
            code, _out, err = _run(argv, capsys)
            if code not in (0, 2, "stopped", None) or "Traceback" in err or "internal error" in err:
                failures.append((argv, code, err[-500:]))
            reached += "usage:" not in err
    assert failures == []
    assert reached >= len(commands)  # the fuzz exercises the commands, not only argparse
