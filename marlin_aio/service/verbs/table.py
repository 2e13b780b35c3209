"""The table of verbs itself: what a verb is (`Verb`, its `Arg`s, `Access`, `Queue`, the doors), the registry
(`VERBS`, filled by `@verb`), who calls (`Caller`), what verbs need of the service (`Owner`), and `call`, which every
door goes through. The verbs are declared in the modules beside this one (see the package's docstring).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol

from marlin_aio.protocol.rpc import INVALID_PARAMS, METHOD_NOT_FOUND, RpcError

if TYPE_CHECKING:
    from marlin_aio.farm.presets import Preset
    from marlin_aio.farm.supervisor import Farm, FarmPrinter
    from marlin_aio.service.appkeys import AppKeys
    from marlin_aio.service.history import History
    from marlin_aio.service.uploads import Uploads

__all__ = [
    "DOORS",
    "NOT_HTTP",
    "REQUIRED",
    "SOCKETS",
    "SOCKETS_AND_HTTP",
    "VERBS",
    "Access",
    "Arg",
    "Caller",
    "Context",
    "Door",
    "Encoded",
    "FarmOwner",
    "Owner",
    "Queue",
    "Subscriber",
    "Verb",
    "call",
    "heavy_verbs",
    "printer_of",
    "urgent_verbs",
    "verb",
]

Door = Literal["socket", "tcp", "mqtt", "http"]
#: Every door of the service: the owner's Unix socket, TCP (with a token), MQTT commands, the OctoPrint API.
DOORS: frozenset[Door] = frozenset({"socket", "tcp", "mqtt", "http"})
#: The socket's doors (the owner's Unix socket and TCP), for the verbs only a socket client has.
SOCKETS: frozenset[Door] = frozenset({"socket", "tcp"})
#: The socket's doors and the OctoPrint API (which reads the status and the job, and has no MQTT-only verb).
SOCKETS_AND_HTTP: frozenset[Door] = frozenset({"socket", "tcp", "http"})
#: Every door but the OctoPrint API (whose clients send no G-code, presets or prompt answers).
NOT_HTTP: frozenset[Door] = frozenset({"socket", "tcp", "mqtt"})


class Access(Enum):
    """Who may call a verb: anyone the door let in may READ; CONTROL changes the printer (the MQTT door offers
    those only when the bridge takes commands)."""

    READ = "read"
    CONTROL = "control"


class Queue(Enum):
    """How a verb's request is queued at its door."""

    URGENT = "urgent"
    """At once: never refused as busy, never waiting behind the caller's other requests (it stops or steers what
    is under way: an emergency stop, a pause, a cancel, the answer that ends an M600 the queue waits behind)."""
    ORDERED = "ordered"
    """In order with the caller's other requests, within the door's bound of requests under way."""
    HEAVY = "heavy"
    """A big answer (a history: hundreds of kilobytes): one at a time per client, and only once it has read what
    it was answered before, so a client piling them up delays nobody but itself."""


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


#: An argument with no default: a request without it is refused.
REQUIRED: Any = _Required()


@dataclass(frozen=True)
class Arg:
    """One argument of a verb: its name, JSON kind (`str`, `int`, `float` for any number, `bool`, `list` of
    strings), its default (`REQUIRED` for none) and what it means."""

    name: str
    kind: type
    default: Any = None
    doc: str = ""

    def take(self, params: Mapping[str, Any]) -> Any:
        """This argument's value in `params`, checked to be of its kind.

        Raises:
            RpcError: INVALID_PARAMS, naming the argument.
        """
        value = params.get(self.name, self.default)  # a Mapping: `in` and `get` only
        if value is REQUIRED or (value is None and self.default is REQUIRED):
            raise RpcError(INVALID_PARAMS, f"missing parameter {self.name!r}")
        if value is None or value is self.default:
            return value
        kinds: tuple[type, ...] = (int, float) if self.kind is float else (self.kind,)
        # JSON's true is no number, and a list of commands is a list of strings.
        wrong = not isinstance(value, kinds) or (isinstance(value, bool) and self.kind is not bool)
        if wrong or (isinstance(value, list) and not all(isinstance(item, str) for item in value)):
            raise RpcError(INVALID_PARAMS, f"parameter {self.name!r} has the wrong type ({type(value).__name__})")
        return value


