#!/usr/bin/env python3
"""Reads Stylet session files (docs/session-format.md) into plain Python columns.

    from stylet_session import read_session
    s = read_session("session.mcap")
    s.ticks["pos_x_mm"][0], s.tick_rate_hz, s.events["name"]
    pandas.DataFrame(s.ticks)           # every table is a dict of equal-length lists

    python3 stylet_session.py SESSION.mcap [--csv TICKS.csv] [--events-csv EVENTS.csv]

Needs the `mcap` package (with `zstandard` and `lz4`, which it pulls in) and `cbor2`
(requirements.txt beside this file; scripts/python-env makes a virtual environment with them).

The read is strict, like the Rust reader's `read`: a file that is cut short, altered (a CRC
mismatch), or holds a record, block, event or header the format does not allow raises
`SessionFormatError` naming what and where. Nothing is guessed or skipped silently.
"""

import argparse
import csv
import io
import math
import os
import struct
import sys
import zlib
from itertools import accumulate
from operator import add, xor

try:
    import cbor2
    from mcap.exceptions import McapError
    from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata
    from mcap.stream_reader import StreamReader, get_chunk_data_stream
    from mcap.data_stream import ReadDataStream
except ImportError as e:  # pragma: no cover - depends on the environment
    raise ImportError(
        f"{e}: stylet_session needs mcap and cbor2 "
        "(pip install --require-hashes -r recorder/python/requirements.txt, or scripts/python-env)"
    ) from e

__all__ = [
    "SessionFormatError",
    "Session",
    "read_session",
    "tool_in_hand",
    "rows",
    "write_csv",
    "TICK_COLUMNS",
    "EVENT_COLUMNS",
    "DIGEST_COLUMNS",
    "ANNOTATION_COLUMNS",
    "PREVIEW_COLUMNS",
    "BLOCK_COLUMNS",
    "SECOND_HAND_COLUMNS",
    "TOOL_COLUMNS",
]

PROFILE = "stylet-session"
META_HEADER = "stylet.session"
META_END = "stylet.session.end"
TOPIC_TICKS = "/stylet/ticks"
TOPIC_EVENTS = "/stylet/events"
TOPIC_DIGESTS = "/stylet/digests"
TOPIC_ANNOTATIONS = "/stylet/annotations"
TOPIC_PREVIEW = "/stylet/preview"
TOPIC_DEVICE_FORCES = "/stylet/device_forces"
TOPICS = (
    TOPIC_TICKS, TOPIC_EVENTS, TOPIC_DIGESTS, TOPIC_ANNOTATIONS, TOPIC_PREVIEW, TOPIC_DEVICE_FORCES,
)

# Schema versions this reader reads (the Rust reader of version N reads N and N - 1).
SCHEMA_VERSIONS = (1, 2, 3, 4)
CODEC_EXACT = "stylet-columns-v1"
CODEC_ROUNDED = "stylet-columns-v2"

# Rounded outputs (codec v2): integer steps per unit, and the largest step count a writer stores
# (below 2^53, so count / steps is exact).
FORCE_STEPS_PER_N = 65536.0
TORQUE_STEPS_PER_NMM = 4096.0
MAX_STEPS = 2**53 - 1

# The Rust reader's default limits (recorder/src/reader.rs, Limits::default): a hostile or
# damaged file gets an error, never a huge allocation.
MAX_FILE_BYTES = 2 << 30
MAX_RECORD_BYTES = 64 << 20
MAX_CHUNK_UNCOMPRESSED_BYTES = 64 << 20
MAX_BLOCK_TICKS = 100_000
MAX_NAME_CHARS = 64
MAX_NOTE_CHARS = 2000

F64_COLUMNS = ("pos_x_mm", "pos_y_mm", "pos_z_mm", "q_w", "q_x", "q_y", "q_z", "inserted_mm")
OUTPUT_COLUMNS = ("force_x_n", "force_y_n", "force_z_n", "torque_x_nmm", "torque_y_nmm", "torque_z_nmm")
INT_COLUMNS = (("buttons", 4), ("tip_label", 2))

