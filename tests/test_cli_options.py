"""The command line's rough edges (issue 25): `log --duration` counts from the first row, `sim` is a command like the
others, JSON output is asked for the same way everywhere, and the README's commands and defaults are the ones
`--help` shows.

Everything runs through typer's CliRunner against the simulated printer, as a user would type it.
"""

from __future__ import annotations

import asyncio
import csv
import itertools
import json
import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path

from conftest import until
from typer.testing import CliRunner

import marlin_aio
from marlin_aio.simulator import SimulatorConfig, serve_tcp
from marlin_temp.main import app

runner = CliRunner()


def rows_on_disk(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


# ------------------------------------------------------------------------------------------- log --duration


async def test_log_duration_counts_from_the_first_row_not_from_before_the_handshake(tmp_path: Path) -> None:
    # A board that resets when the port is opened (a TCP client always finds it reset) spends its bootloader's 2 s
    # deaf: the handshake takes that long. Counted from before it, 2.5 s of --duration left half a second of rows.
    duration_s, interval_s = 2.5, 0.25
    output = tmp_path / "t.csv"
    async with serve_tcp(SimulatorConfig(boot_delay_s=2.0), time_scale=1.0) as sim:
        args = ["log", "--port", sim.url, "-o", str(output), "--duration", str(duration_s)]
        result = await asyncio.to_thread(runner.invoke, app, [*args, "--interval", str(interval_s)])
    assert result.exit_code == 0, result.output
    rows = rows_on_disk(output)
    epochs = [float(row["epoch_s"]) for row in rows]
    # The last row is at most one interval short of the duration; one more interval of slack for a loaded machine.
    assert epochs[-1] - epochs[0] >= duration_s - 2 * interval_s, epochs
    assert len(rows) >= duration_s / interval_s - 2, epochs


async def test_log_reconnect_goes_on_until_the_duration_counted_from_the_first_row(tmp_path: Path) -> None:
    # A 3 s handshake, then 2.8 s of rows: the link is lost after the first rows, already past 2.8 s from the start.
    # The reconnect must still come, and log until 2.8 s after the first row.
    output = tmp_path / "t.csv"
    args = ["log", "-o", str(output), "--reconnect", "--duration", "2.8", "--interval", "0.1"]

    def sessions() -> list[str]:
        return list(dict.fromkeys(row["session"] for row in rows_on_disk(output))) if output.exists() else []

    async with serve_tcp(SimulatorConfig(boot_delay_s=3.0), time_scale=1.0) as sim:
        port = sim.url.rsplit(":", 1)[1]
        logging = asyncio.create_task(asyncio.to_thread(runner.invoke, app, [*args, "--port", sim.url]))
        await until(lambda: len(rows_on_disk(output)) >= 3 if output.exists() else False, "rows of the first session")
    # The simulator is gone (the log's reconnect attempts are refused meanwhile); then it is back, quick to answer.
    async with serve_tcp(SimulatorConfig(), port=int(port), time_scale=1.0):
        result = await logging
    assert result.exit_code == 0, result.output
    assert "reconnecting in" in result.stderr
    assert len(sessions()) == 2, result.stderr  # the second connection logged too


# ------------------------------------------------------------------------------------ sim, a command like the others


def test_sim_help_is_typer_help_with_every_simulator_option_and_its_default() -> None:
    from marlin_aio.simulator._options import SIMULATOR_OPTIONS, build_parser

    shown = runner.invoke(app, ["sim", "--help"], env={"COLUMNS": "200"})
    assert shown.exit_code == 0, shown.output
    text = " ".join(shown.output.split())
    assert "Usage: marlin-temp sim [OPTIONS]" in text
    # One table, two command lines: every flag of marlin-sim is an option here, with the same help and default.
    listed = build_parser().format_help()
    for option in SIMULATOR_OPTIONS:
        assert f"{option.flag} " in text and option.flag in listed, option.flag
    assert "serial receive buffer (default 128)" in text and "share of oks not sent (default 0)" in text
    assert "--time-scale" not in text  # the older names work, unlisted
    assert "Exit codes: 0 stopped" in text


def test_only_sim_imports_the_simulator() -> None:
    # sim's options come from the simulator's table; the other commands (and the list of them) start without it.
    script = (
        "import sys; from typer.testing import CliRunner; from marlin_temp.main import app; "
        "results = [CliRunner().invoke(app, args) for args in (['--help'], ['ports', '--json'])]; "
        "print([r.exit_code for r in results], 'marlin_aio.simulator' in sys.modules)"
    )
    completed = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert completed.stdout.split() == ["[0,", "0]", "False"], completed.stdout + completed.stderr


def test_every_command_takes_h_for_help() -> None:
    for command in ([], ["watch"], ["log"], ["sim"], ["ports"]):
        short = runner.invoke(app, [*command, "-h"], env={"COLUMNS": "200"})
        assert short.exit_code == 0, (command, short.output)
        assert short.output == runner.invoke(app, [*command, "--help"], env={"COLUMNS": "200"}).output


def test_sim_bad_values_are_one_line_and_exit_2() -> None:
    cases = {
        ("--drop-ok", "2"): "between 0 and 1",
        ("--extruders", "9"): "1-8",
        ("--rx-buffer", "0"): "--rx-buffer must be at least 1",  # the configuration's own check, named by its flag
        ("--seed", "x"): "not a int: 'x'",
        ("--password", "a b"): "password",
    }
    for args, message in cases.items():
        result = runner.invoke(app, ["sim", *args])
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert result.exit_code == 2, (args, result.output)
        assert len(lines) == 1 and message in lines[0] and lines[0].startswith("error:"), (args, result.output)


async def test_sim_serves_with_the_options_given_and_its_older_names_then_stops_on_sigterm() -> None:
    process = await asyncio.create_subprocess_exec(
        *(sys.executable, "-m", "marlin_temp", "sim", "--tcp", "0", "--printers", "2", "--time-scale", "20"),
        *("--no-bed", "--chamber"),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    assert process.stdout is not None
    try:
        async with asyncio.timeout(30):
            urls = [(await process.stdout.readline()).decode().strip() for _ in range(2)]
        assert all(url.startswith("socket://127.0.0.1:") for url in urls), urls
        async with marlin_aio.Printer(urls[1]) as printer:
            heaters = (await printer.read_temperatures()).temperatures.heaters
        assert set(heaters) == {"T", "C"}  # --no-bed and --chamber reached the printer
    finally:
        process.send_signal(signal.SIGTERM)
        async with asyncio.timeout(30):
            _, stderr = await process.communicate()
    assert process.returncode == 0, stderr
    assert b"marlin-temp sim: stopped" in stderr and b"Traceback" not in stderr


def test_marlin_sim_refuses_what_the_configuration_refuses_in_one_line() -> None:
    completed = subprocess.run(
        [sys.executable, "-m", "marlin_aio.simulator", "--rx-buffer", "0"], capture_output=True, text=True, timeout=60
    )
    assert completed.returncode == 2
    assert (
        completed.stderr.strip()
        == "marlin-sim: error: --rx-buffer must be at least 1, got 0 (--help lists the options)"
    )


# ------------------------------------------------------------------------------------------- ports --json


def test_ports_json_is_one_object_listing_every_port() -> None:
    result = runner.invoke(app, ["ports", "--json"])
    assert result.exit_code == 0, result.output
    listed = json.loads(result.output)
    assert [port["device"] for port in listed["ports"]] == [info.device for info in marlin_aio.list_ports()]


def test_a_port_in_json_has_its_usb_ids_and_whether_it_looks_like_a_printer() -> None:
    from marlin_temp.ports.options import port_record

    ch340 = port_record(marlin_aio.PortInfo("/dev/ttyUSB0", "USB Serial", "1a86:7523", "CH340"))
    assert ch340 == {
        "device": "/dev/ttyUSB0",
        "description": "USB Serial",
        "vid": "1a86",
        "pid": "7523",
        "usb_id": "1a86:7523",
        "bridge": "CH340",
        "likely_printer": True,
    }
    onboard = port_record(marlin_aio.PortInfo("/dev/ttyS0", "ttyS0", None, None))
    assert (onboard["vid"], onboard["pid"], onboard["likely_printer"]) == (None, None, False)
    json.dumps(onboard)  # plain JSON values


# ------------------------------------------------------------------------------------------- one way to ask for JSON


def test_log_json_is_format_jsonl(tmp_path: Path) -> None:
    fast = ["--sim", "--sim-speed", "50", "--interval", "0.1", "--duration", "0.5"]
    by_flag, by_format = tmp_path / "flag.jsonl", tmp_path / "format.jsonl"
    assert runner.invoke(app, ["log", *fast, "-o", str(by_flag), "--json"]).exit_code == 0
    assert runner.invoke(app, ["log", *fast, "-o", str(by_format), "--format", "jsonl"]).exit_code == 0
    keys = [
        {tuple(sorted(json.loads(line))) for line in path.read_text().splitlines()} for path in (by_flag, by_format)
    ]
    assert keys[0] == keys[1] and len(keys[0]) == 1  # the same records, one shape
    assert "heaters" in next(iter(keys[0]))


def test_log_json_with_another_format_is_refused_before_anything_is_made(tmp_path: Path) -> None:
    output = tmp_path / "t.csv"
    result = runner.invoke(app, ["log", "--sim", "-o", str(output), "--json", "--format", "csv"])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "--json" in lines[0] and "--format csv" in lines[0], result.output
    assert not output.exists()


def test_every_interval_says_what_it_paces_and_its_default() -> None:
    meanings = {"watch": "M105 polls", "log": "rows", "terminal": "polls", "serve": "M105 polls", "farm": "M105 polls"}
    for command, meaning in meanings.items():
        shown = help_options(command)["--interval"]
        assert meaning in shown, (command, shown)
        assert default_in(shown) is not None, f"marlin-temp {command} --help: --interval states no default: {shown}"


def test_every_duration_says_what_happens_without_it() -> None:
    for command in ("watch", "log", "serve", "farm", "bench"):
        shown = help_options(command)["--duration"]
        assert re.search(r"\b[Dd]efault", shown), f"marlin-temp {command} --help: --duration states no default: {shown}"


# ------------------------------------------------------------------------------------ the README and --help agree

README = Path(__file__).resolve().parent.parent / "README.md"
# Every command the app has, so a new one is checked as soon as it is registered.
COMMANDS = tuple(str(command.name) for command in app.registered_commands)
_help_cache: dict[str, dict[str, str]] = {}


def help_options(command: str) -> dict[str, str]:
    """Each option `marlin-temp COMMAND --help` lists (every name of it, short ones too), with its whole row: names,
    value, help text and the default typer adds."""
    if command not in _help_cache:
        args = [command, "--help"] if command else ["--help"]
        result = runner.invoke(app, args, env={"COLUMNS": "1000"})  # one row per option, nothing wrapped
        assert result.exit_code == 0, (command, result.output)
        rows: list[list[str]] = []  # each option's row, as words
        in_row = False
        for line in result.output.splitlines():
            content = line.strip().strip("│").strip()
            if not line.strip().startswith("│"):
                in_row = False  # a panel's border or the text around: a row never goes on across it
            elif re.match(r"(\*\s+)?-", content):
                rows.append(content.removeprefix("*").split())
                in_row = True
            elif content and in_row:
                rows[-1] += content.split()  # a wrapped row goes on
        listed: dict[str, str] = {}
        for words in rows:
            names = list(itertools.takewhile(lambda word: re.fullmatch(r"--?[\w-]+", word), words))
            listed.update((name, " ".join(words)) for name in names)  # the names column, not the help text
        _help_cache[command] = listed
    return _help_cache[command]


def default_in(help_row: str) -> str | None:
    """The default a help row states: typer's `[default: 1.0]`, or the text's own `default 0.01` / `Default: 250000`."""
    found = re.search(r"\[default: ([^\]]+)\]", help_row) or re.search(r"\b[Dd]efault:? ([\w.]+)", help_row)
    return found.group(1) if found else None


def same_value(readme: str, shown: str) -> bool:
    try:
        return float(readme) == float(shown)
    except ValueError:
        return readme == shown


def readme_commands() -> list[tuple[str, list[str], str]]:
    """(command, its options, the line) for every `marlin-temp COMMAND ...` the README shows: the lines of its code
    blocks and its inline code."""
    text = README.read_text()
    lines: list[str] = []
    for block in re.findall(r"```[^\n]*\n(.*?)```", text, flags=re.S):
        lines += [line.split(" #")[0].strip() for line in block.splitlines()]
    lines += re.findall(r"(?<!`)`(marlin-temp [^`]+)`", text)
    found = []
    for line in lines:
        if not line.startswith("marlin-temp "):
            continue
        words = shlex.split(line)
        command = words[1]
        if command.startswith("-"):
            command = ""  # an option of marlin-temp itself
        found.append((command, [word.split("=")[0] for word in words[2:] if word.startswith("-")], line))
    return found


def readme_defaults() -> list[tuple[str, str, str, str]]:
    """(command, option, default, the words) for every default the README states next to an option: "`--baud`
    (default 250000)", "(`--interval`, default 1 s", "`--interval` (1 s by default)". The command is the one the
    text last named (`marlin-temp log`, or `terminal` alone); "" for the common options, which every command that
    has them must agree with."""
    text = " ".join(README.read_text().split())
    named = r"`(?:marlin-temp )?(" + "|".join(COMMANDS) + r")(?: [^`]*)?`"
    patterns = (
        r"`(--[\w-]+)`[^`().;]{0,20}\(default ([^\s;,)]+)",
        r"\(`(--[\w-]+)`, default ([^\s;,)]+)",
        r"`(--[\w-]+)` \(([\d.]+)(?: \w+)? by default",
    )
    found = []
    for pattern in patterns:
        for match in re.finditer(pattern, text):
            before = text[: match.start()]
            commands = re.findall(named, before)
            last_named = max((m.start() for m in re.finditer(named, before)), default=-1)
            command = "" if before.rfind("Common options:") > last_named or not commands else commands[-1]
            found.append((command, match.group(1), match.group(2), match.group(0)))
    return found


def test_every_option_the_readme_shows_is_in_that_commands_help() -> None:
    shown = readme_commands()
    assert len(shown) > 20  # the parsing found the README's commands
    problems = []
    for command, options, line in shown:
        if command and command not in COMMANDS:
            problems.append(f"README shows `{line}`, but marlin-temp has no command {command!r}")
            continue
        listed = help_options(command)
        problems += [
            f"README shows `{line}`, but `marlin-temp {command} --help` has no {option}"
            for option in options
            if option not in listed
        ]
    assert not problems, "\n".join(problems)


def test_every_default_the_readme_states_is_the_one_help_shows() -> None:
    stated = readme_defaults()
    assert len(stated) >= 4  # the parsing found the README's defaults
    problems = []
    for command, option, value, words in stated:
        # The common options are the printer's: sim's --baud is the simulated wire's, a command of its own.
        commands = [command] if command else [c for c in COMMANDS if c != "sim" and option in help_options(c)]
        if not commands:
            problems.append(f"README says {words!r}, but no command's --help has {option}")
        for name in commands:
            row = help_options(name).get(option)
            if row is None:
                problems.append(f"README says {words!r} (of marlin-temp {name}), but its --help has no {option}")
            elif default_in(row) is None or not same_value(value, default_in(row) or ""):
                problems.append(
                    f"README says {words!r}, but `marlin-temp {name} --help` shows {option} with default "
                    f"{default_in(row)}: {row}"
                )
    assert not problems, "\n".join(problems)


#: Options the README names that no --help lists, and why.
UNLISTED = {
    "--password": "hidden on purpose: the README says `--password VALUE` is refused",
    "--time-scale": "sim's older name of --sim-speed, still taken, not listed",
    "--speed": "sim's older name of --sim-speed, still taken, not listed",
}


def test_every_option_the_readme_names_for_marlin_temp_is_in_some_help() -> None:
    # The prose of the marlin-temp sections names options alone (`--refresh`, `--cool-to`): each must be one that
    # some command (or marlin-temp itself) lists, so a renamed or removed option cannot linger in the README.
    text = README.read_text()
    sections = text[text.index("\n## marlin-temp\n") : text.index("\n## Layout\n")]
    spans = re.findall(r"(?<!`)`([^`\n]+)`", sections)
    named = {
        option
        for span in spans
        if span.startswith(("-", "marlin-temp ", *(f"{command} " for command in COMMANDS)))  # not systemctl's
        for option in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", span)
    }
    assert len(named) > 30, named  # the parsing found them
    listed = set(help_options(""))
    for command in COMMANDS:
        listed |= set(help_options(command))
    missing = sorted(named - listed - UNLISTED.keys())
    assert not missing, f"README.md names {missing}, but no `marlin-temp [COMMAND] --help` lists them"