class Subscriber(Protocol):
    """What the socket's feeds need of a client: its subscriptions, and how much it missed."""

    subscriptions: dict[str, set[str]]
    dropped: int
    uploads: set[str]
    """Uploads it began and has not finished (dropped if it leaves)."""


@dataclass(frozen=True)
class Caller:
    """Who calls a verb, through which door: a verb's rules (which files it may print, who started a job) read
    this, never the door's own objects."""

    door: Door
    who: str
    """For people and the job's `started_by`: `socket client 3`, `mqtt`, `octoprint`."""
    files: Literal["any", "uploads"] = "any"
    """Which files it may print: any path on this machine (the owner's socket, MQTT's allowed folder, already
    checked by its door) or only what was uploaded (a client on another machine)."""
    subscriber: Subscriber | None = field(default=None, compare=False)
    """The socket client, for the feeds (subscriptions)."""


class Owner(Protocol):
    """What verbs need of the service that owns the printers."""

    farm: Farm
    uploads: Uploads
    histories: dict[str, History]
    presets: tuple[Preset, ...]
    socket_path: Path
    sent_files: dict[Path, str]
    """Files the service made of prints sent as lines (removed when their job ends), with their given names."""
    interrupted_jobs: dict[str, dict[str, object]]
    """By printer: the print an earlier service was running when it was killed or stopped (its own record)."""
    app_keys: AppKeys
    """The OctoPrint API's application keys: requests waiting for the owner's decision, and the keys issued."""

    @property
    def clients(self) -> int:
        """Socket clients connected now."""

    def note(self, printer: str, direction: str, text: str) -> None:
        """Keep a console line and tell the console's subscribers."""

    def tell_progress(self, farm_printer: FarmPrinter) -> None:
        """Tell the progress subscribers of the printer's job now (a change of state shows at once)."""

    def tell_requests(self, farm_printer: FarmPrinter) -> None:
        """Tell the requests subscribers the state of the printer's prompts now."""


class FarmOwner:
    """The owner of a farm that serves no socket (a bridge made on a bare `Farm`): the verbs' state with nobody
    to tell. `marlin-temp farm` gives its bridge the service instead, whose clients hear everything."""

    def __init__(self, farm: Farm, presets: tuple[Preset, ...]) -> None:
        import tempfile

        from marlin_aio.service.appkeys import AppKeys
        from marlin_aio.service.history import History
        from marlin_aio.service.uploads import Uploads

        self.farm = farm
        self.presets = presets
        # Never made unless a verb uploads (none of MQTT's does): the folder is created on first use.
        self.uploads = Uploads(Path(tempfile.gettempdir()) / f"marlin-temp-farm-{id(self)}")
        self.histories = {name: History() for name in farm.printers}
        self.socket_path = Path("(no socket)")
        self.sent_files: dict[Path, str] = {}
        self.interrupted_jobs: dict[str, dict[str, object]] = {}
        self.app_keys = AppKeys(None)  # no HTTP door here: nobody asks

    @property
    def clients(self) -> int:
        """None: it has no socket."""
        return 0

    def note(self, printer: str, direction: str, text: str) -> None:
        """Nobody to tell."""

    def tell_progress(self, farm_printer: FarmPrinter) -> None:
        """Nobody to tell."""

    def tell_requests(self, farm_printer: FarmPrinter) -> None:
        """Nobody to tell."""


Handler = Callable[["Context", dict[str, Any]], Awaitable[object]]


@dataclass(frozen=True)
class Verb:
    """One remote method of the service."""

    name: str
    handler: Handler
    args: tuple[Arg, ...]
    access: Access
    queue: Queue
    doors: frozenset[Door]
    result: str
    """What it returns, for people (the table in the README and `--help` come from here)."""
    doc: str
    on_printer: bool = True
    """It acts on one printer: takes `printer` (a name; optional when the service has one)."""