# Column order of `Session.ticks` (the Rust CSV export's order, with the block's column names).
TICK_COLUMNS = (
    "tick", "t_s",
    "pos_x_mm", "pos_y_mm", "pos_z_mm",
    "q_w", "q_x", "q_y", "q_z",
    "buttons",
    "force_x_n", "force_y_n", "force_z_n",
    "torque_x_nmm", "torque_y_nmm", "torque_z_nmm",
    "tip_label", "inserted_mm",
)
# `Session.second_hand`: one row per tick with a second hand (two-handed sessions, schema 4).
SECOND_HAND_COLUMNS = (
    "tick", "t_s",
    "hand2_pos_x_mm", "hand2_pos_y_mm", "hand2_pos_z_mm",
    "hand2_q_w", "hand2_q_x", "hand2_q_y", "hand2_q_z",
    "hand2_buttons",
    "hand2_force_x_n", "hand2_force_y_n", "hand2_force_z_n",
    "hand2_torque_x_nmm", "hand2_torque_y_nmm", "hand2_torque_z_nmm",
)
# The second hand's real columns in a tick block (exact in both codecs) and its presence flags.
HAND2_F64_COLUMNS = (
    "hand2_pos_x_mm", "hand2_pos_y_mm", "hand2_pos_z_mm",
    "hand2_q_w", "hand2_q_x", "hand2_q_y", "hand2_q_z",
    "hand2_force_x_n", "hand2_force_y_n", "hand2_force_z_n",
    "hand2_torque_x_nmm", "hand2_torque_y_nmm", "hand2_torque_z_nmm",
)
HAND2_COLUMNS = HAND2_F64_COLUMNS + ("hand2_buttons",)
EVENT_COLUMNS = ("tick", "t_s", "name", "tool", "gauge", "length_mm", "stylet_in", "ml", "wire", "size_fr")
DIGEST_COLUMNS = ("tick", "t_s", "digest", "digest_hex")
ANNOTATION_COLUMNS = ("tick", "t_s", "text")
PREVIEW_COLUMNS = (
    "tick", "t_s",
    "pos_x_mm", "pos_y_mm", "pos_z_mm",
    "force_x_n", "force_y_n", "force_z_n", "force_magnitude_n",
    "tip_label", "inserted_mm",
)
BLOCK_COLUMNS = ("first_tick", "count", "codec", "outputs_digest")
DEVICE_FORCE_COLUMNS = (
    "tick", "t_s", "sent_x_n", "sent_y_n", "sent_z_n", "sent_magnitude_n",
    "held", "watchdog", "waiting", "not_finite", "ramping", "clamped", "continuous",
)
# The force guard's flags in a device-force block's `guard` column, bit by bit.
GUARD_FLAGS = ("held", "watchdog", "waiting", "not_finite", "ramping", "clamped", "continuous")
DEVICE_FORCE_STEPS_PER_N = 1 << 16
MAX_DEVICE_FORCE_BLOCK_TICKS = 500
TOOL_COLUMNS = ("tick", "tool", "tool_gauge", "tool_length_mm", "tool_stylet_in")

EVENT_NAMES = (
    "tool", "tool2", "stylet-remove", "stylet-insert", "xray-on", "xray-off",
    "contrast-inject", "breath-hold", "breath-release", "wire-in", "needle-out", "wire-out",
    "dilator-in", "dilator-out", "catheter-in",
)
# A `wire-in` event's wire: "<diameter> <tip>".
WIRE_DIAMETERS = ("0.018", "0.035")
WIRE_TIPS = ("j", "straight")
#: Sizes (French) of the tools that go over the wire.
DILATOR_SIZES_FR = (6, 8, 10, 12)
CATHETER_SIZES_FR = (8, 10)
TOOLS = ("needle", "finger", "probe-linear", "probe-convex")
# What the second hand may hold (`none`: empty).
HAND2_TOOLS = ("finger", "probe-linear", "probe-convex", "none")
GAUGES = (16, 18, 20, 22)
HEADER_KEYS = (
    "schema_version", "session_id", "trainee", "scenario", "difficulty", "atlas_id",
    "atlas_hash", "software_version", "physics_version", "tick_rate_hz", "seed", "device",
    "tool", "wall_clock_start",
)

U64 = (1 << 64) - 1
_MAGIC = b"\x89MCAP0\r\n"


class SessionFormatError(Exception):
    """The file is not a readable Stylet session: not MCAP, cut short, altered, or holding
    something the session format does not allow. The message says what (and where)."""


def _columns(names):
    return {n: [] for n in names}


