"""Every call of octorest 0.4's public API, in one fixed order from one fixed state, with the HTTP status each ends in.

The same sequence runs against a real OctoPrint (to record what it answers) and against `marlin-temp serve
--octoprint` (tests/test_serve_octoprint.py compares the two). The state both start in: the printer connected and
idle, no SD card support, no file uploaded, and a key with the rights of OctoPrint's default "Operator" group
(users), which is what a key of the service is: it may print, control and upload, and may not administer the
server (users, settings, system commands, logs, plugins), which is done on the service's host instead.

To record OctoPrint's answers again (OctoPrint installed elsewhere, its virtual printer enabled, `feature.sdSupport`
off, an operator user with this key; see tests/data/README.md):

    python tests/octorest_calls.py http://127.0.0.1:5000 KEY > tests/data/octorest-octoprint-1.11.8.json
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import requests
from octorest import OctoRest

#: The job states the sequence waits for, as OctoPrint's `/api/job` names them.
_PRINTING = ("Printing",)
_PAUSED = ("Paused",)
_IDLE = ("Operational",)
_OFFLINE = ("Offline", "Closed")
#: How long a wait for a job state may take before the run stops with the state it saw.
_WAIT_S = 60.0


@dataclass
class Recorder:
    """The statuses of one call's HTTP responses, collected by a `requests` response hook."""

    statuses: list[int] = field(default_factory=list)

    def hook(self, response: requests.Response, *args: Any, **kwargs: Any) -> None:
        self.statuses.append(response.status_code)

    def outcome(self) -> int:
        """The first status that is not a success, or else the last one (0: no request was made).

        A redirect that was followed is not an outcome: the answer it led to is.
        """
        for i, status in enumerate(self.statuses):
            if 300 <= status < 400 and i + 1 < len(self.statuses):
                continue
            if not 200 <= status < 300:
                return status
        return self.statuses[-1] if self.statuses else 0


def _wait_for(client: OctoRest, states: tuple[str, ...]) -> int:
    """200 once the job is in one of `states`, 504 if it is not within `_WAIT_S` (the run goes on)."""
    deadline = time.monotonic() + _WAIT_S
    while client.job_info()["state"] not in states:
        if time.monotonic() > deadline:
            return 504
        time.sleep(0.05)  # polling, as the clients do: the wait ends on the state, not on the time
    return 200


