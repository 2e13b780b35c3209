"""`marlin-temp serve --octoprint`, driven by third-party OctoPrint clients from PyPI, not by our code:
pyoctoprintapi (the library Home Assistant's OctoPrint integration is built on) and octorest (a slicer-style
upload, select and start), plus a raw multipart upload with `print=true` as PrusaSlicer and OrcaSlicer post it.
"""

from __future__ import annotations

import asyncio
import socket
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest
from octorest import OctoRest
from pyoctoprintapi import OctoprintClient
from pyoctoprintapi.exceptions import UnauthorizedException
from test_serve import Served, serving

from marlin_aio.service.uploads import UploadError, Uploads, safe_name

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
        client.set_api_key(KEY)
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
        async with session.post(f"{url}/api/files/local", data=form, headers={"X-Api-Key": KEY}) as response:
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
