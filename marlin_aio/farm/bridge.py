"""The farm's bridge to an MQTT broker: telemetry, state, events and availability per printer, and Home Assistant
discovery, published with aiomqtt.

Topics, for a printer named `NAME` under the prefix `P` (default `marlin`):

- `P/NAME/telemetry`: `{"time": epoch_s, "heaters": {"hotend": {"actual", "target", "power_percent"}, ...}}` at
  the bridge's rate (QoS 0). Heaters a printer does not report are never in it.
- `P/NAME/state` (retained): `{"link": "up" | "down", "firmware", "print", "last_error", "readings_dropped",
  "prompt": {"message", "buttons"} | null, "waiting_for_user"}`, published when it changes.
- `P/NAME/events` (QoS 1): `{"event", "message", "time"}` for connected, connection_lost, connect_failed, halted,
  thermal_runaway, reset, print_started, print_finished, print_cancelled, print_failed, and the firmware's own
  requests: prompt_opened (the message and buttons), prompt_closed, paused_by_printer, resumed_by_printer,
  cancelled_by_printer (with the reason). Never dropped while the queue has room: kept until the broker
  acknowledged them.
- `P/NAME/availability` (retained): `online` while the printer's link is up, else `offline`.
- `P/bridge/availability` (retained): `online`, and `offline` as the bridge's Last Will, so a killed bridge shows,
  and on every clean exit. (`bridge` is therefore not a printer name.)
- `homeassistant/sensor/marlin_NAME/.../config` (retained): Home Assistant discovery.
- `P/NAME/command` and `P/NAME/response`: commands (with `allow_commands`; see `marlin_aio.farm.commands`).

The retained topics are the bridge's: it subscribes to them, and when another client overwrites one (a forged
`online`, a deleted discovery config) it publishes its own again (at most once a second per topic, logged).

Hostile input: a command is parsed under size, depth and character limits (`marlin_aio.farm.commands`); a retained
command is never run (it would run again at every reconnection); every refusal is one answer on the response
topic and one log line, never an exception out of the bridge. A print runs as a task of the farm
(`Farm.start_print`), so however it ends is that printer's event, not the bridge's failure. Sets that other
clients can grow are bounded (the names of other bridges' printers, the commands waiting per printer).

Backpressure: telemetry waits in a bounded buffer per printer and goes out in batches (`telemetry.TelemetryLane`):
the serial loops never wait for the broker. Events wait in a queue of their own (bounded too: past the bound the
oldest is dropped, counted, and logged). When the broker goes away the bridge reconnects with backoff and publishes
availability, state and discovery again.

Secrets: state and events are retained or kept by the broker for any later subscriber, so nothing published or
logged carries a printer's password: each event, state and answer is redacted (`redact`) before it is
queued, whatever the farm and the library already did, since a command's text and an error's message can quote
`M511 P<password>` (typed as G-code, or sent by the handshake).

Over 400 lines because these are one MQTT session's rules, each guarding against the others' failures:
availability with the Last Will, retained-message hygiene and forged-state correction, the bounded queues (answers
apart from events), the commands taken and answered, reconnecting, and redaction. Apart from it: the settings
(`bridgesettings`), the payloads and the telemetry's buffers and batches (`telemetry`), Home Assistant discovery
(`discovery`), the command checks (`commands`), the printers (`supervisor`) and the farm's file (`config`).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any

import aiomqtt

import marlin_aio
from marlin_aio.aio import Backoff
from marlin_aio.service.verbs import FarmOwner, Owner

from .bridgesettings import BridgeSettings, BrokerSettings
from .commands import UNQUEUED_ACTIONS, CommandError, FarmCommand, command_id_of, parse_command, run_command
from .config import NAME_PATTERN
from .discovery import discovery_messages, heater_slug, preset_slugs
from .supervisor import RESERVED_NAMES, Farm, FarmEvent, one_line, redact, redact_payload
from .telemetry import TelemetryLane, compact_json, state_inputs, state_payload

__all__ = ["Bridge", "BridgeSettings", "BrokerSettings", "heater_slug", "preset_slugs"]

_log = logging.getLogger("marlin_temp.bridge")

ANSWER_QUEUE = 1_000
"""Answers to commands kept until published; past it the oldest is dropped (counted): a flood of commands from
outside fills this queue, never the events' one."""
ANSWER_BATCH = 64
"""Answers published between two looks at states, events and telemetry: a flood of answers delays them little."""
FIGHT_LIMIT = 5
"""Corrections of one topic within FIGHT_WINDOW_S after which the bridge stops correcting it (for the session) and
says so: another client that keeps publishing there (a second bridge with a printer of the same name) is not
fought for ever."""
FIGHT_WINDOW_S = 60.0
MAX_OTHER_PRINTERS = 1_024
"""Names of other bridges' printers remembered (from their availability topics); past it the oldest is forgotten."""
MAX_PENDING_COMMANDS = 16
"""Commands accepted and not yet finished, per printer; past it a command is refused (a flood cannot queue more)."""
CORRECTION_GAP_S = 1.0
"""A retained topic someone else overwrote is corrected at most this often (two bridges fighting stay slow)."""