def _calls(client: OctoRest, folder: Path) -> list[tuple[str, Callable[[], object]]]:
    """The sequence: (name, call). A name may repeat where the same call is asked in a later state."""
    a, b = folder / "a.gcode", folder / "b.gcode"
    # A print that lasts: 1000 dwells of a second on OctoPrint's virtual printer, 1000 x 20 ms on the simulator at
    # --sim-speed 50; long enough for pause, resume and restart in either, and cancel ends it.
    a.write_text("G28\n" + "G4 P1000\n" * 1000)
    b.write_text("G1 X10 F3000\nG1 X0\n")
    language = folder / "pack.zip"
    language.write_bytes(b"PK\x05\x06" + bytes(18))  # an empty zip
    c = client
    return [
        ("wait_idle", lambda: _wait_for(c, _IDLE)),
        # Reading the server and the printer.
        ("get_version", c.get_version),
        ("connection_info", c.connection_info),
        ("state", c.state),
        ("settings", c.settings),
        ("settings_save", lambda: c.settings({"appearance": {"name": "octorest"}})),
        ("regenerate_apikey", c.regenerate_apikey),
        ("fetch_templates", c.fetch_templates),
        ("printer", c.printer),
        ("printer_exclude", lambda: c.printer(exclude=["sd"])),
        ("printer_history", lambda: c.printer(history=True, limit=2)),
        ("tool", c.tool),
        ("bed", c.bed),
        ("chamber", c.chamber),
        ("sd", c.sd),
        ("sd_init", c.sd_init),
        ("sd_refresh", c.sd_refresh),
        ("sd_release", c.sd_release),
        ("custom_control_request", c.custom_control_request),
        ("printer_profiles", c.printer_profiles),
        ("printer_profile", lambda: c.printer_profile("_default")),
        ("add_printer_profile", lambda: c.add_printer_profile({"profile": {"id": "other", "name": "Other"}})),
        ("update_printer_profile", lambda: c.update_printer_profile("_default", {"profile": {"name": "Renamed"}})),
        ("delete_printer_profile", lambda: c.delete_printer_profile("other")),
        ("system_commands", c.system_commands),
        ("source_system_commands", lambda: c.source_system_commands("core")),
        ("execute_system_command", lambda: c.execute_system_command("core", "restart")),
        ("languages", c.languages),
        ("upload_language", lambda: c.upload_language(str(language))),
        ("delete_language", lambda: c.delete_language("de", "_core")),
        ("timelapses", c.timelapses),
        ("change_timelapse_config", lambda: c.change_timelapse_config("off")),
        ("delete_timelapse", lambda: c.delete_timelapse("none.mp4")),
        ("delete_unrendered_timelapse", lambda: c.delete_unrendered_timelapse("none")),
        ("render_timelapse", lambda: c.render_timelapse("none")),
        ("slicers", c.slicers),
        ("slicer_profiles", lambda: c.slicer_profiles("curalegacy")),
        ("slicer_profile", lambda: c.slicer_profile("curalegacy", "none")),
        ("add_slicer_profile", lambda: c.add_slicer_profile("curalegacy", "mine", {"displayName": "Mine"})),
        ("delete_slicer_profile", lambda: c.delete_slicer_profile("curalegacy", "mine")),
        ("logs", c.logs),
        ("delete_log", lambda: c.delete_log("octoprint.log")),
        ("users", c.users),
        ("user", lambda: c.user("op")),
        ("add_user", lambda: c.add_user("someone", "password1", active=True)),
        ("update_user", lambda: c.update_user("someone", admin=False)),
        ("user_settings", lambda: c.user_settings("op")),
        ("update_user_settings", lambda: c.update_user_settings("op", {"interface": {"language": "en"}})),
        ("reset_user_password", lambda: c.reset_user_password("someone", "password2")),
        ("regenerate_user_apikey", lambda: c.regenerate_user_apikey("someone")),
        ("delete_user_apikey", lambda: c.delete_user_apikey("someone")),
        ("delete_user", lambda: c.delete_user("someone")),
        ("wizard", c.wizard),
        ("finish_wizards", lambda: c.finish_wizards([])),
        ("tmp_session_key", c.tmp_session_key),
        ("verify_tmp_session_key", c.verify_tmp_session_key),
        ("util_test_path", lambda: c.util_test_path(str(folder), "dir", True)),
        ("util_test_url", lambda: c.util_test_url("http://127.0.0.1:9/", "success", "HEAD", "bytes", timeout=1)),
        ("util_test_server", lambda: c.util_test_server("127.0.0.1", 9, "tcp", timeout=1)),
        ("probe_app_keys_workflow_support", c.probe_app_keys_workflow_support),
        ("start_authorization_process", lambda: c.start_authorization_process("octorest")),
        ("poll_auth_request_decision", lambda: c.poll_auth_request_decision(c.start_authorization_process("x"))),
        # Controlling the idle printer.
        ("gcode", lambda: c.gcode("M118 octorest")),
        ("home", lambda: c.home(["x", "y"])),
        ("jog", lambda: c.jog(x=5, y=5)),
        ("feedrate", lambda: c.feedrate(100)),
        ("flowrate", lambda: c.flowrate(100)),
        ("tool_select", lambda: c.tool_select("tool0")),
        ("extrude", lambda: c.extrude(1)),
        ("retract", lambda: c.retract(1)),
        ("tool_target", lambda: c.tool_target(0)),
        ("tool_offset", lambda: c.tool_offset(0)),
        ("bed_target", lambda: c.bed_target(0)),
        ("bed_offset", lambda: c.bed_offset(0)),
        ("chamber_target", lambda: c.chamber_target(0)),
        ("chamber_offset", lambda: c.chamber_offset(0)),
        ("fake_ack", c.fake_ack),
        # Files.
        ("files", c.files),
        ("files_local", lambda: c.files("local")),
        ("upload", lambda: c.upload(str(a))),
        ("upload", lambda: c.upload(str(b))),
        ("files_info", lambda: c.files_info("local", "a.gcode")),
        ("files_info_missing", lambda: c.files_info("local", "none.gcode")),
        ("new_folder", lambda: c.new_folder("sub")),
        ("copy", lambda: c.copy("b.gcode", "b2.gcode")),
        ("copy_over", lambda: c.copy("b.gcode", "b2.gcode")),
        ("move", lambda: c.move("b2.gcode", "b3.gcode")),
        ("move_missing", lambda: c.move("b2.gcode", "b4.gcode")),
        ("copy_to_folder", lambda: c.copy("b.gcode", "sub")),
        ("slice", lambda: c.slice("b.gcode")),
        ("delete", lambda: c.delete("none.gcode")),
        # The job, through its states.
        ("pause_idle", c.pause),
        ("restart_idle", c.restart),
        ("cancel_idle", c.cancel),
        ("select", lambda: c.select("a.gcode")),
        ("job_info", c.job_info),
        ("start", c.start),
        ("wait_printing", lambda: _wait_for(c, _PRINTING)),
        ("start_printing", c.start),
        ("select_printing", lambda: c.select("a.gcode")),
        ("delete_printing", lambda: c.delete("a.gcode")),
        ("jog_printing", lambda: c.jog(x=1)),
        ("pause", c.pause),
        ("wait_paused", lambda: _wait_for(c, _PAUSED)),
        ("restart", c.restart),
        ("wait_printing", lambda: _wait_for(c, _PRINTING)),
        ("toggle", c.toggle),
        ("wait_paused", lambda: _wait_for(c, _PAUSED)),
        ("resume", c.resume),
        ("wait_printing", lambda: _wait_for(c, _PRINTING)),
        ("cancel", c.cancel),
        ("wait_idle", lambda: _wait_for(c, _IDLE)),
        ("delete_file", lambda: c.delete("a.gcode")),
        # The connection last: it ends where it began, connected.
        ("disconnect", c.disconnect),
        ("wait_offline", lambda: _wait_for(c, _OFFLINE)),
        ("printer_offline", c.printer),
        ("job_offline", c.job_info),
        ("connect", c.connect),
        ("wait_idle", lambda: _wait_for(c, _IDLE)),
    ]


