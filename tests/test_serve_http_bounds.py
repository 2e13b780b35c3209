"""Bounds on the HTTP door of `marlin-temp serve --octoprint`, through a real service process and the simulator:
uploads over the size bound or the folder's quota refused before (or as) they are written, a huge form field
refused without being held, control characters in names refused, malformed requests logged as one short line
with no key in it, the key needed on every route, a refused `print=true` keeping nothing, and a TCP client unable to
print another client's unfinished upload.

The bounds are made small through the service's environment (`$MARLIN_SERVE_UPLOAD_LIMIT_MIB`, `..._QUOTA_MIB`),
so no test sends hundreds of MiB to see one hold.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest
from test_serve import Served, serving

from marlin_aio.protocol import rpc
from marlin_aio.service.uploads import LIMIT_ENV, QUOTA_ENV, UploadError, Uploads, UploadTooLargeError, check_name

KEY = "0123456789abcdef0123456789abcdef"
MIB = 1024 * 1024
BOUNDARY = "bOuNdArY-for-the-test"


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.fixture
async def octo(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> AsyncIterator[tuple[Served, str, Path]]:
    """A service with the OctoPrint API, uploads bounded to 1 MiB each and 2 MiB in all."""
    port = _free_port()
    monkeypatch.setenv("MARLIN_SERVE_API_KEY", KEY)
    monkeypatch.setenv(LIMIT_ENV, "1")
    monkeypatch.setenv(QUOTA_ENV, "2")
    async with serving(
        tmp_path, "--sim", "--sim-speed", "50", "--interval", "0.05", "--octoprint", f"127.0.0.1:{port}"
    ) as served:
        yield served, f"http://127.0.0.1:{port}", served.socket.parent / "uploads"


def _gcode(size: int) -> bytes:
    line = b"G1 X10 Y10 F6000\n"
    return (line * (size // len(line) + 1))[:size]


def _folder_bytes(folder: Path) -> int:
    """All the folder holds, hidden `.part` files included."""
    return sum(path.stat().st_size for path in folder.iterdir()) if folder.is_dir() else 0


def _names(folder: Path) -> list[str]:
    return sorted(path.name for path in folder.iterdir()) if folder.is_dir() else []


def _part(name: str, value: bytes, filename: str | None = None) -> bytes:
    disposition = f'form-data; name="{name}"' + (f'; filename="{filename}"' if filename is not None else "")
    return f"--{BOUNDARY}\r\nContent-Disposition: {disposition}\r\n\r\n".encode() + value + b"\r\n"


def _end() -> bytes:
    return f"--{BOUNDARY}--\r\n".encode()


_FORM = {"Content-Type": f"multipart/form-data; boundary={BOUNDARY}", "X-Api-Key": KEY}


async def _raw_http(port: int, request: bytes) -> bytes:
    """Send `request` as it is and read the answer's status line and headers (the server may go on reading)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request)
        await writer.drain()
        return await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 30)
    finally:
        writer.close()


async def test_every_route_needs_the_key_version_too(octo: tuple[Served, str, Path]) -> None:
    _, url, _ = octo
    async with aiohttp.ClientSession() as session:
        for headers in ({}, {"X-Api-Key": "wrong-key-wrong-key-wrong-key-00"}):
            async with session.get(f"{url}/api/version", headers=headers) as response:
                assert response.status == 403, headers  # a slicer's "test" fails on a wrong key
        async with session.get(f"{url}/api/version", headers={"X-Api-Key": KEY}) as response:
            assert response.status == 200 and (await response.json())["api"] == "0.1"
        async with session.get(f"{url}/api/version", params={"apikey": KEY}) as response:
            assert response.status == 200


