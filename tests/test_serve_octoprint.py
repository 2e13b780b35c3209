"""`marlin-temp serve --octoprint`, driven by third-party OctoPrint clients from PyPI, not by our code:
pyoctoprintapi (the library Home Assistant's OctoPrint integration is built on) and octorest (a slicer-style
upload, select and start), plus a raw multipart upload with `print=true` as PrusaSlicer and OrcaSlicer post it.
"""

from __future__ import annotations

import asyncio
import re
import socket
import sys
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import requests
from conftest import until
from octorest import OctoRest
from octorest_calls import load, run
from pyoctoprintapi import OctoprintClient
from pyoctoprintapi.exceptions import ApiError, PrinterOffline, UnauthorizedException
from test_serve import Served, serving

import marlin_aio
from marlin_aio.service.uploads import UploadError, Uploads, UploadTooLargeError, UploadTypeError, safe_name

KEY = "0123456789abcdef0123456789abcdef"


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.fixture
async def octo(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> AsyncIterator[tuple[Served, str]]:
    port = _free_port()
    monkeypatch.setenv("MARLIN_SERVE_API_KEY", KEY)
    async with serving(
        tmp_path, "--sim", "--sim-speed", "50", "--interval", "0.05", "--octoprint", f"127.0.0.1:{port}"
    ) as served:
        assert any("OctoPrint API on http://127.0.0.1" in line for line in served.lines), served.lines
        yield served, f"http://127.0.0.1:{port}"


def _gcode(lines: int) -> bytes:
    return "".join(f"G1 X{i % 100} F6000\nG4 P5\n" for i in range(lines // 2)).encode()


async def test_home_assistants_client_reads_state_sets_targets_and_controls_a_print(
    octo: tuple[Served, str], tmp_path: Path
) -> None:
    _, url = octo
    port = int(url.rsplit(":", 1)[1])
    async with aiohttp.ClientSession() as session:
        client = OctoprintClient("127.0.0.1", session, port=port)
        with pytest.raises(UnauthorizedException):
            await client.get_printer_info()  # no key, no state
        await _home_assistants_session(client, session, url, KEY)


async def _home_assistants_session(client: OctoprintClient, session: aiohttp.ClientSession, url: str, key: str) -> None:
    """What Home Assistant's integration does with its key: server, printer, targets, then a print (uploaded as a
    slicer does) paused, resumed and cancelled."""
    client.set_api_key(key)
    assert (await client.get_server_info()).version.startswith("1.")
    info = await client.get_printer_info()
    assert info.state.flags.operational and info.state.text == "Operational"
    assert {t.name for t in info.temperatures} == {"tool0", "bed"}
    await client.set_tool_temperature("tool0", 50)
    await client.set_bed_temperature(40)

    async def targets() -> dict[str, float]:
        temps = (await client.get_printer_info()).temperatures
        return {t.name: t.target_temp for t in temps}

    seen: dict[str, float] = {}

    async def poll() -> bool:
        seen.update(await targets())
        return seen == {"tool0": 50.0, "bed": 40.0}

    for _ in range(200):  # bounded: each round asks the service once
        if await poll():
            break
    assert seen == {"tool0": 50.0, "bed": 40.0}

    # A print started by a slicer-style upload, then paused, resumed and cancelled by Home Assistant.
    form = aiohttp.FormData()
    form.add_field("file", _gcode(4000), filename="benchy.gcode", content_type="application/octet-stream")
    form.add_field("print", "true")
    async with session.post(f"{url}/api/files/local", data=form, headers={"X-Api-Key": key}) as response:
        assert response.status == 201, await response.text()
        assert (await response.json())["effectivePrint"] is True
    job = await client.get_job_info()
    assert job.state == "Printing" and job.job.file.name == "benchy.gcode"
    await client.pause_job()
    assert (await client.get_job_info()).state == "Paused"
    assert (await client.get_printer_info()).state.flags.paused
    await client.resume_job()
    assert (await client.get_job_info()).state == "Printing"
    await client.cancel_job()
    job = await client.get_job_info()
    assert job.state == "Operational"
    assert 0 < job.progress.completion < 100


def test_a_slicer_style_client_uploads_selects_and_starts(octo: tuple[Served, str], tmp_path: Path) -> None:
    _, url = octo
    with pytest.raises(RuntimeError):
        OctoRest(url=url, apikey="wrong-key-wrong-key").job_info()  # every route needs the key
    client = OctoRest(url=url, apikey=KEY)
    assert client.version["api"] == "0.1"
    source = tmp_path / "cube.gcode"
    source.write_bytes(_gcode(200))
    uploaded = client.upload(str(source))
    assert uploaded["files"]["local"]["name"] == "cube.gcode"
    client.select("cube.gcode")
    client.start()
    info = client.job_info()
    assert info["job"]["file"]["name"] == "cube.gcode"
    assert info["state"] in ("Printing", "Operational")  # 200 short lines may already be done
    for _ in range(500):  # bounded polling of the job, as a slicer's monitor does
        info = client.job_info()
        if info["state"] == "Operational":
            break
    assert info["progress"]["completion"] == 100.0


async def test_hostile_uploads_are_refused_or_tamed(octo: tuple[Served, str]) -> None:
    served, url = octo
    async with aiohttp.ClientSession(headers={"X-Api-Key": KEY}) as session:

        async def upload(data: bytes, name: str) -> tuple[int, str]:
            form = aiohttp.FormData()
            form.add_field("file", data, filename=name, content_type="application/octet-stream")
            async with session.post(f"{url}/api/files/local", data=form) as response:
                return response.status, await response.text()

        status, text = await upload(b"\x7fELF\x00\x01binary", "payload.gcode")
        assert status == 400 and "not a text G-code file" in text
        status, text = await upload(b"G28\n\xff\xfe\n", "latin.gcode")
        assert status == 400 and "not UTF-8" in text
        status, text = await upload(b"G28\n", "../../../etc/cron.d/evil")
        assert status == 201
        uploads = served.socket.parent / "uploads"
        assert sorted(p.name for p in uploads.iterdir()) == ["evil.gcode"]  # inside the folder, made G-code
        status, _ = await upload(b"G28\n", "evil")
        assert sorted(p.name for p in uploads.iterdir()) == ["evil-2.gcode", "evil.gcode"]  # never over another
        async with session.post(f"{url}/api/job", json={"command": "start"}) as response:
            assert response.status == 409  # nothing selected
        async with session.post(f"{url}/api/files/local/..%2Fapi-key", json={"command": "select"}) as response:
            assert response.status == 404
        async with session.post(f"{url}/api/printer/tool", json={"command": "target", "targets": {"tool0": 900}}) as r:
            assert r.status == 400 and "above the limit" in await r.text()
        async with aiohttp.ClientSession() as anonymous, anonymous.get(f"{url}/api/job") as response:
            assert response.status == 403


def test_uploads_are_bounded_and_safe(tmp_path: Path) -> None:
    uploads = Uploads(tmp_path / "up", max_bytes=100)
    upload_id = uploads.begin()
    uploads.append(upload_id, ["G28", "G1 X1\n"])
    with pytest.raises(UploadError, match="over the limit"):
        uploads.append(upload_id, ["G1 X1"] * 50)
    assert not list((tmp_path / "up").iterdir())  # the part file went with it
    with pytest.raises(UploadError, match="line break inside"):
        uploads.append(uploads.begin(), ["G28\nM112"])
    assert safe_name("..") == "upload.gcode"
    assert safe_name("a b;rm -rf.gco") == "a_b_rm_-rf.gco"
    assert safe_name(".hidden") == "hidden.gcode"


def test_a_copy_keeps_to_the_quota_and_neither_copy_nor_move_overwrites(tmp_path: Path) -> None:
    uploads = Uploads(tmp_path / "up", max_bytes=1000, quota_bytes=250)
    source = uploads.store("part.gcode", b"G1 X1\n" * 20)  # 120 bytes
    copied = uploads.copy(source, "copy.gcode")
    assert copied.read_bytes() == source.read_bytes()
    with pytest.raises(UploadTooLargeError, match="full"):
        uploads.copy(source, "third.gcode")  # 360 bytes would be past the quota of 250
    with pytest.raises(FileExistsError):
        uploads.copy(source, "copy.gcode")
    with pytest.raises(FileExistsError):
        uploads.move(source, "copy.gcode")
    with pytest.raises(UploadTypeError):
        uploads.move(source, "folder")  # no G-code file's name: OctoPrint's "invalid type"
    with pytest.raises(UploadError, match="not a file name"):
        uploads.copy(source, "../outside.gcode")
    moved = uploads.move(source, "renamed.gcode")
    assert not source.exists() and moved.read_bytes() == copied.read_bytes()
    with pytest.raises(FileNotFoundError):
        uploads.move(source, "again.gcode")
    # Nothing else was written: no part file left behind by the refused copy.
    assert sorted(p.name for p in (tmp_path / "up").iterdir()) == ["copy.gcode", "renamed.gcode"]


async def test_the_octoprint_port_in_use_is_one_error_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MARLIN_SERVE_API_KEY", KEY)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        process = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "marlin_temp",
            "serve",
            "--sim",
            "--socket",
            str(tmp_path / "s.sock"),
            "--octoprint",
            str(port),
            stderr=asyncio.subprocess.PIPE,
        )
        _, err = await asyncio.wait_for(process.communicate(), 60)
    assert process.returncode == 2
    lines = [line for line in err.decode().splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and f"127.0.0.1:{port}" in lines[0], err.decode()


async def _marlin_temp(*args: str) -> tuple[int, str]:
    """`marlin-temp ARGS` as the service's owner types it; its exit code and output."""
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "marlin_temp", *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT
    )
    output, _ = await process.communicate()
    assert process.returncode is not None
    return process.returncode, output.decode()


def _token(lines: list[str]) -> str | None:
    for line in lines:
        found = re.search(r"marlin-temp keys approve (\S+)`", line)
        if found:
            return found[1]
    return None


async def _ask_for_key(
    session: aiohttp.ClientSession, octo: tuple[Served, str], app: str, user: str
) -> tuple[OctoprintClient, asyncio.Task[str], str]:
    """pyoctoprintapi's `request_app_key` under way (as Home Assistant calls it), and the token the service said."""
    served, url = octo
    client = OctoprintClient("127.0.0.1", session, port=int(url.rsplit(":", 1)[1]))
    asking = asyncio.create_task(client.request_app_key(app, user, 300))
    await until(lambda: _token(served.lines) is not None, "the service to say that a request waits")
    token = _token(served.lines)
    assert token is not None
    return client, asking, token


async def test_home_assistants_config_flow_gets_a_key_once_the_owner_approves_it(
    octo: tuple[Served, str],
) -> None:
    # Home Assistant's config flow, with its own library (pyoctoprintapi): probe, request, poll until the owner
    # decides, then the key, the discovery info (its device id), the printer and the job.
    served, served_url = octo
    service = f"serve:sim@{served.socket}"
    async with aiohttp.ClientSession() as session:
        client, asking, token = await _ask_for_key(session, octo, "Home Assistant", "homeassistant")
        assert not asking.done()  # nothing is handed out before the owner decides
        code, output = await _marlin_temp("keys", "--port", service)
        assert code == 0 and f"waiting: Home Assistant (user homeassistant): marlin-temp keys approve {token}" in output
        code, output = await _marlin_temp("keys", "approve", token, "--port", service)
        assert code == 0 and "approved" in output, output
        key = await asyncio.wait_for(asking, 60)
        assert len(key) == 32 and key != KEY
        client.set_api_key(key)
        discovery = await client.get_discovery_info()
        assert discovery is not None and discovery.upnp_uuid  # the device's id
        again = (await client.get_discovery_info()).upnp_uuid
        assert again == discovery.upnp_uuid
        webcam = await client.get_webcam_info()
        assert webcam is not None and webcam.enabled is False
        assert (await client.get_printer_info()).state.flags.operational
        assert (await client.get_job_info()).state == "Operational"
        # Then what the integration does with that key: targets, and a print paused, resumed and cancelled.
        await _home_assistants_session(client, session, served_url, key)
        # Listed, and revocable: the API refuses the key from then on.
        code, output = await _marlin_temp("keys", "list", "--port", service)
        assert code == 0 and f"issued: Home Assistant (user homeassistant), key {key[:6]}..." in output
        code, output = await _marlin_temp("keys", "revoke", "home assistant", "--port", service)
        assert code == 0 and "revoked: Home Assistant" in output
        with pytest.raises(UnauthorizedException):
            await client.get_printer_info()


async def test_curas_app_key_request_shows_how_to_approve_and_gets_the_key_once_approved(
    octo: tuple[Served, str],
) -> None:
    # The requests Cura's OctoPrint plugin (DiscoverOctoPrintAction) makes, in its order: probe, request with
    # {"app": "Cura"} (it opens `auth_dialog` in a browser), poll the 201's Location every 500 ms with an empty
    # Content-Type until 200, then GET api/settings with the key (it reads feature, webcam and plugins).
    served, url = octo
    async with aiohttp.ClientSession() as session:
        async with session.get(f"{url}/plugin/appkeys/probe") as response:
            assert response.status == 204
        async with session.post(f"{url}/plugin/appkeys/request", json={"app": "Cura"}) as response:
            assert response.status == 201
            asked = await response.json()
            poll_url = response.headers["Location"]
        token = asked["app_token"]
        assert poll_url == f"{url}/plugin/appkeys/request/{token}"
        async with session.get(asked["auth_dialog"]) as response:
            page = await response.text()
            # The page says how to approve; it decides nothing (the owner's socket does).
            assert response.status == 200 and f"marlin-temp keys approve {token}" in page
        async with session.get(poll_url, headers={"Content-Type": ""}) as response:
            assert response.status == 202
        code, output = await _marlin_temp("keys", "approve", token, "--port", f"serve:sim@{served.socket}")
        assert code == 0, output
        async with session.get(poll_url, headers={"Content-Type": ""}) as response:
            assert response.status == 200
            key = (await response.json())["api_key"]
        async with session.get(poll_url, headers={"Content-Type": ""}) as response:
            assert response.status == 404  # said once
        async with session.get(f"{url}/api/settings", headers={"X-Api-Key": key}) as response:
            assert response.status == 200
            settings = await response.json()
    assert settings["feature"]["sdSupport"] is False and settings["webcam"]["streamUrl"] == ""
    assert list(settings["plugins"]) == ["discovery"]


async def test_curas_monitor_polls_jogs_and_steers_a_print_with_its_own_requests(
    octo: tuple[Served, str], tmp_path: Path
) -> None:
    # Cura's OctoPrint plugin (OctoPrintOutputDevice) once connected: GET version, POST login (passive; a 404 is
    # "anonymous user" to it), GET printerprofiles (axes' speed and inverted), settings; then every 2 s GET printer
    # and job, all with `Content-Type: application/json`, GETs too. Its jog is G91, G0, G90 in one
    # printer/command; its pause and resume are `pause` (a toggle) on the job; it reads the keys it indexes.
    _, url = octo
    headers = {"X-Api-Key": KEY, "Content-Type": "application/json"}
    async with aiohttp.ClientSession(headers=headers) as session:

        async def get(path: str) -> dict[str, Any]:
            async with session.get(f"{url}/api/{path}") as response:
                assert response.status == 200, (path, await response.text())
                answer: dict[str, Any] = await response.json()
                return answer

        async def post(path: str, body: dict[str, Any]) -> int:
            async with session.post(f"{url}/api/{path}", json=body) as response:
                return response.status

        assert "server" in await get("version")
        assert await post("login", {"passive": True}) in (200, 404)
        for profile in (await get("printerprofiles"))["profiles"].values():
            assert all({"speed", "inverted"} <= set(profile["axes"][axis]) for axis in "xyze")
        assert "sdSupport" in (await get("settings"))["feature"]
        printer = await get("printer")
        assert printer["state"]["flags"]["operational"] and "actual" in printer["temperature"]["tool0"]
        assert await post("printer/command", {"commands": ["G91", "G0 X10 Y0 Z0 F6000", "G90"]}) == 204
        form = aiohttp.FormData()
        form.add_field("path", "", content_type="text/plain")
        form.add_field("file", _relative_moves(2000), filename="cura.gcode", content_type="application/octet-stream")
        form.add_field("select", "true", content_type="text/plain")
        form.add_field("print", "true", content_type="text/plain")
        # The upload without the session's Content-Type: Qt sets the form's own.
        async with (
            aiohttp.ClientSession() as upload,
            upload.post(f"{url}/api/files/local", data=form, headers={"X-Api-Key": KEY}) as response,
        ):
            assert response.status == 201
            assert response.headers["Location"].split("api/", 1)[1] == "files/local/cura.gcode"
        job = await get("job")
        assert job["state"] in ("Starting", "Printing") and job["job"]["file"]["name"] == "cura.gcode"
        assert {"printTime", "completion", "printTimeLeft"} <= set(job["progress"])
        assert await post("job", {"command": "pause"}) == 204
        assert (await get("job"))["state"] == "Paused" and (await get("printer"))["state"]["flags"]["paused"]
        assert await post("job", {"command": "pause"}) == 204  # Cura's resume: the toggle
        assert (await get("job"))["state"] == "Printing"
        assert await post("job", {"command": "cancel"}) == 204
        assert (await get("job"))["state"] == "Operational"


async def test_a_denied_or_unknown_request_gets_no_key(octo: tuple[Served, str]) -> None:
    served, url = octo
    service = f"serve:sim@{served.socket}"
    async with aiohttp.ClientSession() as session:
        _, asking, token = await _ask_for_key(session, octo, "Some App", "")
        code, output = await _marlin_temp("keys", "deny", token, "--port", service)
        assert code == 0 and "denied" in output
        with pytest.raises(ApiError):
            await asyncio.wait_for(asking, 60)
        # A token nobody asked for, and one decided already: one clear line, exit 2, nothing issued.
        code, output = await _marlin_temp("keys", "approve", token, "--port", service)
        assert code != 0 and f"no request {token!r} waits for a decision" in output
        assert len(output.strip().splitlines()) == 1
        code, output = await _marlin_temp("keys", "list", "--port", service)
        assert "no app has asked for a key, and none holds one" in output
    # The app-key calls need no key; the key is still needed everywhere else.
    async with aiohttp.ClientSession() as session:
        async with session.get(f"{url}/plugin/appkeys/probe") as response:
            assert response.status == 204
        async with session.get(f"{url}/plugin/appkeys/request/nonsense") as response:
            assert response.status == 404
        async with session.get(f"{url}/api/version", headers={"X-Api-Key": "0" * 32}) as response:
            assert response.status == 403


def test_octorests_file_printer_and_profile_calls_answer_as_octoprint_does(
    octo: tuple[Served, str], tmp_path: Path
) -> None:
    # octorest 0.4's calls that were 404 or 405 (issue 35), each answered with OctoPrint 1.11's shape or status.
    _, url = octo
    client = OctoRest(url=url, apikey=KEY)
    first, second = tmp_path / "first.gcode", tmp_path / "second.gcode"
    first.write_bytes(_gcode(20))
    second.write_bytes(_gcode(20))
    client.upload(str(first))
    client.upload(str(second))
    # After `select`, the job names the file selected (not the previous print's).
    client.select("second.gcode")
    assert client.job_info()["job"]["file"]["name"] == "second.gcode"
    info = client.files_info("local", "first.gcode")
    assert info["name"] == "first.gcode" and info["size"] == first.stat().st_size
    assert info["refs"]["resource"] == f"{url}/api/files/local/first.gcode"  # absolute, as OctoPrint's
    listing = client.files()
    assert {f["name"] for f in listing["files"]} >= {"first.gcode", "second.gcode"}
    assert isinstance(listing["free"], int) and listing["free"] > 0
    client.delete("local/first.gcode")
    with pytest.raises(RuntimeError):
        client.files_info("local", "first.gcode")  # 404 now
    client.gcode("M118 from octorest")  # POST /api/printer/command, one command
    client.gcode("M118 one\nM118 two")  # and a list
    with pytest.raises(RuntimeError):
        client.gcode("M104 S900")  # over the hotend's limit: refused (400), as at every door
    profiles = client.printer_profiles()["profiles"]
    assert profiles["_default"]["name"] and set(profiles["_default"]["axes"]) == {"x", "y", "z", "e"}
    assert client.printer_profile("_default")["id"] == "_default"
    options = client.connection_info()["options"]
    assert all("name" in profile for profile in options["printerProfiles"])


async def test_an_upload_says_where_the_file_is_as_cura_reads_it(octo: tuple[Served, str]) -> None:
    # Cura's `_onUploadFinished` reads the 201's Location and splits it at `api/`.
    _, url = octo
    async with aiohttp.ClientSession() as session:
        form = aiohttp.FormData()
        form.add_field("file", _gcode(20), filename="cura part.gcode", content_type="application/octet-stream")
        async with session.post(f"{url}/api/files/local", data=form, headers={"X-Api-Key": KEY}) as response:
            assert response.status == 201
            location = response.headers["Location"]
            body = await response.json()
    assert location.startswith(f"{url}/api/files/local/")
    assert location.split("api/", 1)[1].startswith("files/local/")
    assert body["files"]["local"]["refs"]["resource"] == location


def test_octorests_temperature_calls_take_exclude_history_and_limit(octo: tuple[Served, str]) -> None:
    _, url = octo
    client = OctoRest(url=url, apikey=KEY)
    assert set(client.printer(exclude=["state"])) == {"temperature"}
    assert set(client.printer(exclude=["temperature", "sd"])) == {"state"}
    full = client.printer(history=True, limit=2)
    history = full["temperature"]["history"]
    assert 1 <= len(history) <= 2  # the service polls every 0.05 s: it has readings already
    assert {"time", "tool0", "bed"} <= set(history[-1]) and set(history[-1]["tool0"]) == {"actual", "target"}
    tools = client.tool(history=True, limit=1)
    assert set(tools) == {"tool0", "history"} and set(tools["history"][0]) == {"time", "tool0"}
    bed = client.bed()
    assert set(bed) == {"bed"} and set(bed["bed"]) == {"actual", "target", "offset"}


def test_octorests_printhead_and_tool_calls_move_home_and_refuse_what_is_out_of_bounds(
    octo: tuple[Served, str],
) -> None:
    _, url = octo
    client = OctoRest(url=url, apikey=KEY)
    client.home(["x", "y"])  # G28 X Y
    client.jog(x=10, y=-5)  # relative G1
    client.jog()  # no axes: nothing to do, as OctoPrint takes it
    client.feedrate(90)  # M220 S90
    client.feedrate(1.1)  # a fraction: 110 %
    client.flowrate(95)  # M221 S95
    client.tool_select("tool0")  # T0
    client.extrude(1)  # cold: the printer's own answer, not an error
    client.tool_target(30)
    refused: list[Callable[[], object]] = [
        lambda: client.jog(x=1e9),  # beyond any printer
        lambda: client.feedrate(5000),
        lambda: client.tool_select("nozzle"),
        lambda: client.tool_target({"tool7x": 30}),
        lambda: client.tool_target(900),  # over the hotend's limit
    ]
    for call in refused:
        with pytest.raises(RuntimeError):
            call()
    assert client.printer()["state"]["flags"]["operational"]


async def test_home_assistants_connect_service_closes_and_reopens_the_port(octo: tuple[Served, str]) -> None:
    # HA's `octoprint.printer_connect` and pyoctoprintapi's disconnect: POST /api/connection.
    served, url = octo
    port = int(url.rsplit(":", 1)[1])
    async with aiohttp.ClientSession() as session:
        client = OctoprintClient("127.0.0.1", session, port=port)
        client.set_api_key(KEY)
        await client.disconnect()
        await until(lambda: any(": disconnected:" in line for line in served.lines), "the port to close")
        with pytest.raises(PrinterOffline):
            await client.get_printer_info()  # 409: offline, as OctoPrint says it
        assert (await client.get_job_info()).state == "Offline"
        async with session.post(
            f"{url}/api/connection", json={"command": "connect", "port": "/dev/other"}, headers={"X-Api-Key": KEY}
        ) as response:
            assert response.status == 400  # not the port this printer is on
        await client.connect()
        await until(lambda: sum(": connected:" in line for line in served.lines) >= 2, "the port to open again")
        assert (await client.get_printer_info()).state.flags.operational


def _relative_moves(count: int) -> bytes:
    """A print whose end position counts the moves that ran: each line moves X by 0.1 mm, relative."""
    return ("G91\n" + "G1 X0.1 F6000\n" * count + "G90\n").encode()


@pytest.mark.parametrize(
    ("slicer", "fields"),
    [
        # PrusaSlicer's and OrcaSlicer's OctoPrint host: the file, then `print` (and an empty `path`).
        ("prusaslicer", {"print": "true", "path": ""}),
        # Cura's OctoPrint plugin with "start print job after uploading": `select` and `print`.
        ("cura", {"select": "true", "print": "true"}),
    ],
)
async def test_a_slicers_upload_and_print_runs_every_line_once(
    octo: tuple[Served, str], slicer: str, fields: dict[str, str]
) -> None:
    served, url = octo
    lines = 300
    async with marlin_aio.connect(f"serve:sim@{served.socket}") as printer:
        start = (await printer.position())["X"]
        async with aiohttp.ClientSession() as session:
            form = aiohttp.FormData()
            form.add_field("file", _relative_moves(lines), filename=f"{slicer}.gcode")
            for name, value in fields.items():
                form.add_field(name, value)
            async with session.post(f"{url}/api/files/local", data=form, headers={"X-Api-Key": KEY}) as response:
                assert response.status == 201, await response.text()
                assert (await response.json())["effectivePrint"] is True
            state = ""
            for _ in range(3000):  # bounded polling of the job, as the slicers' monitors do
                async with session.get(f"{url}/api/job", headers={"X-Api-Key": KEY}) as response:
                    job = await response.json()
                state = job["state"]
                if state == "Operational" and job["progress"]["completion"] == 100.0:
                    break
            assert state == "Operational" and job["job"]["file"]["name"] == f"{slicer}.gcode"
        # Every line ran once: the head is 300 x 0.1 mm further, neither a move more nor a move less.
        assert (await printer.position())["X"] == pytest.approx(start + lines * 0.1, abs=1e-6)


def test_octorests_chamber_custom_system_and_empty_calls_answer_as_octoprint_without_them(
    octo: tuple[Served, str],
) -> None:
    # What OctoPrint 1.11 answers for a printer without a chamber, with no custom controls and no system commands.
    _, url = octo
    client = OctoRest(url=url, apikey=KEY)
    assert client.custom_control_request() == {"controls": []}
    assert client.timelapses() == {"config": {"type": "off"}, "enabled": False, "files": [], "unrendered": []}
    assert client.slicers() == {}
    # octorest raises on each; the statuses, read directly, are OctoPrint's: 409 without a heated chamber, 404 for a
    # system command it does not have.
    with pytest.raises(RuntimeError):
        client.chamber()
    headers = {"X-Api-Key": KEY}
    assert requests.get(f"{url}/api/printer/chamber", headers=headers, timeout=30).status_code == 409
    target: dict[str, str | int] = {"command": "target", "target": 40}
    assert requests.post(f"{url}/api/printer/chamber", json=target, headers=headers, timeout=30).status_code == 409
    # System commands are an administrator's (OctoPrint answers an operator's key 403): the service never restarts
    # or shuts down its machine for a client.
    reboot = f"{url}/api/system/commands/core/reboot"
    assert requests.post(reboot, headers=headers, timeout=30).status_code == 403
    assert requests.get(f"{url}/api/system/commands", headers=headers, timeout=30).status_code == 403


#: What OctoPrint 1.11.8 answered to octorest's calls, and where the service answers otherwise, with why.
OCTOPRINT_RECORD = Path(__file__).parent / "data" / "octorest-octoprint-1.11.8.json"
NOT_AS_OCTOPRINT = {
    # The service has no user accounts: a key is not a user, so there is no own user record to read or change
    # (OctoPrint lets a key read and change its own user's); every other user call is 403 in both.
    "user": (200, 403),
    "user_settings": (200, 403),
    "update_user_settings": (200, 403),
}


def test_every_octorest_call_answers_with_octoprints_status_for_the_same_state(
    octo: tuple[Served, str], tmp_path: Path
) -> None:
    """octorest 0.4's whole public API, call by call (tests/octorest_calls.py: reading, controlling, files, a print
    started, paused, restarted, resumed and cancelled, disconnect and connect), against the statuses a real
    OctoPrint 1.11.8 gave for the same calls from the same state (an operator's key, the printer idle)."""
    _, url = octo
    server, recorded = load(OCTOPRINT_RECORD)
    assert server == "OctoPrint 1.11.8"
    answered = run(url, KEY, tmp_path)
    assert [name for name, _ in answered] == [name for name, _ in recorded]
    pairs = zip(recorded, answered, strict=True)
    differences = {name: (expected, status) for (name, expected), (_, status) in pairs if status != expected}
    assert differences == NOT_AS_OCTOPRINT
