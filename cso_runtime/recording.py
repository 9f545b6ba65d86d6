"""Record every ``cso/<robot>/**`` message to MCAP, and play a recording back into Zenoh.

Storage format (chosen so that replay is byte-exact *and* Foxglove / the ``mcap`` CLI can read it):

* One MCAP channel per Zenoh key (the channel topic is the key, e.g. ``cso/r0/scan``) and message
  type; one schema per message type, named ``cso.<schema>`` with ``jsonschema`` encoding.
* A message is our msgpack envelope ``{"schema", "v", "body"}`` written as JSON
  (``message_encoding: json``, which Foxglove decodes), msgpack ``bin`` values as
  ``{"$base64": "..."}``. Before writing, the recorder checks that packing the decoded envelope
  again gives back exactly the received bytes; every payload that passes is replayed exactly.
* Anything that would not come back byte-identical through JSON (not msgpack, NaN/inf floats,
  non-string map keys, extension types, another packer's choices) is stored verbatim on a channel
  with ``message_encoding: cso-raw`` (no schema) and replayed verbatim, so replay never alters a
  payload, malformed ones included.

``log_time`` is the reception time (ns, strictly increasing in arrival order), so replay in log-time
order reproduces the order and the timing of the original run.
"""

from __future__ import annotations

import base64
import json
import logging
import math
import os
import queue
import struct
import threading
import time
from collections import Counter
from collections.abc import Generator, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import zenoh

from cso_runtime.keys import ROOT, RobotKeys, check_robot_id, topic_of

log = logging.getLogger("cso.recording")

JSON_ENCODING = "json"
RAW_ENCODING = "cso-raw"
"""Message encoding of payloads kept verbatim (not representable as exact JSON)."""
BIN_TAG = "$base64"
"""JSON form of a msgpack ``bin`` value: ``{"$base64": "<base64>"}``."""
MCAP_PROFILE = ""
LIBRARY = "cso-runtime recording"


class RecordingError(RuntimeError):
    """A recording cannot be read or written."""


class ReplayRefused(RecordingError):
    """A replay would publish into a network where a robot of the recording runs (``running_robot``)."""


class _NotExactJson(ValueError):
    """This msgpack value has no exact JSON form."""


def _to_json(obj: Any) -> Any:
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if isinstance(obj, float):
        if not math.isfinite(obj):
            raise _NotExactJson("non-finite float")
        return obj
    if isinstance(obj, bytes):
        return {BIN_TAG: base64.b64encode(obj).decode("ascii")}
    if isinstance(obj, list):
        return [_to_json(v) for v in obj]
    if isinstance(obj, dict):
        if set(obj) == {BIN_TAG}:
            raise _NotExactJson("a map that looks like a tagged bin")
        if not all(isinstance(k, str) for k in obj):
            raise _NotExactJson("non-string map key")
        return {k: _to_json(v) for k, v in obj.items()}
    raise _NotExactJson(f"unsupported msgpack type {type(obj).__name__}")


def _from_json(obj: Any) -> Any:
    if isinstance(obj, list):
        return [_from_json(v) for v in obj]
    if isinstance(obj, dict):
        if set(obj) == {BIN_TAG}:
            return base64.b64decode(obj[BIN_TAG])
        return {k: _from_json(v) for k, v in obj.items()}
    return obj


def payload_to_json(payload: bytes) -> tuple[str, bytes] | None:
    """(schema name, JSON bytes) when ``payload`` round-trips exactly through JSON, else None."""
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        text = json.dumps(_to_json(obj), separators=(",", ":"), allow_nan=False).encode("utf-8")
        exact = msgpack.packb(obj, use_bin_type=True) == payload
    except (_NotExactJson, ValueError, TypeError, msgpack.ExtraData, msgpack.FormatError, msgpack.StackError):
        return None
    if not exact:
        return None
    schema = obj.get("schema") if isinstance(obj, dict) and set(obj) == {"schema", "v", "body"} else None
    return (schema if isinstance(schema, str) and schema else "any"), text