class Session:
    """A session as read. Every table is a dict of equal-length lists, one list per column, so
    `pandas.DataFrame(table)` works and an empty table keeps its columns.

    - `ticks`: one row per recorded tick (TICK_COLUMNS).
    - `events`, `digests`, `annotations`, `previews`: EVENT_COLUMNS, DIGEST_COLUMNS,
      ANNOTATION_COLUMNS, PREVIEW_COLUMNS, in the order the file holds them.
    - `blocks`: one row per tick block (BLOCK_COLUMNS): its codec and, for codec v2, the digest
      of its exact outputs.
    - `second_hand`: two-handed sessions (schema 4): the second device's pose, buttons and
      force at every tick it reported (SECOND_HAND_COLUMNS); empty for one-handed sessions.
    - `device_forces`: sessions trained on a force-feedback device (schema 3): per tick the force
      the device was sent and what its force guard did (DEVICE_FORCE_COLUMNS; flags as booleans).
    - `header`: the `stylet.session` metadata as stored (all values strings); `end`: the
      `stylet.session.end` record decoded (ticks, dropped_ticks, complete, reason) or None;
      `metadata`: every metadata record by name; `profile`, `library`: the MCAP header's.
    """

    def __init__(self, path):
        self.path = path
        self.profile = None
        self.library = None
        self.metadata = {}
        self.header = {}
        self.end = None
        self.ticks = _columns(TICK_COLUMNS)
        self.events = _columns(EVENT_COLUMNS)
        self.digests = _columns(DIGEST_COLUMNS)
        self.annotations = _columns(ANNOTATION_COLUMNS)
        self.previews = _columns(PREVIEW_COLUMNS)
        self.blocks = _columns(BLOCK_COLUMNS)
        self.device_forces = _columns(DEVICE_FORCE_COLUMNS)
        self.second_hand = _columns(SECOND_HAND_COLUMNS)
        self.tick_rate_hz = None
        self.schema_version = None

    @property
    def scenario(self):
        return self.header.get("scenario")

    @property
    def physics_version(self):
        return int(self.header["physics_version"])

    @property
    def codec_versions(self):
        """The column codecs of the file's tick blocks, sorted (e.g. ['stylet-columns-v2'])."""
        return sorted(set(self.blocks["codec"]))

    @property
    def duration_s(self):
        """Up to the end of the last tick, as the Rust reader counts it."""
        t = self.ticks["tick"]
        return (t[-1] + 1) / self.tick_rate_hz if t else 0.0

    def initial_tool(self):
        """The tool at tick 0 from the header: {tool, tool_gauge, tool_length_mm, tool_stylet_in}
        (the last three None for tools other than the needle)."""
        return _header_tool(self.header)

    def settings(self):
        """The header with typed values: whole numbers as int, `true`/`false` as bool, and each
        `..._bits` key (an f64's exact bits in hex) as a float under its name without `_bits`
        (`tool_length_mm_bits` -> `tool_length_mm`). Other values stay strings."""
        out = {}
        for k, v in self.header.items():
            if k.endswith("_bits"):
                try:
                    out[k[: -len("_bits")]] = _f64_from_hex(v)
                    continue
                except ValueError:
                    pass
            if v.isascii() and v.isdigit():
                out[k] = int(v)
            elif v in ("true", "false"):
                out[k] = v == "true"
            else:
                out[k] = v
        return out

    def tool_in_hand(self):
        """See `tool_in_hand`."""
        return tool_in_hand(self)

    def __repr__(self):
        return (
            f"Session({self.path!r}, schema {self.schema_version}, {len(self.ticks['tick'])} ticks, "
            f"{len(self.events['tick'])} events, {len(self.digests['tick'])} digests)"
        )


def rows(table):
    """A table (dict of columns) as a list of dicts, one per row."""
    names = list(table)
    return [dict(zip(names, r)) for r in zip(*(table[n] for n in names))]


def tool_in_hand(session):
    """The tool in hand at every recorded tick, aligned with `session.ticks` (TOOL_COLUMNS).

    Starts with the header's tool. Events apply from their own tick on: the simulation applies a
    tick's events before it computes that tick (stylet_physics `Simulation::step`), and the
    recorder stores them under that tick. A `tool` event takes the new tool with its gauge,
    length and stylet state; `stylet-remove` / `stylet-insert` change the needle's stylet (and
    nothing with another tool). Several events of one tick apply in file order.
    """
    tool = _header_tool(session.header)
    ev = session.events
    order = sorted(range(len(ev["tick"])), key=lambda i: ev["tick"][i])  # stable: file order
    out = _columns(TOOL_COLUMNS)
    k = 0
    for tick in session.ticks["tick"]:
        while k < len(order) and ev["tick"][order[k]] <= tick:
            i = order[k]
            name = ev["name"][i]
            if name == "tool":
                needle = ev["tool"][i] == "needle"
                tool = {
                    "tool": ev["tool"][i],
                    "tool_gauge": ev["gauge"][i] if needle else None,
                    "tool_length_mm": ev["length_mm"][i] if needle else None,
                    "tool_stylet_in": ev["stylet_in"][i] if needle else None,
                }
            elif name in ("stylet-remove", "stylet-insert") and tool["tool"] == "needle":
                tool = dict(tool, tool_stylet_in=name == "stylet-insert")
            k += 1
        out["tick"].append(tick)
        for c in TOOL_COLUMNS[1:]:
            out[c].append(tool[c])
    return out


# --- column codecs (recorder/src/codec.rs) ---------------------------------------------------

_WORD = {1: "B", 2: "H", 4: "I", 8: "Q"}


def _unshuffle(data, width, count, column):
    """The little-endian words of `count` values stored as byte planes (all first bytes, then
    all second bytes, ...)."""
    if len(data) != count * width:
        raise SessionFormatError(f"column '{column}' has {len(data)} bytes, not {count * width}")
    interleaved = bytearray(count * width)
    for b in range(width):
        interleaved[b::width] = data[b * count : (b + 1) * count]
    return struct.unpack(f"<{count}{_WORD[width]}", interleaved)