def run(url: str, key: str, folder: Path) -> list[tuple[str, int]]:
    """Run the sequence against `url` with `key`; return (call, status) in order. Files are written in `folder`.

    A call's status is the first HTTP status of its requests that is not a success, or else its last one; a
    `wait_` step's is 200 when the job reached the state it waits for, 504 when it did not.
    """
    recorder = Recorder()
    session = requests.Session()
    session.hooks["response"].append(recorder.hook)
    client = OctoRest(url=url, apikey=key, session=session)
    outcomes: list[tuple[str, int]] = []
    for name, call in _calls(client, folder):
        recorder.statuses.clear()
        if name.startswith("wait_"):
            outcomes.append((name, int(call())))  # type: ignore[call-overload]  # a wait's outcome is its status
            continue
        # octorest raises on a refusal (RuntimeError) or on a body it cannot read; the status says which.
        with contextlib.suppress(RuntimeError, requests.RequestException, ValueError, KeyError, TypeError):
            call()
        outcomes.append((name, recorder.outcome()))
    return outcomes


def main(argv: list[str]) -> int:
    """Record the sequence's statuses from a running server as JSON on stdout."""
    import tempfile

    if len(argv) != 3:
        print("usage: python tests/octorest_calls.py URL KEY", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as folder:
        outcomes = run(argv[1], argv[2], Path(folder))
    version = requests.get(f"{argv[1]}/api/version", headers={"X-Api-Key": argv[2]}, timeout=30).json()
    sys.stdout.write(dumps(version["text"], outcomes))
    return 0


def dumps(server: str, outcomes: list[tuple[str, int]]) -> str:
    """The record as JSON, one call a line (a diff of two records reads as the calls that changed)."""
    calls = ",\n".join(f"  {json.dumps([name, status])}" for name, status in outcomes)
    return f'{{"server": {json.dumps(server)}, "calls": [\n{calls}\n]}}\n'


def load(path: Path) -> tuple[str, list[tuple[str, int]]]:
    """A record written by `dumps`: the server that answered, and (call, status) in order."""
    record = json.loads(path.read_text())
    return record["server"], [(name, status) for name, status in record["calls"]]


if __name__ == "__main__":
    sys.exit(main(sys.argv))