async def _stop(tasks: list[asyncio.Task[None]]) -> None:
    """Cancel `tasks` and wait (bounded) until they have ended."""
    for task in tasks:
        task.cancel()
    _, pending = await asyncio.wait(tasks, timeout=5.0)
    for task in pending:
        _log.error("task %s did not end when cancelled", task.get_name())


def _raise_if_cancelled() -> None:
    """Raise CancelledError if this task was cancelled but the cancellation did not reach it.

    On Python 3.11 `asyncio.wait_for` (which aiomqtt's publish uses) can swallow a cancellation that arrives as the
    awaited publish completes; the task would then wait for the next wake-up forever while its TaskGroup waits for
    it. (Python 3.12 rewrote `wait_for`.)
    """
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError


def _payload_bytes(payload: object) -> bytes:
    """A message's payload as bytes (aiomqtt gives bytes, or str/int/float/None for some)."""
    if isinstance(payload, bytes | bytearray):
        return bytes(payload)
    return b"" if payload is None else str(payload).encode()


class Bridge:
    """Publishes `farm`'s printers to the broker until cancelled. Give `on_event` to the farm as its listener.

    Counters (`published`, `telemetry_dropped`, `events_lost`, `refused`, `corrections`) say what happened to the
    messages.

    Raises:
        ValueError: (when made) a rate that is not positive, or a printer whose name is not one topic level or is
            reserved (`bridge`).
    """

    def __init__(
        self, farm: Farm, broker: BrokerSettings, settings: BridgeSettings | None = None, *, owner: Owner | None = None
    ) -> None:
        settings = settings or BridgeSettings()
        if not settings.rate_hz > 0:
            raise ValueError(f"the telemetry rate must be positive, got {settings.rate_hz}")
        if not NAME_PATTERN.fullmatch(settings.name):
            raise ValueError(f"the bridge's name {settings.name!r} must be letters, digits, '-' and '_'")
        for name in farm.printers:
            if not name or any(c in name for c in "/+#") or name in RESERVED_NAMES | {settings.name}:
                raise ValueError(f"printer name {name!r} cannot be a topic level of the bridge")
        self.farm = farm
        self.broker = broker
        self.settings = settings
        # Whose verbs the commands call: the service the farm belongs to (`marlin-temp farm`), else the farm alone.
        self.owner: Owner = owner if owner is not None else FarmOwner(farm, settings.presets)
        self._wake = asyncio.Event()
        self._telemetry = TelemetryLane(
            {name: self.topic(name, "telemetry") for name in farm.printers},
            settings.rate_hz,
            settings.telemetry_buffer,
            self._wake.set,
            batched=settings.batch_telemetry,
        )
        # Events and command answers: QoS 1, each kept until the broker acknowledged it; apart, so that answers to
        # a flood of commands never push an event (a thermal runaway) out.
        self._events: deque[tuple[str, str]] = deque()
        self._answers: deque[tuple[str, str]] = deque()
        self._group: asyncio.TaskGroup | None = None
        # Printers of other bridges on the same broker, newest last; bounded, since anyone can publish a name.
        self._elsewhere: OrderedDict[str, None] = OrderedDict()
        self._pending: dict[str, int] = dict.fromkeys(farm.printers, 0)
        self._states_dirty = True
        self._discovery_dirty = True
        for farm_printer in farm.printers.values():
            farm_printer.reading_listeners.append(self._listener(farm_printer.name))
        self._states: dict[str, str] = {}
        # What each printer's state was last made of, while it has no print (see `_sample`).
        self._state_inputs: dict[str, tuple[object, ...]] = {}
        self._published_states: dict[str, str] = {}
        self._heaters: dict[str, tuple[str, ...]] = {}
        self._announced: dict[str, tuple[str, ...]] = {}
        # What each of the bridge's retained topics should hold (as last published), to notice an overwrite.
        self._retained: dict[str, bytes] = {}
        self._overwritten: set[str] = set()
        self._corrected_at: dict[str, deque[float]] = {}
        self._given_up: set[str] = set()
        self.connected = False
        """True while a session with the broker is open."""
        self.connections = 0
        """Sessions opened with the broker so far."""
        self.connect_failures = 0
        """Attempts to open a session with the broker that failed (refused, unreachable, TLS or login refused)."""
        self.broker_error: str | None = None
        """Why the last session with the broker ended or could not open (None: none has yet)."""
        self._published = 0  # apart from telemetry, which its lane counts
        self.events_lost = 0
        """Events dropped from a full event queue (the oldest)."""
        self.answers_dropped = 0
        """Answers dropped from a full answer queue (the oldest)."""
        self.refused = 0
        """Commands refused (bad payload, retained, stale, unknown printer, too many waiting)."""
        self.ignored = 0
        """Messages on a command topic no answer was owed for: a name that cannot be a printer's, or a retained
        command for a printer this bridge does not have."""
        self.corrections = 0
        """Retained topics of the bridge's that another client overwrote and the bridge published again."""
        self.on_connected: Callable[[], None] | None = None
        """Called after each (re)connection to the broker, once availability and states are published."""

    # ------------------------------------------------------------------------------------------- topics

    def topic(self, printer: str, leaf: str) -> str:
        """`prefix/printer/leaf`."""
        return self.settings.topic(printer, leaf)

    @property
    def bridge_availability_topic(self) -> str:
        """The bridge's own availability (its Last Will sets it offline)."""
        return self.settings.bridge_availability_topic

    # ------------------------------------------------------------------------------------------- counters

    @property
    def telemetry_path(self) -> tuple[int, int]:
        """(batches written through paho's private queue, messages through its public `publish`): which way the
        telemetry went (`telemetry.TelemetryLane.publish`)."""
        return self._telemetry.batches, self._telemetry.one_by_one

    @property
    def published(self) -> int:
        """Messages handed to the broker."""
        return self._published + self._telemetry.published

    @property
    def telemetry_dropped(self) -> int:
        """Telemetry messages dropped from a full per-printer buffer (the oldest)."""
        return self._telemetry.dropped

    # ------------------------------------------------------------------------------------------- intake

    def on_event(self, event: FarmEvent) -> None:
        """Queue a printer's event for delivery (the farm's listener); past the bound the oldest is lost."""
        payload = {"event": event.kind, "message": one_line(redact(event.message)), "time": round(event.time_s, 3)}
        if len(self._events) >= self.settings.event_queue:
            lost_topic, lost = self._events.popleft()
            self.events_lost += 1
            _log.warning("event queue full (%d): lost %s on %s", self.settings.event_queue, lost, lost_topic)
        self._events.append((self.topic(event.printer, "events"), json.dumps(payload)))
        self._wake.set()

    def _listener(self, name: str) -> Callable[[marlin_aio.TemperatureReading], None]:
        return functools.partial(self._on_reading, name)  # (a lambda would add a Python call to every reading)

    def _on_reading(self, name: str, reading: marlin_aio.TemperatureReading) -> None:
        """A printer's reading, as it is read: into its telemetry lane, and a discovery anew if its heaters changed."""
        payload = self._telemetry.add(name, reading)
        if payload is None:
            return
        heaters = tuple(payload["heaters"])
        if heaters and heaters != self._heaters.get(name):
            self._heaters[name] = heaters
            self._discovery_dirty = True
            self._wake.set()

    def _sample(self) -> None:
        """Note each printer's state; wake the publisher only when one changed (or a correction is due)."""
        changed = False
        for farm_printer in self.farm.printers.values():
            # A state is made (redacted, encoded) only when what it is made of changed: 50 printers sampled ten
            # times a second would otherwise cost 500 of them a second, nearly all equal to the last. A print's
            # progress changes as it goes, so a printer with a print is looked at in full.
            inputs = state_inputs(farm_printer)
            if farm_printer.print_handle is None:
                if self._state_inputs.get(farm_printer.name) == inputs:
                    continue
                self._state_inputs[farm_printer.name] = inputs
            else:
                self._state_inputs.pop(farm_printer.name, None)
            state = compact_json(state_payload(farm_printer)).decode()
            if self._states.get(farm_printer.name) != state:
                self._states[farm_printer.name] = state
                changed = True
        if changed or len(self._published_states) < len(self._states):
            self._states_dirty = True
            self._wake.set()
        if self._overwritten:
            self._wake.set()  # a correction held back by CORRECTION_GAP_S may be due now

    # ------------------------------------------------------------------------------------------- running

    async def run(self) -> None:
        """Sample at the rate and publish whenever connected; reconnect to the broker with backoff. Runs until
        cancelled."""
        async with asyncio.TaskGroup() as group:
            self._group = group  # commands run here: a broker that goes away does not cancel a G28 half-way
            group.create_task(self._sampler(), name="telemetry sampler")
            group.create_task(self._connection_loop(), name="broker connection")

    async def _sampler(self) -> None:
        # States are looked at once a second at least, whatever the telemetry rate: a print's end, a link lost.
        interval = min(1.0 / self.settings.rate_hz, 1.0)
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        while True:
            self._sample()
            next_at += interval
            delay = next_at - loop.time()
            if delay < 0:
                next_at = loop.time()  # behind (a stalled loop): skip, do not catch up
                delay = 0
            await asyncio.sleep(delay)

    async def _connection_loop(self) -> None:
        # The same waits as a printer's reconnect (`marlin_aio.aio.Backoff`), with the bridge's own bounds.
        backoff = Backoff(self.settings.backoff_start_s, self.settings.backoff_max_s)
        while True:
            delay = backoff.start_s  # (set again by the failure that ends the attempt)
            try:
                async with self.broker.client(self.bridge_availability_topic) as client:
                    self.connected = True
                    self.connections += 1
                    backoff.reset()
                    _log.info("connected to the broker at %s", self.broker.address)
                    try:
                        await self._announce(client)
                        if self.on_connected is not None:
                            self.on_connected()
                        # The message stream ends with an MqttError as soon as the broker goes away, even with
                        # nothing subscribed: the session ends then, not at the next publish's timeout. (Two tasks
                        # and asyncio.wait rather than a TaskGroup: on Python 3.11 a TaskGroup whose child fails
                        # while it waits leaves this task marked as cancelling, which would end the reconnect loop.)
                        session = [
                            asyncio.create_task(self._publish_forever(client), name="publisher"),
                            asyncio.create_task(self._listen(client), name="listener"),
                        ]
                        try:
                            done, _ = await asyncio.wait(session, return_when=asyncio.FIRST_COMPLETED)
                        finally:
                            await _stop(session)
                        for task in done:
                            task.result()  # the MqttError that ended the session
                    except aiomqtt.MqttError:
                        raise  # the broker is gone: nobody to say goodbye to
                    except BaseException:
                        # Stopping, or failing: every printer and the bridge offline while the broker still
                        # listens (a clean disconnect does not fire the Last Will).
                        await self._say_goodbye(client)
                        raise
            except aiomqtt.MqttError as exc:
                self.broker_error = str(exc)
                delay = backoff.next_delay()
                if self.connected:
                    _log.warning("lost the broker at %s: %s; reconnecting", self.broker.address, exc)
                else:
                    self.connect_failures += 1
                    _log.warning("cannot reach the broker at %s: %s; retrying in %g s", self.broker.address, exc, delay)
            finally:
                self.connected = False
                self._published_states.clear()  # republished in full on the next connection
                self._announced.clear()
                self._overwritten.clear()
                self._given_up.clear()  # a new session: a fight that ended may be over
            await asyncio.sleep(delay)

    async def _listen(self, client: aiomqtt.Client) -> None:
        """Watch the bridge's own retained topics and, with commands allowed, take commands from
        `PREFIX/+/command`: each is checked here and run in a task of its own. Either way, return only by raising
        when the broker is lost.

        Several bridges may share a broker, each with printers of its own: the retained availability topics say
        which printers exist, so a command for another bridge's printer is left to that bridge, and only a name
        no bridge has is answered with an error.
        """
        prefix = self.settings.prefix
        topics = [(f"{prefix}/+/availability", 1), (f"{prefix}/+/state", 1)]
        if self.settings.discovery:
            discovery = self.settings.discovery_prefix
            topics += [(f"{discovery}/+/marlin_{name}/+/config", 1) for name in self.farm.printers]
        if self.settings.allow_commands:
            topics.append((f"{prefix}/+/command", 1))
        await client.subscribe(topics)
        async for message in client.messages:
            try:
                self._on_message(message.topic.value, _payload_bytes(message.payload), message.retain)
            except Exception:  # a bug here must cost one message, not the bridge
                _log.exception("could not handle a message on %s", one_line(message.topic.value[:200]))

    def _on_message(self, topic: str, payload: bytes, retained: bool) -> None:
        if topic in self._retained:
            # A retained message comes only as a subscription starts, and each session publishes all of the
            # bridge's topics anew: only a live message is someone else writing over them now.
            if not retained and payload != self._retained[topic] and topic not in self._given_up:
                self._overwritten.add(topic)
                self._wake.set()
            return
        # PREFIX/NAME/LEAF, NAME one topic level (as `+` matches it): anything else is no topic of the bridge's.
        name, _, leaf = topic.removeprefix(self.settings.prefix + "/").rpartition("/")
        if not topic.startswith(self.settings.prefix + "/") or "/" in name:
            return
        if leaf == "availability":
            if name in self.farm.printers or name == self.settings.name or not NAME_PATTERN.fullmatch(name):
                return
            self._elsewhere.pop(name, None)
            if payload:  # an empty retained message deletes the topic: that printer is gone
                self._elsewhere[name] = None
                if len(self._elsewhere) > MAX_OTHER_PRINTERS:
                    self._elsewhere.popitem(last=False)
            return
        if leaf != "command" or not self.settings.allow_commands:
            return
        if name not in self.farm.printers and (name in self._elsewhere or retained or not NAME_PATTERN.fullmatch(name)):
            # Another bridge's printer (its bridge answers), a retained command for a printer nobody has (it
            # would be answered at every reconnection), or a name no printer can have (its answer's topic could
            # be longer than MQTT allows): no answer owed, and none that outsiders could multiply.
            self.ignored += 1
            return
        if retained:
            # A retained command would run again at every reconnection of this bridge (and at every restart of
            # the broker); MQTT marks such a message, and it is never taken as a command.
            self._refuse(
                name,
                command_id_of(payload),
                "refused: a retained message is never run as a command (publish commands without the retain flag)",
            )
            return
        try:
            command = parse_command(
                name,
                payload,
                self.farm.printers,
                self.settings.allowed_dir,
                now_s=time.time(),
                max_age_s=self.settings.max_command_age_s,
                presets=self.settings.presets,
            )
        except CommandError as exc:
            # The id as parse_command checked it; a refusal before that (an unknown printer) looks for one.
            self._refuse(name, exc.command_id if exc.command_id is not None else command_id_of(payload), str(exc))
            return
        if command.action not in UNQUEUED_ACTIONS and self._pending[command.printer] >= MAX_PENDING_COMMANDS:
            self._refuse(
                name, command.id, f"busy: {MAX_PENDING_COMMANDS} commands are waiting for this printer; try again"
            )
            return
        assert self._group is not None
        self._pending[command.printer] += 1
        self._group.create_task(self._run(command), name=f"command {command.action} on {command.printer}")

    def _refuse(self, printer: str, command_id: object, error: str) -> None:
        self.refused += 1
        self._answer(printer, command_id, error=error)

    async def _run(self, command: FarmCommand) -> None:
        """Run a checked command and answer it; whatever happens, an answer, never an exception."""
        try:
            # Through the service's table of verbs, as every door: a print started here is the job every client
            # sees, a cancel runs its one cancel script.
            result = await run_command(command, self.owner)
        except (CommandError, ValueError, RuntimeError, OSError, marlin_aio.MarlinError) as exc:
            self._answer(command.printer, command.id, error=str(exc) or type(exc).__name__)
        except Exception as exc:
            _log.exception("command %s on %s failed", command.action, command.printer)
            self._answer(command.printer, command.id, error=f"internal error: {type(exc).__name__}: {exc}")
        else:
            self._answer(command.printer, command.id, result=result)
        finally:
            self._pending[command.printer] -= 1

    def _answer(self, printer: str, command_id: object, *, result: Any = None, error: str | None = None) -> None:
        # The answer goes to every subscriber of the response topic, not only to whoever sent the command: a G-code
        # command's text (and its echo in the reply lines) and an error's message are redacted.
        answer: dict[str, Any] = {"id": command_id, "ok": error is None}
        if error is None:
            answer["result"] = result
        else:
            lines = error.strip().splitlines()
            answer["error"] = one_line(lines[0]) if lines else "failed"  # the first line says what was wrong
        answer = redact_payload(answer)
        if error is not None:
            _log.warning("command for %r refused or failed: %s", printer[:64], answer["error"])
        if len(self._answers) >= ANSWER_QUEUE:
            self._answers.popleft()
            self.answers_dropped += 1
        # default=str: a result is JSON-able by construction; if one ever is not, it is still an answer.
        self._answers.append((self.topic(printer, "response"), json.dumps(answer, default=str)))
        self._wake.set()

    async def _publish_retained(self, client: aiomqtt.Client, topic: str, payload: str) -> None:
        """Publish one of the bridge's retained topics and remember what it holds."""
        self._retained[topic] = payload.encode()
        await client.publish(topic, payload, qos=1, retain=True)
        self._published += 1

    async def _announce(self, client: aiomqtt.Client) -> None:
        await self._publish_retained(client, self.bridge_availability_topic, "online")
        self._sample()
        await self._publish_states(client)

    async def _say_goodbye(self, client: aiomqtt.Client) -> None:
        """Stopping: the bridge and every printer offline, and each printer's state with its link down (retained:
        nobody watches the link once the bridge is gone). The Last Will covers only the bridge's own topic, for
        when the process dies without this."""
        with contextlib.suppress(aiomqtt.MqttError, TimeoutError):
            async with asyncio.timeout(2.0):
                await self._publish_retained(client, self.bridge_availability_topic, "offline")
                for name in self.farm.printers:
                    await self._publish_retained(client, self.topic(name, "availability"), "offline")
                    if name in self._states:
                        state = json.loads(self._states[name]) | {"link": "down"}
                        await self._publish_retained(client, self.topic(name, "state"), json.dumps(state))

    async def _publish_forever(self, client: aiomqtt.Client) -> None:
        self._states_dirty = self._discovery_dirty = True  # a new session publishes both in full
        while True:
            self._wake.clear()
            # Checked only when something changed: a wake per reading must not walk every printer.
            if self._states_dirty:
                self._states_dirty = False
                await self._publish_states(client)
            if self._discovery_dirty:
                self._discovery_dirty = False
                await self._publish_discovery(client)
            if self._overwritten:
                await self._publish_corrections(client)
            while self._events:
                await self._publish_queued(client, self._events)
            for _ in range(min(ANSWER_BATCH, len(self._answers))):
                await self._publish_queued(client, self._answers)
            if self._telemetry.waiting:
                self._telemetry.publish(client)
            _raise_if_cancelled()
            if not self._answers:  # else straight on with the next batch
                await self._wake.wait()

    async def _publish_queued(self, client: aiomqtt.Client, queue: deque[tuple[str, str]]) -> None:
        """Publish the oldest message of `queue` (QoS 1) and take it off only once the broker has it: a broken link
        leaves it queued. One the MQTT client refuses outright (a topic too long) is dropped, with a log line."""
        topic, payload_text = queue[0]
        try:
            await client.publish(topic, payload_text, qos=1)
        except ValueError as exc:
            _log.error("could not publish to %r: %s; dropped", topic[:100], exc)
        else:
            self._published += 1
        queue.popleft()

    async def _publish_corrections(self, client: aiomqtt.Client) -> None:
        """Publish again each retained topic of ours that another client overwrote, unless it was corrected less
        than CORRECTION_GAP_S ago (then the sampler's next wake-up comes back for it)."""
        now = time.monotonic()
        for topic in list(self._overwritten):
            recent = self._corrected_at.setdefault(topic, deque(maxlen=FIGHT_LIMIT))
            if recent and now - recent[-1] < CORRECTION_GAP_S:
                continue
            self._overwritten.discard(topic)
            if len(recent) == FIGHT_LIMIT and now - recent[0] < FIGHT_WINDOW_S:
                self._given_up.add(topic)
                _log.error(
                    "%s: another client keeps publishing there (%d times in %g s); no longer correcting it. Is a "
                    "second bridge using the same printer or bridge name on this broker and prefix?",
                    topic,
                    FIGHT_LIMIT + 1,
                    FIGHT_WINDOW_S,
                )
                continue
            recent.append(now)
            self.corrections += 1
            _log.warning("%s was overwritten by another client: published the bridge's own again", topic)
            await self._publish_retained(client, topic, self._retained[topic].decode())

    async def _publish_states(self, client: aiomqtt.Client) -> None:
        for name, state in list(self._states.items()):
            if self._published_states.get(name) == state:
                continue
            link_up = self.farm.printers[name].link_up
            await self._publish_retained(client, self.topic(name, "state"), state)
            await self._publish_retained(client, self.topic(name, "availability"), "online" if link_up else "offline")
            self._published_states[name] = state

    async def _publish_discovery(self, client: aiomqtt.Client) -> None:
        if not self.settings.discovery:
            return
        for name, heaters in list(self._heaters.items()):
            if self._announced.get(name) == heaters:
                continue
            for topic, config in self.discovery_messages(name, heaters):
                await self._publish_retained(client, topic, json.dumps(config))
            self._announced[name] = heaters

    # ------------------------------------------------------------------------------------------- discovery

    def discovery_messages(self, name: str, heaters: tuple[str, ...]) -> list[tuple[str, dict[str, Any]]]:
        """Home Assistant MQTT discovery for the printer `name` with `heaters` (see `discovery.discovery_messages`)."""
        return discovery_messages(self.settings, self.farm.printers[name], heaters)