def decode_xor(data, width, count, column="?"):
    """Integer column: each value XOR the one before it (the first XOR 0)."""
    return list(accumulate(_unshuffle(data, width, count, column), xor))


def decode_predicted(data, count, column="?"):
    """u64 words stored as zigzag residuals of the prediction 2*w[i-1] - w[i-2] (wrapping, with
    w[-1] = w[-2] = 0). The prediction's second difference is the residual, so the words are
    the residuals summed twice (mod 2^64)."""
    residuals = [(z >> 1) ^ -(z & 1) for z in _unshuffle(data, 8, count, column)]
    return [w & U64 for w in accumulate(accumulate(residuals, add), add)]


def decode_f64(data, count, column="?"):
    """f64 column (codec v1): every bit pattern, NaN payloads and -0 included."""
    words = decode_predicted(data, count, column)
    return list(struct.unpack(f"<{count}d", struct.pack(f"<{count}Q", *words)))


def decode_steps(data, count, steps_per_unit, column="?"):
    """Rounded output column (codec v2): i64 step counts as values (count / steps_per_unit,
    exact; a count of 0 gives +0)."""
    words = decode_predicted(data, count, column)
    values = []
    for s in struct.unpack(f"<{count}q", struct.pack(f"<{count}Q", *words)):
        if abs(s) > MAX_STEPS:
            raise SessionFormatError(f"column '{column}' holds a step count out of range ({s})")
        values.append(s / steps_per_unit)
    return values


# --- records -------------------------------------------------------------------------------------


def _f64_from_hex(v):
    if len(v) != 16:
        raise ValueError(v)
    return struct.unpack("<d", struct.pack("<Q", int(v, 16)))[0]


def _header_tool(h):
    kind = h.get("tool")
    if kind == "needle":
        return {
            "tool": kind,
            "tool_gauge": int(h["tool_gauge"]),
            "tool_length_mm": _f64_from_hex(h["tool_length_mm_bits"]),
            "tool_stylet_in": h["tool_stylet_in"] == "true",
        }
    return {"tool": kind, "tool_gauge": None, "tool_length_mm": None, "tool_stylet_in": None}


def _uint(v, what, bits=64):
    # bool is an int in Python; CBOR true/false are not numbers.
    if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < (1 << bits):
        raise SessionFormatError(f"{what} is not an unsigned {bits}-bit integer: {v!r}")
    return v


def _real(v, what):
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SessionFormatError(f"{what} is not a number: {v!r}")
    return float(v)


def _text(v, what, max_chars):
    if not isinstance(v, str):
        raise SessionFormatError(f"{what} is not text: {v!r}")
    if len(v) > max_chars:
        raise SessionFormatError(f"{what} is longer than {max_chars} characters")
    return v


def _map(data, what):
    try:
        m = cbor2.loads(data)
    except RecursionError:
        raise SessionFormatError(f"{what}: CBOR nested too deeply") from None
    except Exception as e:  # cbor2 raises several kinds on malformed input
        raise SessionFormatError(f"{what}: bad CBOR: {e}") from None
    if not isinstance(m, dict):
        raise SessionFormatError(f"{what}: not a CBOR map")
    return m


def _get(m, key, what):
    if key not in m:
        raise SessionFormatError(f"{what} lacks '{key}'")
    return m[key]


def _parse_header(m):
    for k in HEADER_KEYS:
        if k not in m:
            raise SessionFormatError(f"session header lacks '{k}'")
    try:
        schema = int(m["schema_version"])
        rate = int(m["tick_rate_hz"])
        int(m["physics_version"])
        int(m["seed"])
    except ValueError as e:
        raise SessionFormatError(f"session header: a number is not a number ({e})") from None
    if schema not in SCHEMA_VERSIONS:
        raise SessionFormatError(
            f"schema version {schema} (this reader reads {', '.join(map(str, SCHEMA_VERSIONS))})"
        )
    if not 1 <= rate <= 100_000:
        raise SessionFormatError(f"session header tick_rate_hz {rate} is out of range")
    if m["tool"] not in TOOLS:
        raise SessionFormatError(f"session header: unknown tool '{m['tool'][:64]}'")
    if m["tool"] == "needle":
        try:
            tool = _header_tool(m)
        except (KeyError, ValueError) as e:
            raise SessionFormatError(f"session header: bad needle ({e})") from None
        if m["tool_stylet_in"] not in ("true", "false"):
            raise SessionFormatError("session header 'tool_stylet_in' is not true/false")
        _check_needle(tool["tool_gauge"], tool["tool_length_mm"], "session header")
    if "hand2.device" in m:
        if "hand2.tool" not in m:
            raise SessionFormatError("session header lacks 'hand2.tool'")
        if m["hand2.tool"] not in HAND2_TOOLS:
            raise SessionFormatError(f"session header: the second hand cannot hold '{m['hand2.tool'][:64]}'")
    return schema, rate