def payload_from_json(data: bytes) -> bytes:
    """The original msgpack bytes of a JSON-encoded recorded message."""
    return msgpack.packb(_from_json(json.loads(data)), use_bin_type=True)


def json_schema(schema: str) -> bytes:
    """The jsonschema of one message type's JSON form (fields are documented in docs/messages.md)."""
    doc: dict[str, Any] = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"cso.{schema}",
        "description": f"cso-runtime '{schema}' message: the msgpack envelope as JSON; msgpack bin values are "
        f'{{"{BIN_TAG}": "..."}}, numpy arrays are {{dtype, shape, z (zlib), data}}. See docs/messages.md.',
        "type": "object",
    }
    if schema != "any":
        doc["properties"] = {"schema": {"type": "string", "const": schema}, "v": {"type": "integer"}, "body": {"type": "object"}}
        doc["required"] = ["schema", "v", "body"]
    return json.dumps(doc).encode("utf-8")


def robot_key_expr(robot: str) -> str:
    """Everything of one robot (``*``: every robot)."""
    return f"{ROOT}/{check_robot_id(robot, allow_wildcard=True)}/**"


@dataclass
class RecordStats:
    """What a recording holds."""

    path: Path = field(default_factory=Path)
    messages: int = 0
    per_key: Counter = field(default_factory=Counter)
    raw: int = 0
    """Payloads stored verbatim (``cso-raw``) because they have no exact JSON form."""
    bytes_in: int = 0
    left_out: int = 0
    """Messages that had arrived but were not written: the recorder was stopped with more to write than its
    ``drain_s`` allowed."""


class _McapSink:
    """An MCAP writer that registers a schema per message type and a channel per (key, type)."""

    def __init__(self, fh: Any, robot: str) -> None:
        from mcap.writer import CompressionType, Writer  # noqa: PLC0415  (mcap is loaded only by record and replay)

        # Chunks of 256 KiB rather than the library's 1 MiB: a recorder killed outright (SIGKILL, power) loses
        # at most the chunk it was filling; ``read_recording`` reads the chunks before it.
        self.writer = Writer(fh, compression=CompressionType.ZSTD, chunk_size=256 * 1024)
        self.writer.start(profile=MCAP_PROFILE, library=LIBRARY)
        self.writer.add_metadata(
            "cso-runtime", {"robot": robot, "payload": "msgpack envelope as JSON, see cso_runtime/recording.py"}
        )
        self.schemas: dict[str, int] = {}
        self.channels: dict[tuple[str, str], int] = {}
        self.sequence = 0

    def channel(self, key: str, schema: str | None) -> int:
        ident = (key, schema or "")
        cid = self.channels.get(ident)
        if cid is None:
            if schema is None:
                cid = self.writer.register_channel(key, RAW_ENCODING, 0, {"zenoh_key": key})
            else:
                sid = self.schemas.get(schema)
                if sid is None:
                    sid = self.schemas[schema] = self.writer.register_schema(f"cso.{schema}", "jsonschema", json_schema(schema))
                cid = self.writer.register_channel(key, JSON_ENCODING, sid, {"zenoh_key": key})
            self.channels[ident] = cid
        return cid

    def write(self, key: str, payload: bytes, log_time_ns: int) -> bool:
        """Write one message; True when it went in as JSON, False when stored verbatim."""
        converted = payload_to_json(payload)
        schema, data = converted if converted is not None else (None, payload)
        self.sequence += 1
        self.writer.add_message(
            self.channel(key, schema), log_time=log_time_ns, data=data, publish_time=log_time_ns, sequence=self.sequence
        )
        return converted is not None

    def finish(self) -> None:
        self.writer.finish()