async def test_an_upload_longer_than_the_bound_is_refused_before_a_byte_is_written(
    octo: tuple[Served, str, Path],
) -> None:
    _, url, uploads = octo
    port = int(url.rsplit(":", 1)[1])
    head = (
        "POST /api/files/local HTTP/1.1\r\nHost: x\r\n"
        f"X-Api-Key: {KEY}\r\nContent-Type: multipart/form-data; boundary={BOUNDARY}\r\n"
        f"Content-Length: {600 * MIB}\r\n\r\n"
    ).encode()
    # Says 600 MiB, sends a few KiB and waits: the answer must come at once, not after the body.
    answer = await _raw_http(port, head + _part("file", _gcode(4096), filename="big.gcode"))
    assert answer.startswith(b"HTTP/1.1 413"), answer
    assert _folder_bytes(uploads) == 0, _names(uploads)


async def test_a_streamed_upload_growing_past_the_bound_is_refused_and_its_part_removed(
    octo: tuple[Served, str, Path],
) -> None:
    _, url, uploads = octo
    seen: list[int] = []

    async def body() -> AsyncIterator[bytes]:  # no length known: sent chunked, checked as it streams
        yield f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="file"; filename="big.gcode"\r\n\r\n'.encode()
        for _ in range(48):  # 3 MiB, three times the bound
            seen.append(_folder_bytes(uploads))
            yield _gcode(64 * 1024)
        yield b"\r\n" + _end()

    async with (
        aiohttp.ClientSession() as session,
        session.post(f"{url}/api/files/local", data=body(), headers=_FORM) as response,
    ):
        assert response.status == 413
        assert "over the limit of 1 MiB" in await response.text()
    assert max(seen) <= MIB  # never more than the bound on disk, even while streaming
    assert _folder_bytes(uploads) == 0, _names(uploads)  # the partial file is gone


async def test_the_folders_quota_holds_whether_the_length_is_told_or_not(octo: tuple[Served, str, Path]) -> None:
    _, url, uploads = octo
    piece = _gcode(900 * 1024)

    async def told(name: str) -> tuple[int, str]:
        data = _part("file", piece, filename=name) + _end()
        async with session.post(f"{url}/api/files/local", data=data, headers=_FORM) as response:
            return response.status, await response.text()

    async def streamed(name: str) -> tuple[int, str]:
        async def body() -> AsyncIterator[bytes]:
            yield _part("file", piece, filename=name)
            yield _end()

        async with session.post(f"{url}/api/files/local", data=body(), headers=_FORM) as response:
            return response.status, await response.text()

    async with aiohttp.ClientSession() as session:
        assert (await told("a.gcode"))[0] == 201
        assert (await streamed("b.gcode"))[0] == 201  # 1.8 MiB of the 2 MiB quota used
        status, text = await told("c.gcode")
        assert status == 413 and "uploads folder is full" in text, text
        status, text = await streamed("d.gcode")
        assert status == 413 and "uploads folder is full" in text, text
    assert _names(uploads) == ["a.gcode", "b.gcode"]  # nothing of c or d, no .part left


def _reset_peak(pid: int) -> None:
    """Make `pid`'s peak memory (VmHWM) restart from its memory now."""
    Path(f"/proc/{pid}/clear_refs").write_text("5")