def _check_needle(gauge, length_mm, what):
    if gauge not in GAUGES:
        raise SessionFormatError(f"{what}: gauge {gauge} is not 16, 18, 20 or 22")
    if length_mm is None or not math.isfinite(length_mm) or length_mm <= 0:
        raise SessionFormatError(f"{what}: needle without a valid length")


def _parse_end(m):
    try:
        end = {
            "ticks": int(m["ticks"]),
            "dropped_ticks": int(m["dropped_ticks"]),
            "complete": m["complete"],
            "reason": m["reason"],
        }
    except KeyError as e:
        raise SessionFormatError(f"session end lacks {e}") from None
    except ValueError as e:
        raise SessionFormatError(f"session end: a number is not a number ({e})") from None
    if end["complete"] not in ("true", "false"):
        raise SessionFormatError("session end 'complete' is not true/false")
    end["complete"] = end["complete"] == "true"
    return end


class _Reader:
    """Builds a Session from the records of a file, in file order."""

    def __init__(self, session):
        self.s = session
        self.channels = {}
        self.last_tick = None

    def t(self, tick):
        return tick / self.s.tick_rate_hz

    def record(self, rec):
        if isinstance(rec, Channel):
            if rec.topic not in TOPICS:
                raise SessionFormatError(f"channel on unexpected topic '{rec.topic[:64]}'")
            self.channels[rec.id] = rec.topic
        elif isinstance(rec, Message):
            topic = self.channels.get(rec.channel_id)
            if topic is None:
                raise SessionFormatError(f"message on unknown channel {rec.channel_id}")
            if self.s.tick_rate_hz is None:
                raise SessionFormatError("a message before the session header")
            getattr(self, "_" + topic.rsplit("/", 1)[1])(_map(rec.data, topic))
        elif isinstance(rec, Metadata):
            self.s.metadata[rec.name] = dict(rec.metadata)
            if rec.name == META_HEADER:
                self.s.header = dict(rec.metadata)
                self.s.schema_version, self.s.tick_rate_hz = _parse_header(self.s.header)
            elif rec.name == META_END:
                self.s.end = _parse_end(rec.metadata)

    def chunk(self, chunk):
        if chunk.uncompressed_size > MAX_CHUNK_UNCOMPRESSED_BYTES:
            raise SessionFormatError(
                f"chunk claims {chunk.uncompressed_size} bytes uncompressed, over the limit"
            )
        if chunk.compression not in ("", "zstd", "lz4"):
            raise SessionFormatError(f"chunk compression '{chunk.compression[:64]}' is not supported")
        stream, size = get_chunk_data_stream(chunk, validate_crc=True)
        if size != chunk.uncompressed_size:
            raise SessionFormatError(
                f"chunk decompresses to {size} bytes, not the {chunk.uncompressed_size} it declares"
            )
        plain = stream.read(size)
        pos = 0
        while pos < size:
            if pos + 9 > size:
                raise SessionFormatError("record header cut off inside a chunk")
            op, length = struct.unpack_from("<BQ", plain, pos)
            if length > MAX_RECORD_BYTES:
                raise SessionFormatError(f"record of {length} bytes in a chunk exceeds the limit")
            body = plain[pos + 9 : pos + 9 + length]
            if len(body) != length:
                raise SessionFormatError("record runs past its chunk")
            kind = {0x04: Channel, 0x05: Message}.get(op)
            if kind is not None:
                rs = ReadDataStream(io.BytesIO(body))
                rec = kind.read(rs, length) if kind is Message else kind.read(rs)
                if rs.count != length:
                    raise SessionFormatError(f"bad {kind.__name__.lower()} record in a chunk")
                self.record(rec)
            pos += 9 + length

    # --- messages, by topic ---

    def _ticks(self, m):
        what = "tick block"
        first = _uint(_get(m, "first_tick", what), "first_tick")
        n = _uint(_get(m, "count", what), "count", 32)
        codec = _get(m, "codec", what)
        columns = _get(m, "columns", what)
        digest = m.get("outputs_digest")
        if codec == CODEC_EXACT:
            if digest is not None:
                raise SessionFormatError(f"a '{CODEC_EXACT}' block with an outputs digest")
        elif codec == CODEC_ROUNDED:
            if digest is None:
                raise SessionFormatError(f"a '{CODEC_ROUNDED}' block without its outputs digest")
            _uint(digest, "outputs_digest")
        else:
            raise SessionFormatError(f"unknown column codec '{str(codec)[:64]}'")
        if not 0 < n <= MAX_BLOCK_TICKS:
            raise SessionFormatError(f"block of {n} ticks")
        if first + n > U64 + 1:
            raise SessionFormatError("block tick numbers overflow")
        if not isinstance(columns, dict):
            raise SessionFormatError("tick block columns are not a map")

        def column(name):
            data = columns.get(name)
            if data is None:
                raise SessionFormatError(f"block at tick {first} lacks column '{name}'")
            if not isinstance(data, bytes):
                raise SessionFormatError(f"column '{name}' is not a byte string")
            return data

        cols = {c: decode_f64(column(c), n, c) for c in F64_COLUMNS}
        for i, c in enumerate(OUTPUT_COLUMNS):
            if codec == CODEC_ROUNDED:
                per = FORCE_STEPS_PER_N if i < 3 else TORQUE_STEPS_PER_NMM
                cols[c] = decode_steps(column(c), n, per, c)
            else:
                cols[c] = decode_f64(column(c), n, c)
        for c, width in INT_COLUMNS:
            cols[c] = decode_xor(column(c), width, n, c)
        ticks = range(first, first + n)
        self._check_poses(ticks, cols)
        if "hand2" in columns:
            present = decode_xor(column("hand2"), 1, n, "hand2")
            if any(p not in (0, 1) for p in present):
                raise SessionFormatError("column 'hand2' holds a value other than 0 or 1")
            hand = {c: decode_f64(column(c), n, c) for c in HAND2_F64_COLUMNS}
            hand["hand2_buttons"] = decode_xor(column("hand2_buttons"), 4, n, "hand2_buttons")
            hand = {c: [v for v, p in zip(hand[c], present) if p] for c in HAND2_COLUMNS}
            hand_ticks = [k for k, p in zip(ticks, present) if p]
            self._check_poses(hand_ticks, {k[len("hand2_"):]: hand[k] for k in HAND2_F64_COLUMNS})
        else:
            hand, hand_ticks = None, []
        if self.last_tick is not None and first <= self.last_tick:
            raise SessionFormatError(f"tick {first} after tick {self.last_tick}")
        self.last_tick = first + n - 1
        out = self.s.ticks
        out["tick"].extend(ticks)
        out["t_s"].extend(self.t(k) for k in ticks)
        for c in TICK_COLUMNS[2:]:
            out[c].extend(cols[c])
        if hand_ticks:
            h = self.s.second_hand
            h["tick"].extend(hand_ticks)
            h["t_s"].extend(self.t(k) for k in hand_ticks)
            for c in HAND2_COLUMNS:
                h[c].extend(hand[c])
        b = self.s.blocks
        b["first_tick"].append(first)
        b["count"].append(n)
        b["codec"].append(codec)
        b["outputs_digest"].append(digest)

    @staticmethod
    def _check_poses(ticks, c):
        pos = zip(c["pos_x_mm"], c["pos_y_mm"], c["pos_z_mm"])
        rot = zip(c["q_w"], c["q_x"], c["q_y"], c["q_z"])
        for tick, p, q in zip(ticks, pos, rot):
            if not all(map(math.isfinite, p)):
                raise SessionFormatError(f"tick {tick}: position {p} mm is not finite")
            if not all(map(math.isfinite, q)):
                raise SessionFormatError(f"tick {tick}: orientation {q} is not finite")
            if not any(q):
                raise SessionFormatError(f"tick {tick}: orientation is all zero")

    def _events(self, m):
        tick = _uint(_get(m, "tick", "event"), "event tick")
        what = f"event at tick {tick}"
        name = _text(_get(m, "name", what), f"{what}: name", MAX_NAME_CHARS)
        tool = m.get("tool")
        if tool is not None:
            _text(tool, f"{what}: tool", MAX_NAME_CHARS)
        gauge = None if m.get("gauge") is None else _uint(m["gauge"], f"{what}: gauge", 32)
        length = None if m.get("length_mm") is None else _real(m["length_mm"], f"{what}: length_mm")
        stylet = m.get("stylet_in")
        if stylet is not None and not isinstance(stylet, bool):
            raise SessionFormatError(f"{what}: stylet_in is not true/false")
        ml = None if m.get("ml") is None else _real(m["ml"], f"{what}: ml")
        wire = m.get("wire")
        if wire is not None:
            _text(wire, f"{what}: wire", MAX_NAME_CHARS)
        if name not in EVENT_NAMES:
            raise SessionFormatError(f"{what}: unknown event '{name}'")
        if name == "tool":
            if tool is None:
                raise SessionFormatError(f"{what}: tool event without a tool")
            if tool not in TOOLS:
                raise SessionFormatError(f"{what}: unknown tool '{tool}'")
            if tool == "needle":
                if gauge is None:
                    raise SessionFormatError(f"{what}: needle without gauge")
                _check_needle(gauge, length, what)
                if stylet is None:
                    raise SessionFormatError(f"{what}: needle without stylet state")
        if name == "tool2" and tool not in HAND2_TOOLS:
            raise SessionFormatError(f"{what}: the second hand cannot hold '{str(tool)[:64]}'")
        if name == "contrast-inject" and ml is None:
            raise SessionFormatError(f"{what}: contrast event without ml")
        size_fr = None if m.get("size_fr") is None else _uint(m["size_fr"], f"{what}: size_fr", 8)
        sizes = {"dilator-in": DILATOR_SIZES_FR, "catheter-in": CATHETER_SIZES_FR}.get(name)
        if sizes is not None and size_fr not in sizes:
            raise SessionFormatError(f"{what}: {name} of size {size_fr} F (sizes: {', '.join(map(str, sizes))})")
        if name == "wire-in":
            parts = (wire or "").split(" ")
            if len(parts) != 2 or parts[0] not in WIRE_DIAMETERS or parts[1] not in WIRE_TIPS:
                raise SessionFormatError(f"{what}: wire '{str(wire)[:40]}' is not \"<0.018|0.035> <j|straight>\"")
        e = self.s.events
        for k, v in zip(EVENT_COLUMNS, (tick, self.t(tick), name, tool, gauge, length, stylet, ml, wire, size_fr)):
            e[k].append(v)

    def _digests(self, m):
        tick = _uint(_get(m, "tick", "digest"), "digest tick")
        digest = _uint(_get(m, "digest", "digest"), f"digest at tick {tick}")
        d = self.s.digests
        for k, v in zip(DIGEST_COLUMNS, (tick, self.t(tick), digest, f"{digest:016x}")):
            d[k].append(v)

    def _annotations(self, m):
        tick = _uint(_get(m, "tick", "annotation"), "annotation tick")
        text = _text(_get(m, "text", "annotation"), f"annotation at tick {tick}", MAX_NOTE_CHARS)
        a = self.s.annotations
        for k, v in zip(ANNOTATION_COLUMNS, (tick, self.t(tick), text)):
            a[k].append(v)

    def _device_forces(self, m):
        what = "device-force block"
        first = _uint(_get(m, "first_tick", what), "first_tick")
        n = _uint(_get(m, "count", what), "count", 32)
        columns = _get(m, "columns", what)
        if not 0 < n <= MAX_DEVICE_FORCE_BLOCK_TICKS:
            raise SessionFormatError(f"device-force block of {n} ticks")
        if first + n > U64 + 1:
            raise SessionFormatError("device-force block tick numbers overflow")
        if not isinstance(columns, dict):
            raise SessionFormatError("device-force block columns are not a map")
        d = self.s.device_forces
        if d["tick"] and first <= d["tick"][-1]:
            raise SessionFormatError(f"device forces at tick {first} after tick {d['tick'][-1]}")

        def column(name):
            data = columns.get(name)
            if not isinstance(data, bytes):
                raise SessionFormatError(f"device-force block at tick {first} lacks byte column '{name}'")
            return data

        sent = [
            decode_steps(column(c), n, DEVICE_FORCE_STEPS_PER_N, c)
            for c in ("sent_x_n", "sent_y_n", "sent_z_n")
        ]
        flags = decode_xor(column("guard"), 1, n, "guard")
        if any(f > 0x7F for f in flags):
            raise SessionFormatError("device-force column 'guard' holds a value out of range")
        for i in range(n):
            tick = first + i
            x, y, z = sent[0][i], sent[1][i], sent[2][i]
            row = (tick, self.t(tick), x, y, z, math.sqrt(x * x + y * y + z * z)) + tuple(
                bool(flags[i] >> b & 1) for b in range(len(GUARD_FLAGS))
            )
            for k, v in zip(DEVICE_FORCE_COLUMNS, row):
                d[k].append(v)

    def _preview(self, m):
        tick = _uint(_get(m, "tick", "preview"), "preview tick")
        what = f"preview at tick {tick}"

        def vec3(key):
            v = _get(m, key, what)
            if not isinstance(v, list) or len(v) != 3:
                raise SessionFormatError(f"{what}: {key} is not 3 numbers")
            return [_real(x, f"{what}: {key}") for x in v]

        row = (
            tick,
            _real(_get(m, "t_s", what), f"{what}: t_s"),
            *vec3("position_mm"),
            *vec3("force_n"),
            _real(_get(m, "force_magnitude_n", what), f"{what}: force_magnitude_n"),
            _uint(_get(m, "tip_label", what), f"{what}: tip_label", 16),
            _real(_get(m, "inserted_mm", what), f"{what}: inserted_mm"),
        )
        p = self.s.previews
        for k, v in zip(PREVIEW_COLUMNS, row):
            p[k].append(v)