def record(
    session: zenoh.Session,
    robot: str,
    out_path: Path,
    stop_event: threading.Event,
    ready: threading.Event | None = None,
    stats: RecordStats | None = None,
    drain_s: float | None = None,
) -> RecordStats:
    """Record every ``cso/<robot>/**`` sample into ``out_path`` until ``stop_event`` is set.

    The Zenoh callback only stamps and queues (stamps strictly increase in arrival order); this thread
    writes, so the MCAP writer is used from one thread. ``ready`` is set once the subscriber is declared;
    ``stats`` (optional) is updated as messages are written, for callers that watch progress. ``drain_s``:
    once stopped, write what had arrived for at most this long, then leave the rest out (``stats.left_out``)
    and finish the file; None: write it all (a recorder behind a dense stream on a busy machine can hold a
    long backlog, which a stop with a deadline, the launcher's, cannot wait for).
    """
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    inbox: queue.Queue[tuple[str, bytes, int]] = queue.Queue()  # not SimpleQueue: see services.common.ServiceInputs
    lock = threading.Lock()
    last_ns = [0]

    def on_sample(sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        with lock:
            now = max(time.time_ns(), last_ns[0] + 1)
            last_ns[0] = now
            inbox.put((str(sample.key_expr), payload, now))

    stats = stats if stats is not None else RecordStats(out_path)
    stats.path = out_path
    with out_path.open("xb") as fh:  # never over an earlier recording (FileExistsError)
        sink = _McapSink(fh, robot)
        sub = session.declare_subscriber(robot_key_expr(robot), on_sample)
        if ready is not None:
            ready.set()
        log.info("recording %s into %s", robot_key_expr(robot), out_path)
        try:
            while not stop_event.is_set():  # checked at every message: a dense stream must not keep Ctrl-C waiting
                try:
                    key, payload, t_ns = inbox.get(timeout=0.05)
                except queue.Empty:
                    continue
                _write(sink, stats, key, payload, t_ns)
        finally:
            drain_until = time.monotonic() + drain_s if drain_s is not None else None
            sub.undeclare()
            while not inbox.empty():  # what arrived before the undeclare
                if drain_until is not None and time.monotonic() > drain_until:
                    stats.left_out = inbox.qsize()
                    break
                _write(sink, stats, *inbox.get_nowait())
            sink.finish()
    log.info("recorded %d messages (%d verbatim) on %d keys into %s", stats.messages, stats.raw, len(stats.per_key), out_path)
    if stats.left_out:
        log.warning(
            "%d messages that had arrived were left out of %s: writing them would have taken more than %g s after the stop; "
            "the file holds the run up to then", stats.left_out, out_path, drain_s,
        )
    return stats


def write_recording(path: Path, robot: str, messages: Iterable[RecordedMessage]) -> RecordStats:
    """Write messages as ``record`` does, without Zenoh: a recording made from a filtered or built message
    list (tools, tests) reads, replays and exports like a recorded one."""
    stats = RecordStats(Path(path))
    with Path(path).open("wb") as fh:
        sink = _McapSink(fh, robot)
        try:
            for m in messages:
                _write(sink, stats, m.key, m.payload, m.log_time_ns)
        finally:
            sink.finish()
    return stats


def _write(sink: _McapSink, stats: RecordStats, key: str, payload: bytes, t_ns: int) -> None:
    exact = sink.write(key, payload, t_ns)
    stats.raw += not exact
    stats.bytes_in += len(payload)
    stats.per_key[key] += 1
    stats.messages += 1


@dataclass(frozen=True)
class RecordedMessage:
    """One message of a recording: its Zenoh key, reception time and the exact original payload."""

    key: str
    log_time_ns: int
    payload: bytes


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The first eight bytes of every MCAP file (the MCAP specification's magic)."""


def recording_path(out: Path | str | None, default_folder: Path, stem: str) -> Path:
    """The MCAP file to write: ``out``; ``stem.mcap`` inside it when ``out`` is a folder (one that exists, one
    written with a trailing slash such as ``--out recordings/`` that may not exist yet, or an empty ``--out ""``),
    and inside ``default_folder`` when there is no ``out``."""
    if out is None:
        return default_folder / f"{stem}.mcap"
    return Path(out) / f"{stem}.mcap" if names_a_folder(out) else Path(out)


def names_a_folder(out: Path | str) -> bool:
    """True when an output argument means a folder: one that exists, an empty one (the current folder), or one
    written with a trailing slash (``recordings/``), which may not exist yet (``Path`` drops that slash)."""
    return (isinstance(out, str) and out.endswith(("/", os.sep))) or Path(out).is_dir() or not Path(out).name


def unused_path(path: Path) -> Path:
    """``path`` when nothing is there, else the first free ``<stem>-<n><suffix>`` beside it: a writer that starts
    again (a restarted service, the same profile run twice) keeps what the earlier one wrote."""
    original = candidate = Path(path)
    n = 0
    while candidate.exists():
        n += 1
        candidate = original.with_name(f"{original.stem}-{n}{original.suffix}")
    return candidate


def check_recording(path: Path) -> None:
    """Raise RecordingError unless ``path`` is a file that starts like an MCAP file, so that ``replay``
    names a wrong file before it looks for a run to replay into (``read_recording`` finds damage further in)."""
    if Path(path).is_dir():
        raise RecordingError(f"{path} is a folder; give the .mcap file in it that `cso-runtime record` wrote")
    if not Path(path).is_file():
        raise RecordingError(f"no such recording {path}")
    try:
        with Path(path).open("rb") as fh:
            head = fh.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not head:
        raise RecordingError(f"cannot read {path}: empty file")
    if head != MCAP_MAGIC:
        raise RecordingError(f"cannot read {path}: not an MCAP file (it does not start with the MCAP magic)")


def read_recording(path: Path, topics: Iterable[str] | None = None, quiet: bool = False) -> Generator[RecordedMessage, None, None]:
    """The messages of an MCAP recording in log-time order, payloads restored byte-exactly.

    ``topics``: only keys whose topic name (``cso_runtime.keys.TOPICS``, e.g. ``scan``) is listed. ``quiet``: no
    warning for a file cut short (a first pass over a file that the command reads again, and says so then, once).
    """
    from mcap.exceptions import McapError  # noqa: PLC0415  (mcap is loaded only by record and replay)
    from mcap.reader import make_reader  # noqa: PLC0415

    check_recording(path)  # a missing, empty or foreign file: said the same way as by ``replay``
    wanted = set(topics) if topics is not None else None
    yielded = 0
    try:
        with Path(path).open("rb") as fh:
            reader = make_reader(fh, validate_crcs=True)  # a flipped bit is an error, not a wrong message
            for _schema, channel, message in reader.iter_messages(log_time_order=True):
                restored = _restored(channel, message, wanted)
                if restored is not None:
                    yielded += 1
                    yield restored
    except (McapError, OSError, ValueError, struct.error, zlib_error()) as exc:
        if yielded or is_crc_error(exc) or _ends_with_magic(path):  # damage further in, or in a finished file
            raise RecordingError(f"cannot read {path}: {damage_reason(exc)}") from None
        # No summary to seek with (a recorder killed before it finished the file): read it from the start.
        yield from _read_cut_recording(path, wanted, exc, quiet)


def check_chunks(path: Path) -> None:
    """Raise RecordingError when a chunk of ``path`` no longer matches its CRC (or a finished file does not read
    through), before anything of it is used: the file read once, front to back, its chunks decompressed but no
    message decoded (milliseconds a megabyte). A file cut short (its recorder killed) passes: ``read_recording``
    reads it up to the cut; one cut before its first chunk, with nothing to read, is a RecordingError too. ``replay`` checks first, so that it never feeds a pipeline the run up to the damage."""
    from mcap.exceptions import McapError  # noqa: PLC0415
    from mcap.records import Channel  # noqa: PLC0415
    from mcap.stream_reader import StreamReader  # noqa: PLC0415

    check_recording(path)
    channels = 0
    try:
        with Path(path).open("rb") as fh:
            for record in StreamReader(fh, validate_crcs=True).records:
                channels += isinstance(record, Channel)
    except (McapError, OSError, ValueError, EOFError, struct.error, zlib_error()) as exc:
        if is_crc_error(exc) or _ends_with_magic(path):
            raise RecordingError(f"cannot read {path}: {damage_reason(exc)}") from None
        if not channels:  # cut before anything ``read_recording`` could read: said now, as export-bag and animate say it
            raise RecordingError(f"cannot read {path}: it ends before its first chunk of messages (its recorder was killed before it wrote one?)") from None


def _restored(channel: Any, message: Any, wanted: set[str] | None) -> RecordedMessage | None:
    """One MCAP message back as the payload that was published, or None (a topic not wanted, a foreign channel)."""
    if wanted is not None:
        try:
            if topic_of(channel.topic) not in wanted:
                return None
        except ValueError:
            return None
    if channel.message_encoding == JSON_ENCODING:
        payload = payload_from_json(message.data)
    elif channel.message_encoding == RAW_ENCODING:
        payload = bytes(message.data)
    else:
        log.warning("skipping channel %s with foreign encoding %r", channel.topic, channel.message_encoding)
        return None
    return RecordedMessage(channel.topic, message.log_time, payload)


def _read_cut_recording(path: Path, wanted: set[str] | None, why: Exception, quiet: bool = False) -> Iterable[RecordedMessage]:
    """The messages of an MCAP file without its summary, read front to back (in the order they were recorded)
    up to where it was cut, with a warning that counts them all (``quiet``: none); RecordingError when not even
    one message can be read."""
    from mcap.exceptions import McapError  # noqa: PLC0415
    from mcap.records import Channel, Message  # noqa: PLC0415
    from mcap.stream_reader import StreamReader  # noqa: PLC0415

    channels: dict[int, Any] = {}
    count, read, cut = 0, 0, None
    with Path(path).open("rb") as fh:
        records = iter(StreamReader(fh, validate_crcs=True).records)
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except (McapError, OSError, ValueError, EOFError, struct.error, zlib_error()) as exc:
                if is_crc_error(exc):  # damage, not a cut: nothing after it can be trusted to be what was recorded
                    raise RecordingError(f"cannot read {path}: {damage_reason(exc)}") from None
                cut = exc
                break
            if isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message) and record.channel_id in channels:
                read += 1
                try:
                    restored = _restored(channels[record.channel_id], record, wanted)
                except ValueError as exc:  # a payload that does not decode: the file's fault, as in read_recording
                    raise RecordingError(f"cannot read {path}: {exc}") from None
                if restored is not None:
                    count += 1
                    yield restored
    if not count and not channels:
        if not _ends_with_magic(path):  # no footer and nothing readable: cut before the first chunk was written
            raise RecordingError(f"cannot read {path}: it ends before its first chunk of messages (its recorder was killed before it wrote one?)")
        raise RecordingError(f"cannot read {path}: {damage_reason(why)}")
    if not quiet and (cut is not None or not count):
        log.warning("%s ends early (its recorder was killed before it finished the file?): read %d messages up to there", path, read)


def _ends_with_magic(path: Path) -> bool:
    """True when the file ends as a finished MCAP file does (its footer is followed by the magic)."""
    with Path(path).open("rb") as fh:
        size = fh.seek(0, 2)
        if size < 2 * len(MCAP_MAGIC):
            return False
        fh.seek(size - len(MCAP_MAGIC))
        return fh.read() == MCAP_MAGIC


def is_crc_error(exc: BaseException) -> bool:
    """True for the mcap library's CRC mismatch: bytes changed after they were written (disk, copy, edit)."""
    from mcap.stream_reader import CRCValidationError  # noqa: PLC0415

    return isinstance(exc, CRCValidationError)


def damage_reason(exc: BaseException) -> str:
    """What a reader's exception says about a file, in words (some of the library's messages are blank)."""
    if is_crc_error(exc):
        return f"damaged: a {type(getattr(exc, 'record', None)).__name__}'s CRC does not match its bytes (the file changed after it was written)"
    return str(exc) or type(exc).__name__


def zlib_error() -> type[Exception]:
    """The decompressors' error types a chunk cut in the middle raises (zstandard's, when installed)."""
    try:
        import zstandard  # noqa: PLC0415

        return zstandard.ZstdError
    except ImportError:
        return ValueError


def robots_of(keys: list[str]) -> list[str]:
    """The robot ids of recorded keys (``cso/<robot>/...``), sorted."""
    return sorted({key.split("/")[1] for key in keys if key.count("/") >= 2})


def recorded_robot(path: Path, robot: str | None = None) -> tuple[str, int | None]:
    """The robot whose messages a command reads (``robot``, else the recording's only one) and the recording's
    message count (None without a summary); RecordingError when it holds no such robot, or several and none was
    named."""
    keys, total = recording_contents(path)
    robots = robots_of(keys)
    if robot is None:
        if len(robots) != 1:
            raise RecordingError(f"{path} holds {'no robot' if not robots else 'robots ' + ', '.join(robots)}: give --robot ID")
        return robots[0], total
    if robot not in robots:
        raise RecordingError(f"{path} holds no messages of robot {robot!r} (it has: {', '.join(robots) or 'none'})")
    return robot, total


def recording_contents(path: Path) -> tuple[list[str], int | None]:
    """The Zenoh keys a recording has messages on (sorted) and how many messages it holds: from its summary
    when it has one (nothing to decompress), else read through (count None; a file cut short raises
    ``RecordingError``)."""
    from mcap.exceptions import McapError  # noqa: PLC0415  (mcap is loaded only by record and replay)
    from mcap.reader import make_reader  # noqa: PLC0415

    check_recording(path)
    try:
        with Path(path).open("rb") as fh:
            summary = make_reader(fh, validate_crcs=True).get_summary()
    except (McapError, OSError, ValueError, EOFError, struct.error):  # a file cut in its summary: a short footer read
        summary = None
    if summary is not None and summary.statistics is not None:
        counts = summary.statistics.channel_message_counts
        keys = {c.topic for cid, c in summary.channels.items() if counts.get(cid, 0) > 0}
        return sorted(keys), int(summary.statistics.message_count)
    return sorted({m.key for m in read_recording(path, quiet=True)}), None


@dataclass
class ReplayStats:
    """What a ``replay`` published: messages per key, how long it took against the time the recording spans, and
    what it had to upgrade or could not read."""

    messages: int = 0
    per_key: Counter = field(default_factory=Counter)
    duration_s: float = 0.0
    """Wall time the replay took."""
    recorded_s: float = 0.0
    """Time between the first and the last recorded message."""
    upgraded: Counter = field(default_factory=Counter)
    """Per key: messages of an older version published as the current one (``messages.upgrade_payload``)."""
    unreadable: Counter = field(default_factory=Counter)
    """Per key: payloads this build cannot read (not an envelope, an unknown schema or version, an older body that
    does not decode), published as recorded: the services reject and count them, as they would have live."""


def parse_speed(speed: float | str) -> float:
    """``max`` (as fast as possible) -> inf; otherwise a positive factor of the recorded speed."""
    if isinstance(speed, str):
        if speed.strip().lower() == "max":
            return math.inf
        try:
            speed = float(speed)
        except ValueError:
            raise ValueError(f"speed must be a positive number or 'max', got {speed!r}") from None
    if not (speed > 0):
        raise ValueError(f"speed must be a positive number or 'max', got {speed!r}")
    if speed < MIN_REPLAY_SPEED:  # 1e-320: a wait past the platform's longest, an OverflowError traceback mid-replay
        raise ValueError(f"speed must be at least {MIN_REPLAY_SPEED:g} (recording.MIN_REPLAY_SPEED: {1 / MIN_REPLAY_SPEED:g} times slower than recorded) or 'max', got {speed!r}")
    return float(speed)


MIN_REPLAY_SPEED = 0.001
"""The slowest ``replay --speed``: a second of the run in a thousand. ``1e-320`` made a wait between two messages
longer than the platform's longest (``threading.TIMEOUT_MAX``): an OverflowError traceback mid-replay; ``1e-12``
waited centuries in silence."""


def running_robot(session: zenoh.Session, robots: Iterable[str], timeout_s: float = 1.0) -> str:
    """Which of ``robots`` runs on ``session``'s network, and how it shows, or "": its launcher answers there, or its
    referee (sim or ROS 2 bridge) is alive. A pipeline of services started by hand to be fed a recording has
    neither: the recording's clock, scans and odometry stand in for the referee."""
    from cso_runtime.run_profile import REFEREES  # noqa: PLC0415  (the profile's imports: only when replaying)

    for robot in robots:
        keys = RobotKeys(robot)
        if any(reply.ok is not None for reply in session.get(keys.launcher_status, timeout=timeout_s)):
            return f"robot {robot} runs on this network (its launcher answers at {keys.launcher_status})"
        for reply in session.liveliness().get(keys.alive("*"), timeout=timeout_s):
            if reply.ok is not None and (name := str(reply.ok.key_expr).rsplit("/", 1)[-1]) in REFEREES:
                return f"robot {robot} runs on this network (its {name} is alive)"
    return ""


def replay(
    session: zenoh.Session,
    path: Path,
    speed: float | str = 1.0,
    stop_event: threading.Event | None = None,
    topics: Iterable[str] | None = None,
) -> ReplayStats:
    """Publish every recorded payload on its original key at the recorded timing / ``speed`` (``'max'``: no
    waiting). Publishers block instead of dropping so nothing is lost at full speed. A payload is published
    unchanged, except one of an older version of its schema (``messages.LEGACY_UPGRADES``), published as the
    current version, since a service rejects any other: an old recording still drives today's services.

    ReplayRefused, before anything is published, when a robot of the recording runs on the network
    (``running_robot``): its old scans, odometry, maps and commands would mix with the live run's, and that run's
    ROS 2 bridge would send the recorded commands to its robot as Twists. RecordingError, before anything is
    published too, for a recording changed after it was written (``check_chunks``)."""
    rate = parse_speed(speed)
    check_chunks(path)  # damage anywhere is said before the first message goes out
    if live := running_robot(session, robots_of(recording_contents(path)[0])):
        raise ReplayRefused(
            f"{live}: replaying {path} there would feed its recorded messages into the live run (and a ROS 2 bridge would "
            "drive its robot with the recorded commands); replay into a router where that robot does not run (--connect), "
            "or stop the run first"
        )
    stop_event = stop_event or threading.Event()
    pubs: dict[str, zenoh.Publisher] = {}
    stats = ReplayStats()
    t0_wall = time.monotonic()
    first_ns: int | None = None
    try:
        for m in read_recording(path, topics):
            if first_ns is None:
                first_ns = m.log_time_ns
            offset_s = (m.log_time_ns - first_ns) / 1e9
            stats.recorded_s = offset_s
            if math.isfinite(rate):
                wait_s = t0_wall + offset_s / rate - time.monotonic()
                if wait_s > 0 and stop_event.wait(wait_s):
                    break
            if stop_event.is_set():
                break
            pub = pubs.get(m.key)
            if pub is None:
                pub = pubs[m.key] = session.declare_publisher(m.key, congestion_control=zenoh.CongestionControl.BLOCK)
            pub.put(_current_payload(m, stats))
            stats.messages += 1
            stats.per_key[m.key] += 1
    finally:
        for pub in pubs.values():
            pub.undeclare()
    stats.duration_s = time.monotonic() - t0_wall
    log.debug("replayed %d messages in %.2f s (recorded span %.2f s)", stats.messages, stats.duration_s, stats.recorded_s)  # `replay` says it
    return stats


def _current_payload(m: RecordedMessage, stats: ReplayStats) -> bytes:
    """``m``'s payload as today's services read it (upgraded from an older version), counted in ``stats``;
    one this build cannot read is left as recorded, and said once per key."""
    from cso_runtime.messages import MessageError, upgrade_payload  # noqa: PLC0415  (numpy and the codecs: only when replaying)

    try:
        payload = upgrade_payload(m.payload)
    except MessageError as exc:
        if not stats.unreadable[m.key]:
            log.warning("%s: published as recorded, which this build cannot read (%s); later ones are only counted", m.key, exc)
        stats.unreadable[m.key] += 1
        return m.payload
    if payload is not m.payload:
        stats.upgraded[m.key] += 1
    return payload