def _vm(pid: int, field: str) -> int:
    """A `/proc/PID/status` memory field, in bytes."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no {field} for {pid}")


async def test_a_huge_form_field_is_refused_without_being_held(octo: tuple[Served, str, Path]) -> None:
    served, url, uploads = octo
    pid = served.process.pid
    async with aiohttp.ClientSession() as session:
        # A small upload first: what it loads (aiohttp's multipart code) is not counted as the field's.
        data = _part("select", b"true") + _part("file", _gcode(1000), filename="warm.gcode") + _end()
        async with session.post(f"{url}/api/files/local", data=data, headers=_FORM) as response:
            assert response.status == 201
        _reset_peak(pid)
        before = _vm(pid, "VmHWM")

        async def body() -> AsyncIterator[bytes]:  # chunked: no length to refuse it by, the field's bound must hold
            yield f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="select"\r\n\r\n'.encode()
            for _ in range(50):
                yield b"t" * MIB
            yield b"\r\n" + _part("file", _gcode(1000), filename="x.gcode") + _end()

        async with session.post(f"{url}/api/files/local", data=body(), headers=_FORM) as response:
            assert response.status == 400
            assert "form field 'select' is over" in await response.text()
        peak = _vm(pid, "VmHWM")
    assert peak - before < 20 * MIB, f"the service's peak memory grew by {(peak - before) / MIB:.1f} MiB"
    assert _names(uploads) == ["warm.gcode"]


async def test_a_control_character_in_a_name_is_a_400_never_a_500(octo: tuple[Served, str, Path]) -> None:
    _, url, uploads = octo
    async with aiohttp.ClientSession(headers={"X-Api-Key": KEY}) as session:
        async with session.post(f"{url}/api/files/local/a%00b.gcode", json={"command": "select"}) as response:
            assert response.status == 400 and "control character" in await response.text()
        for filename in ("a%00b.gcode", "line%0Abreak.gcode"):  # percent-encoded, as some clients send names
            data = _part("file", b"G28\n", filename=filename) + _end()
            async with session.post(f"{url}/api/files/local", data=data, headers=_FORM) as response:
                assert response.status == 400 and "control character" in await response.text(), filename
    assert _names(uploads) == []


async def test_malformed_requests_are_one_short_line_each_at_most_and_never_show_the_key(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    port = _free_port()
    monkeypatch.setenv("MARLIN_SERVE_API_KEY", KEY)
    # The service's log shown on its stderr, as an operator's logging set-up would (the library only logs).
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(
        "import logging\nlogging.basicConfig(level=logging.WARNING, format='%(name)s: %(message)s')\n"
    )
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])]))
    garbage = [
        f"GET /api/job HTTP/1.1\r\nX-Api-Key: {KEY}\x01\r\n\r\n".encode(),  # the key in the header it cannot parse
        f"GET /api/job?apikey={KEY}\x01 HTTP/1.1\r\n\r\n".encode(),
        b"POST /api/job HTTP/1.1\r\nContent-Length: abc\r\n\r\n",
        b"POST /api/job HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\nZZZ\r\n",
        b"GET /" + b"a" * 9000 + b" HTTP/1.1\r\n\r\n",
    ]
    async with serving(
        tmp_path, "--sim", "--sim-speed", "50", "--interval", "0.05", "--octoprint", f"127.0.0.1:{port}"
    ) as served:
        first = len(served.lines)
        started = time.monotonic()
        for number in range(200):
            answer = await _raw_http(port, garbage[number % len(garbage)])
            assert answer.startswith(b"HTTP/1.") and b" 400 " in answer.split(b"\r\n", 1)[0], answer
        elapsed_s = time.monotonic() - started
    new = served.lines[first:]  # all of them: the service has ended, its stderr read to the end
    logged = [line for line in new if "OctoPrint API:" in line]
    assert not any(KEY in line or KEY[:16] in line for line in new)
    assert not any("Traceback" in line for line in new)
    assert logged and all(len(line) < 240 for line in logged), [line for line in logged if len(line) >= 240]
    # At most 10 lines a 10 s window, and one line for what each window left out.
    assert len(logged) <= 11 * (elapsed_s // 10 + 2), len(logged)
    assert sum(len(line) + 1 for line in new) < 200 * 200


async def _upload_json(session: aiohttp.ClientSession, url: str, data: bytes) -> tuple[int, str]:
    async with session.post(f"{url}/api/files/local", data=data, headers=_FORM) as response:
        return response.status, await response.text()


async def test_print_true_while_a_print_runs_stores_nothing(octo: tuple[Served, str, Path]) -> None:
    _, url, uploads = octo
    long_print = b"G1 X10 Y10 F6000\nG4 P20\n" * 30_000  # 720 KiB: minutes of printing at the test's speed
    async with aiohttp.ClientSession() as session:
        status, text = await _upload_json(
            session, url, _part("print", b"true") + _part("file", long_print, filename="long.gcode") + _end()
        )
        assert status == 201 and json.loads(text)["effectivePrint"] is True, text
        # The print field first (as slicers send it), then after the file: refused either way, nothing kept.
        for data in (
            _part("print", b"true") + _part("file", b"G28\n", filename="second.gcode") + _end(),
            _part("file", b"G28\n", filename="third.gcode") + _part("print", b"true") + _end(),
        ):
            status, text = await _upload_json(session, url, data)
            assert status == 409 and "already running" in text, text
        async with session.post(
            f"{url}/api/files/local/long.gcode", json={"command": "select", "print": True}, headers={"X-Api-Key": KEY}
        ) as response:
            assert response.status == 409
        async with session.get(f"{url}/api/job", headers={"X-Api-Key": KEY}) as response:
            assert (await response.json())["state"] == "Printing"  # the refusals did not touch the running print
        async with session.post(f"{url}/api/job", json={"command": "cancel"}, headers={"X-Api-Key": KEY}) as response:
            assert response.status == 204
    assert _names(uploads) == ["long.gcode"]


async def test_a_tcp_client_cannot_print_an_unfinished_upload(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    port = _free_port()
    token = "a-token-of-twenty-chars"
    monkeypatch.setenv("MARLIN_SERVE_TOKEN", token)
    async with serving(tmp_path, "--sim", "--sim-speed", "50", "--interval", "0.05", "--tcp", str(port)):
        reader, writer = await asyncio.open_connection("127.0.0.1", port)

        async def call(number: int, method: str, **params: object) -> dict[str, object]:
            writer.write(rpc.encode_message(rpc.request(number, method, params)))
            while True:  # notifications (`alive`, readings) may come first
                answer: dict[str, object] = json.loads(await asyncio.wait_for(reader.readline(), 30))
                if "method" not in answer:
                    assert answer.get("id") == number, answer
                    return answer

        try:
            assert "result" in await call(1, "auth", token=token)
            upload = await call(2, "upload", printer="sim", lines=["G28"])  # begun, not done: a .part
            upload_id = upload["result"]["upload_id"]  # type: ignore[index]
            part = tmp_path / "run" / "uploads" / f".{upload_id}.part"
            assert part.is_file()
            refused = await call(3, "start_print", printer="sim", path=str(part))
            assert "uploaded first" in json.dumps(refused["error"]), refused
            done = await call(4, "upload", printer="sim", upload_id=upload_id, lines=["G1 X1"], done=True)
            finished = done["result"]["path"]  # type: ignore[index]
            started = await call(5, "start_print", printer="sim", path=finished)
            assert "result" in started, started
        finally:
            writer.close()


def test_the_uploads_quota_counts_finished_files_and_uploads_under_way(tmp_path: Path) -> None:
    folder = tmp_path / "up"
    uploads = Uploads(folder, max_bytes=100, quota_bytes=250)
    first = uploads.store("a.gcode", b"G1 X1\n" * 15)  # 90 bytes
    under_way = uploads.begin()
    uploads.append_bytes(under_way, b"G1 X1\n" * 15)  # 90 more, not finished
    assert uploads.used_bytes() == 180
    with pytest.raises(UploadTooLargeError, match="folder is full"):
        uploads.check_room(80)
    with pytest.raises(UploadTooLargeError, match="over the limit"):
        uploads.check_room(101)
    other = uploads.begin()
    with pytest.raises(UploadTooLargeError, match="folder is full"):
        uploads.append_bytes(other, b"G1 X1\n" * 12)
    assert not any(path.name.startswith(f".{other}") for path in folder.iterdir())  # refused: its part is gone
    assert uploads.is_finished(first)
    assert not uploads.is_finished(folder / f".{under_way}.part")
    assert not uploads.is_finished(tmp_path / "a.gcode")  # not in the folder
    assert not uploads.is_finished(folder / "a\0.gcode")
    (folder / "link.gcode").symlink_to(first)
    assert not uploads.is_finished(folder / "link.gcode")
    with pytest.raises(UploadError, match="control character"):
        check_name("evil\x00.gcode")