def read_session(path):
    """Reads a whole session file strictly. Raises SessionFormatError on any damage, including
    a file that ends without its summary and footer (a crashed or unfinished recording), and
    OSError when the file cannot be read."""
    size = os.path.getsize(path)
    if size > MAX_FILE_BYTES:
        raise SessionFormatError(f"{path}: {size} bytes exceed the limit of {MAX_FILE_BYTES}")
    with open(path, "rb") as f:
        data = f.read()
    try:
        return _read_bytes(data, path)
    except SessionFormatError as e:
        raise SessionFormatError(f"{path}: {e}") from e.__cause__


def _read_bytes(data, path):
    if not data.startswith(_MAGIC):
        raise SessionFormatError("not a Stylet session file: it does not start with the MCAP magic")
    s = Session(path)
    r = _Reader(s)
    src = io.BytesIO(data)
    stream = StreamReader(
        src, emit_chunks=True, validate_crcs=True, record_size_limit=MAX_RECORD_BYTES
    )
    first = True
    in_summary = False
    footer = None
    try:
        for rec in stream.records:
            if first:
                if not isinstance(rec, Header):
                    raise SessionFormatError("the first record is not an MCAP header")
                if rec.profile != PROFILE:
                    raise SessionFormatError(f"MCAP profile '{rec.profile[:64]}' is not '{PROFILE}'")
                s.profile, s.library = rec.profile, rec.library
                first = False
            elif isinstance(rec, Footer):
                footer = rec
            elif isinstance(rec, DataEnd):
                in_summary = True
            elif in_summary:
                pass  # indexes and statistics: nothing a reader needs
            elif isinstance(rec, Chunk):
                r.chunk(rec)
            else:
                r.record(rec)
    except SessionFormatError:
        raise
    except McapError as e:
        raise SessionFormatError(f"damaged session file (cut short?): {e}") from e
    except (ValueError, struct.error, EOFError, UnicodeDecodeError, KeyError) as e:
        # mcap's CRCValidationError is a ValueError; truncated records surface as struct errors.
        raise SessionFormatError(f"damaged session file: {type(e).__name__}: {e}") from e
    except Exception as e:  # zstandard.ZstdError, lz4 errors: a chunk that does not decompress
        raise SessionFormatError(f"damaged session file: {type(e).__name__}: {e}") from e
    if footer is None:
        raise SessionFormatError("the file ends without its summary and footer (cut short?)")
    if src.tell() != len(data):
        raise SessionFormatError("bytes after the footer's closing magic")
    if footer.summary_crc != 0:
        # The CRC covers the summary section through the footer's fields before the CRC, which
        # ends 12 bytes (CRC and closing magic) before the end of the file.
        crc_end = len(data) - 12
        start = footer.summary_start or crc_end - 8 - 8 - 9
        if zlib.crc32(data[start:crc_end]) != footer.summary_crc:
            raise SessionFormatError("summary CRC mismatch (the file was altered)")
    if s.tick_rate_hz is None:
        raise SessionFormatError("no session header")
    return s