@dataclass(frozen=True)
class Context:
    """One call of a verb: the service, who calls, and the printer it names (if it acts on one)."""

    owner: Owner
    caller: Caller
    printer: FarmPrinter | None

    @property
    def farm_printer(self) -> FarmPrinter:
        """The printer the call names."""
        assert self.printer is not None, "a verb on a printer gets one"
        return self.printer


#: Every verb, by name, in the order they were declared.
VERBS: dict[str, Verb] = {}


def verb(
    name: str,
    *args: Arg,
    access: Access,
    queue: Queue = Queue.ORDERED,
    doors: frozenset[Door] = DOORS,
    result: str,
    on_printer: bool = True,
) -> Callable[[Handler], Handler]:
    """Declare the decorated handler as the verb `name` in `VERBS` (its docstring is the verb's doc)."""

    def register(handler: Handler) -> Handler:
        if name in VERBS:
            raise ValueError(f"the verb {name!r} is declared twice")
        doc = (handler.__doc__ or "").strip().split("\n\n")[0]
        VERBS[name] = Verb(name, handler, args, access, queue, doors, result, doc, on_printer)
        return handler

    return register


@dataclass(frozen=True, slots=True)
class Encoded:
    """A verb's result already encoded as JSON: answered as it is (for what is costly to encode, and cached)."""

    json: bytes


def heavy_verbs() -> frozenset[str]:
    """The verbs each door runs one at a time per client (`Queue.HEAVY`)."""
    return frozenset(name for name, entry in VERBS.items() if entry.queue is Queue.HEAVY)


def urgent_verbs() -> frozenset[str]:
    """The verbs every door lets through at once (`Queue.URGENT`)."""
    return frozenset(name for name, entry in VERBS.items() if entry.queue is Queue.URGENT)


def printer_of(owner: Owner, name: object) -> FarmPrinter:
    """The printer `name` names (None: the service's only one).

    Raises:
        RpcError: INVALID_PARAMS: no name and several printers, or not a string.
        PortNotFoundError: no printer of that name.
    """
    import marlin_aio

    printers = owner.farm.printers
    if name is None:
        if len(printers) == 1:
            return next(iter(printers.values()))
        raise RpcError(INVALID_PARAMS, f"which printer? this service has {', '.join(printers)}")
    if not isinstance(name, str):
        raise RpcError(INVALID_PARAMS, f"parameter 'printer' has the wrong type ({type(name).__name__})")
    if name not in printers:
        raise marlin_aio.PortNotFoundError(
            f"no printer named {name[:60]!r} in the service at {owner.socket_path} (it has: {', '.join(printers)})"
        )
    return printers[name]


async def call(owner: Owner, name: str, params: Mapping[str, Any], caller: Caller) -> object:
    """Call the verb `name` with `params` (JSON values, by name) for `caller`, and return its result (JSON).

    Raises:
        RpcError: METHOD_NOT_FOUND (no such verb at this door) or INVALID_PARAMS (an argument missing, unknown or
            of the wrong kind): nothing was done.
        MarlinError, ValueError, RuntimeError, OSError: as the verb raised them (each door says them its way).
    """
    entry = VERBS.get(name)
    if entry is None or caller.door not in entry.doors:
        offered = ", ".join(sorted(n for n, v in VERBS.items() if caller.door in v.doors))
        raise RpcError(METHOD_NOT_FOUND, f"no method {name[:60]!r}; there are {offered}")
    known = {arg.name for arg in entry.args} | ({"printer"} if entry.on_printer else set())
    unknown = sorted(set(params) - known)
    if unknown:
        takes = ", ".join(sorted(known)) or "nothing"
        raise RpcError(INVALID_PARAMS, f"{name} takes no {unknown[0][:40]!r} (it takes: {takes})")
    args = {arg.name: arg.take(params) for arg in entry.args}
    printer = printer_of(owner, params.get("printer")) if entry.on_printer else None
    return await entry.handler(Context(owner, caller, printer), args)