# --- CSV and command line ------------------------------------------------------------------------


def _csv_value(v):
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    return v  # floats are written in repr's shortest round-trip form


def write_csv(table, out):
    """Writes a table (dict of columns) as CSV with a header row; `out` is a path or a text file.
    Floats in shortest round-trip form (parsing gives back the same float), booleans as
    true/false, missing values empty."""
    if isinstance(out, (str, os.PathLike)):
        with open(out, "w", newline="") as f:
            return write_csv(table, f)
    w = csv.writer(out, lineterminator="\n")
    w.writerow(list(table))
    for row in zip(*table.values()):
        w.writerow([_csv_value(v) for v in row])


def _summary(s):
    end = s.end or {}
    lines = [
        f"session   {s.header.get('session_id')} (schema {s.schema_version}, "
        f"physics {s.header.get('physics_version')}, {s.tick_rate_hz} Hz)",
        f"scenario  {s.scenario}  trainee {s.header.get('trainee')}  device {s.header.get('device')}",
        f"tool      {s.initial_tool()['tool']} at tick 0",
        f"ticks     {len(s.ticks['tick'])} ({s.duration_s:g} s) in {len(s.blocks['count'])} blocks "
        f"({', '.join(s.codec_versions) or 'none'})",
        f"events    {len(s.events['tick'])}  digests {len(s.digests['tick'])}  "
        f"annotations {len(s.annotations['tick'])}  previews {len(s.previews['tick'])}",
        f"end       {'complete' if end.get('complete') else 'incomplete'}: {end.get('reason')}"
        if s.end else "end       no end record",
    ]
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description="Read a Stylet session file (MCAP).")
    p.add_argument("session", help="the session file (.mcap)")
    p.add_argument("--csv", metavar="OUT.csv", help="write the ticks, one row per tick")
    p.add_argument("--events-csv", metavar="OUT.csv", help="write the events")
    a = p.parse_args(argv)
    try:
        s = read_session(a.session)
    except (SessionFormatError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    if a.csv:
        write_csv(s.ticks, a.csv)
    if a.events_csv:
        write_csv(s.events, a.events_csv)
    print(_summary(s))
    return 0


if __name__ == "__main__":
    sys.exit(main())
