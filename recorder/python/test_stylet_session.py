"""Tests of stylet_session against the committed session fixtures and hand-made files.

Run from recorder/python: python3 -m unittest
"""

import csv
import io
import math
import os
import random
import struct
import tempfile
import unittest
from contextlib import redirect_stdout
from pathlib import Path

import cbor2
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

import stylet_session as ss
from stylet_session import SessionFormatError, read_session, rows, tool_in_hand

HERE = Path(__file__).resolve().parent
V1 = HERE.parent / "tests/fixtures/session-v1.mcap"
V2 = HERE.parent / "tests/fixtures/session-v2.mcap"
V3 = HERE.parent / "tests/fixtures/session-v3.mcap"
V4 = HERE.parent / "tests/fixtures/session-v4.mcap"
PHYSICS_V13 = HERE.parent.parent / "tests/fixtures/physics-v13"
PHYSICS_FILES = sorted(PHYSICS_V13.glob("*.mcap"))

M64 = (1 << 64) - 1


def bits(v):
    return struct.pack("<d", v)


def synthetic_ticks(n, seed):
    """recorder/tests/sessions.rs `synthetic_ticks`, which wrote both fixtures (the v1 one with
    every bit, the v2 one with forces and torques rounded): the same arithmetic in the same
    order, so the same f64 bits where the C library's exp and sin are those Rust used."""
    state = seed | 1

    def noise():
        nonlocal state
        state ^= (state << 13) & M64
        state ^= state >> 7
        state ^= (state << 17) & M64
        return (state >> 11) / float(1 << 53) - 0.5

    out = []
    for tick in range(n):
        t = tick / 1000.0
        depth = 60.0 * (1.0 - math.exp(-math.fmod(t, 60.0) / 20.0))
        tremor = 0.05 * math.sin(t * 2.0 * math.pi * 8.0) + 0.01 * noise()
        fx = 0.02 * depth + 0.05 * noise()
        fy = 0.01 * noise()
        out.append({
            "tick": tick,
            "pos_x_mm": 150.0 - depth + tremor,
            "pos_y_mm": 1.5 + 0.3 * depth + 0.5 * tremor,
            "pos_z_mm": 15.9 - 0.1 * depth,
            "q_w": 0.70710678,
            "q_x": 0.0,
            "q_y": -0.70710678 + 1e-4 * math.sin(t * 0.3),
            "q_z": 0.0,
            "buttons": tick // 5000 % 2,
            "force_x_n": fx,
            "force_y_n": fy,
            "force_z_n": -0.005 * depth,
            "torque_x_nmm": 0.0,
            "torque_y_nmm": 0.0,
            "torque_z_nmm": 0.0,
            "tip_label": 2 if depth < 3.0 else 3 if depth < 20.0 else 10,
            "inserted_mm": depth,
        })
    return out


def rounded(v, steps):
    return round(v * steps) / steps  # round(): ties to even, as the writer's round_ties_even


def output_digest(ticks):
    """FNV-1a 64 over each tick's exact force x, y, z then torque x, y, z (recorder/src/outputs.rs)."""
    h = 0xCBF29CE484222325
    for t in ticks:
        for c in ss.OUTPUT_COLUMNS:
            for b in bits(t[c]):
                h = ((h ^ b) * 0x100000001B3) & M64
    return h


def summary_counts(path):
    """Messages per topic from the file's summary statistics, read with the official mcap
    reader: an account of the file independent of stylet_session's walk."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    topics = {cid: ch.topic for cid, ch in summary.channels.items()}
    return {topics[cid]: n for cid, n in summary.statistics.channel_message_counts.items()}


# --- writing test files (the encoder side of recorder/src/codec.rs) ---------------------------


def shuffle(words, width):
    n = len(words)
    raw = struct.pack(f"<{n}{ss._WORD[width]}", *words)
    return b"".join(raw[b::width] for b in range(width))


def encode_xor(values, width):
    prev, out = 0, []
    for v in values:
        out.append(v ^ prev)
        prev = v
    return shuffle(out, width)


def encode_predicted(words):
    w1 = w2 = 0
    out = []
    for w in words:
        r = (w - ((2 * w1 - w2) & M64)) & M64
        r = r - (1 << 64) if r >> 63 else r  # as i64
        out.append(((r << 1) ^ (r >> 63)) & M64)
        w2, w1 = w1, w
    return shuffle(out, 8)


def encode_f64(values):
    return encode_predicted(struct.unpack(f"<{len(values)}Q", struct.pack(f"<{len(values)}d", *values)))


def encode_block(ticks, rounded_outputs=False):
    cols = {c: encode_f64([t[c] for t in ticks]) for c in ss.F64_COLUMNS}
    for i, c in enumerate(ss.OUTPUT_COLUMNS):
        if rounded_outputs:
            per = ss.FORCE_STEPS_PER_N if i < 3 else ss.TORQUE_STEPS_PER_NMM
            steps = [round(t[c] * per) & M64 for t in ticks]
            cols[c] = encode_predicted(steps)
        else:
            cols[c] = encode_f64([t[c] for t in ticks])
    for c, width in ss.INT_COLUMNS:
        cols[c] = encode_xor([t[c] for t in ticks], width)
    block = {
        "first_tick": ticks[0]["tick"],
        "count": len(ticks),
        "codec": ss.CODEC_ROUNDED if rounded_outputs else ss.CODEC_EXACT,
        "columns": cols,
    }
    if rounded_outputs:
        block["outputs_digest"] = output_digest(ticks)
    return block


HEADER = {
    "schema_version": "2", "session_id": "s-1", "trainee": "bob", "scenario": "made-up",
    "difficulty": "beginner", "atlas_id": "phantom", "atlas_hash": "ab" * 32,
    "software_version": "test", "physics_version": "10", "tick_rate_hz": "500", "seed": "1",
    "device": "premium", "tool": "needle", "tool_gauge": "20",
    "tool_length_mm_bits": bits(100.0)[::-1].hex(), "tool_stylet_in": "true",
    "wall_clock_start": "2026-12-01T00:00:00Z",
}


def write_file(path, messages, header=HEADER, compression=CompressionType.ZSTD, end=True):
    """A session file as the Rust writer lays it out; `messages` are (topic, tick, object)."""
    with open(path, "wb") as f:
        w = Writer(f, compression=compression)
        w.start(profile=ss.PROFILE, library="test")
        w.add_metadata(ss.META_HEADER, header)
        ids = {}
        for topic in ss.TOPICS:
            schema = w.register_schema(topic.replace("/", "."), "jsonschema", b"{}")
            ids[topic] = w.register_channel(topic, "cbor", schema)
        rate = int(header["tick_rate_hz"])
        for i, (topic, tick, obj) in enumerate(messages):
            t = tick * 10**9 // rate
            w.add_message(ids[topic], t, cbor2.dumps(obj), t, i)
        if end:
            n = sum(m[2]["count"] for m in messages if m[0] == ss.TOPIC_TICKS)
            w.add_metadata(ss.META_END, {"ticks": str(n), "dropped_ticks": "0",
                                         "complete": "true", "reason": "finished"})
        w.finish()


class Fixtures(unittest.TestCase):
    """The committed fixtures read back with the values their writers were given."""

    def test_v1_fixture_holds_every_bit(self):
        s = read_session(V1)
        self.assertEqual(s.schema_version, 1)
        self.assertEqual(s.codec_versions, [ss.CODEC_EXACT])
        self.assertEqual(s.header["trainee"], "alice")
        self.assertEqual(s.scenario, "ptcd-intercostal")
        want = synthetic_ticks(1500, 6)
        self.assertEqual(len(s.ticks["tick"]), 1500)
        for got, exp in zip(rows(s.ticks), want):
            for c, v in exp.items():
                self.assertEqual(bits(float(got[c])), bits(float(v)), f"tick {exp['tick']} {c}")
        # Exact: the first force z is -0 (-0.005 * 0.0), sign included.
        self.assertEqual(math.copysign(1.0, s.ticks["force_z_n"][0]), -1.0)

    def test_v3_fixture_holds_the_force_sent_to_the_device(self):
        s = read_session(V3)
        self.assertEqual(s.schema_version, 3)
        self.assertEqual(s.header["hardware.backend"], "dhd")
        d = s.device_forces
        self.assertEqual(d["tick"], list(range(1500)))
        for i in (0, 499, 1234):
            t = i * 1e-3
            # As the Rust test writes them: a smooth push, a guard flag now and then.
            self.assertAlmostEqual(d["sent_x_n"][i], 0.25 * math.sin(t), delta=2 ** -17)
            self.assertAlmostEqual(d["sent_z_n"][i], 1.5 * t, delta=2 ** -17)
            flags = i // 97 % 128
            for b, name in enumerate(ss.GUARD_FLAGS):
                self.assertEqual(d[name][i], bool(flags >> b & 1), f"tick {i} {name}")

    def test_v4_fixture_holds_the_second_hand(self):
        s = read_session(V4)
        self.assertEqual(s.schema_version, 4)
        self.assertEqual((s.header["hand2.device"], s.header["hand2.tool"]), ("touch", "probe-convex"))
        self.assertEqual(len(s.ticks["tick"]), 1200)
        # sessions.rs with_second_hand(…, 650): no second hand before tick 650, then a probe.
        t = s.second_hand
        self.assertEqual(t["tick"], list(range(650, 1200)))
        for i in (650, 999, 1199):
            x = i * 1e-3
            j = i - 650
            self.assertEqual(bits(t["hand2_pos_x_mm"][j]), bits(180.0 - 0.2 * x), f"tick {i}")
            self.assertEqual(bits(t["hand2_force_z_n"][j]), bits(-0.2))
            self.assertEqual(bits(t["hand2_torque_y_nmm"][j]), bits(2.0 * math.cos(x)), f"tick {i}")
            self.assertEqual(t["hand2_buttons"][j], i // 700 % 2)
        # One-handed files have an empty second-hand table.
        self.assertEqual(read_session(V3).second_hand["tick"], [])
        self.assertEqual(s.events["name"], ["tool2"])
        self.assertEqual(s.events["tool"], ["probe-convex"])

    def test_v2_fixture_holds_rounded_outputs_and_their_digests(self):
        s = read_session(V2)
        self.assertEqual(s.schema_version, 2)
        self.assertEqual(s.codec_versions, [ss.CODEC_ROUNDED])
        want = synthetic_ticks(1500, 6)
        for got, exp in zip(rows(s.ticks), want):
            for c, v in exp.items():
                if c in ss.OUTPUT_COLUMNS:
                    v = rounded(v, ss.FORCE_STEPS_PER_N if c.startswith("force") else ss.TORQUE_STEPS_PER_NMM)
                self.assertEqual(bits(float(got[c])), bits(float(v)), f"tick {exp['tick']} {c}")
        # Rounded, -0 is stored as +0.
        self.assertEqual(bits(s.ticks["force_z_n"][0]), bits(0.0))
        # sessions.rs: three blocks with rounded outputs, each pinning its exact outputs.
        self.assertEqual(s.blocks["count"], [500, 500, 500])
        for first, n, digest in zip(s.blocks["first_tick"], s.blocks["count"], s.blocks["outputs_digest"]):
            self.assertEqual(digest, output_digest(want[first:first + n]))

    def test_both_fixtures_have_the_events_and_digests_the_rust_tests_wrote(self):
        for path in (V1, V2):
            s = read_session(path)
            # sessions.rs write_session: contrast-inject 1.5 ml at ticks = 5 mod 10 000, a digest
            # (tick * 0x9E3779B97F4A7C15) after every tick = 99 mod 100.
            self.assertEqual(rows(s.events), [{
                "tick": 5, "t_s": 0.005, "name": "contrast-inject", "tool": None, "gauge": None,
                "length_mm": None, "stylet_in": None, "ml": 1.5, "wire": None, "size_fr": None,
            }])
            self.assertEqual(s.digests["tick"], list(range(99, 1500, 100)))
            self.assertEqual(s.digests["digest"], [(t * 0x9E3779B97F4A7C15) & M64 for t in range(99, 1500, 100)])
            self.assertEqual(s.digests["digest_hex"][0], f"{(99 * 0x9E3779B97F4A7C15) & M64:016x}")
            self.assertEqual(s.end, {"ticks": 1500, "dropped_ticks": 0, "complete": True, "reason": "finished"})
            self.assertEqual(s.annotations["tick"], [])
            self.assertEqual(s.initial_tool(), {
                "tool": "needle", "tool_gauge": 18, "tool_length_mm": 150.0, "tool_stylet_in": True,
            })
            self.assertEqual(s.profile, "stylet-session")

    def test_counts_match_the_summary_statistics(self):
        for path in [V1, V2, *PHYSICS_FILES]:
            with self.subTest(path=path.name):
                s = read_session(path)
                counts = summary_counts(path)
                n = len(s.ticks["tick"])
                self.assertEqual(n, s.end["ticks"])
                self.assertEqual(len(s.blocks["count"]), counts[ss.TOPIC_TICKS])
                self.assertEqual(sum(s.blocks["count"]), n)
                self.assertEqual(len(s.events["tick"]), counts.get(ss.TOPIC_EVENTS, 0))
                self.assertEqual(len(s.digests["tick"]), counts.get(ss.TOPIC_DIGESTS, 0))
                self.assertEqual(len(s.annotations["tick"]), counts.get(ss.TOPIC_ANNOTATIONS, 0))
                self.assertEqual(len(s.previews["tick"]), counts.get(ss.TOPIC_PREVIEW, 0))
                # The writer's rates: a preview every 20 ticks, a block per 500.
                self.assertEqual(s.previews["tick"], list(range(0, n, 20)))
                self.assertTrue(all(c <= 500 for c in s.blocks["count"]))

    def test_physics_fixtures_are_their_scripts(self):
        # The scripts beside them: "end 4" or "end 9" at 1 kHz; events at 6.3 s and 6.5 s.
        ends = {"finger-sweep": 4000, "probe-linear-across": 4000,
                "probe-convex-parallel": 4000, "needle-contrast": 9000}
        tools = {"finger-sweep": "finger", "probe-linear-across": "probe-linear",
                 "probe-convex-parallel": "probe-convex", "needle-contrast": "needle"}
        self.assertEqual(sorted(p.stem for p in PHYSICS_FILES), sorted(ends))
        for path in PHYSICS_FILES:
            with self.subTest(path=path.name):
                s = read_session(path)
                self.assertEqual(s.physics_version, 13)
                self.assertEqual(s.scenario, path.stem)
                self.assertEqual(s.tick_rate_hz, 1000)
                self.assertEqual(s.ticks["tick"], list(range(ends[path.stem])))
                self.assertEqual(s.initial_tool()["tool"], tools[path.stem])
                self.assertEqual(s.duration_s, ends[path.stem] / 1000)
                event_ticks = set(s.events["tick"])
                # Digests every 100 ticks and at every tick with events.
                self.assertEqual(set(s.digests["tick"]), set(range(99, ends[path.stem], 100)) | event_ticks)
        s = read_session(PHYSICS_V13 / "needle-contrast.mcap")
        self.assertEqual(s.events["name"], ["stylet-remove", "contrast-inject"])
        self.assertEqual(s.events["tick"], [6300, 6500])
        self.assertEqual(s.events["t_s"], [6.3, 6.5])
        self.assertEqual(s.events["ml"], [None, 2.0])

    def test_values_are_sane(self):
        for path in [V1, V2, *PHYSICS_FILES]:
            with self.subTest(path=path.name):
                s = read_session(path)
                t = s.ticks
                self.assertEqual(list(t), list(ss.TICK_COLUMNS))
                self.assertEqual({len(v) for v in t.values()}, {len(t["tick"])})
                self.assertEqual(t["tick"][0], 0)
                self.assertEqual(t["t_s"][0], 0.0)
                self.assertEqual(t["t_s"][1], 1 / s.tick_rate_hz)
                self.assertTrue(all(b - a == 1 for a, b in zip(t["tick"], t["tick"][1:])))
                self.assertTrue(all(b > a for a, b in zip(t["t_s"], t["t_s"][1:])))
                for c in ss.TICK_COLUMNS[2:]:
                    self.assertTrue(all(math.isfinite(v) for v in t[c]), c)
                # Near-unit quaternions as the device reported them (the synthetic poses wobble
                # by 1e-4 in one component).
                for q in zip(t["q_w"], t["q_x"], t["q_y"], t["q_z"]):
                    self.assertAlmostEqual(math.sqrt(sum(x * x for x in q)), 1.0, places=3)
                self.assertTrue(all(v >= 0 for v in t["inserted_mm"]))
                self.assertTrue(all(isinstance(v, int) for v in t["buttons"] + t["tip_label"]))

    def test_previews_are_f32_pictures_of_the_ticks(self):
        f32 = lambda v: struct.unpack("<f", struct.pack("<f", v))[0]  # noqa: E731
        for path in [V1, V2, *PHYSICS_FILES]:
            with self.subTest(path=path.name):
                s = read_session(path)
                p = s.previews
                for j, tick in enumerate(p["tick"]):
                    self.assertEqual(p["t_s"][j], f32(tick / s.tick_rate_hz))
                    for c in ("pos_x_mm", "pos_y_mm", "pos_z_mm", "inserted_mm"):
                        self.assertEqual(p[c][j], f32(s.ticks[c][tick]), c)
                    self.assertEqual(p["tip_label"][j], s.ticks["tip_label"][tick])
                    # The writer takes the preview's force from the exact output: within a
                    # rounding step (and the f32's precision) of a rounded block's value.
                    for c in ("force_x_n", "force_y_n", "force_z_n"):
                        self.assertLessEqual(abs(p[c][j] - s.ticks[c][tick]), 1e-4 + 1e-6 * abs(p[c][j]))

    def test_pandas_data_frame(self):
        try:
            import pandas
        except ImportError:
            self.skipTest("pandas is not installed (optional)")
        s = read_session(V2)
        df = pandas.DataFrame(s.ticks)
        self.assertEqual(df.shape, (1500, len(ss.TICK_COLUMNS)))
        self.assertEqual(df["tick"].dtype.kind, "i")
        self.assertEqual(df["pos_x_mm"].dtype.kind, "f")
        self.assertEqual(list(pandas.DataFrame(s.annotations).columns), list(ss.ANNOTATION_COLUMNS))
        self.assertEqual(len(pandas.DataFrame(s.events)), 1)

    def test_settings_decode_the_header(self):
        s = read_session(PHYSICS_V13 / "needle-contrast.mcap")
        st = s.settings()
        self.assertEqual(st["tool_length_mm"], 150.0)
        self.assertEqual(st["tick_rate_hz"], 1000)
        self.assertIs(st["tool_stylet_in"], True)
        self.assertEqual(st["world.contrast.front_fraction"], 0.5)
        self.assertEqual(st["world.breathing.model"], "synthetic")
        self.assertEqual(s.metadata[ss.META_HEADER], s.header)


class ToolInHand(unittest.TestCase):
    def test_stylet_removal_applies_from_its_tick(self):
        s = read_session(PHYSICS_V13 / "needle-contrast.mcap")
        tools = tool_in_hand(s)
        self.assertEqual(tools["tick"], s.ticks["tick"])
        stylet = tools["tool_stylet_in"]
        self.assertTrue(all(stylet[:6300]))
        self.assertFalse(any(stylet[6300:]))
        self.assertEqual(set(tools["tool"]), {"needle"})
        self.assertEqual(set(tools["tool_gauge"]), {18})

    def test_tool_changes_apply_from_the_event_tick(self):
        ticks = synthetic_ticks(30, 1)
        needle = {"tool": "needle", "gauge": 16, "length_mm": 200.0, "stylet_in": False}
        with tempfile.TemporaryDirectory() as d:
            p = os.path.join(d, "s.mcap")
            write_file(p, [
                (ss.TOPIC_EVENTS, 10, {"tick": 10, "name": "tool", "tool": "finger"}),
                (ss.TOPIC_EVENTS, 20, {"tick": 20, "name": "tool", **needle}),
                (ss.TOPIC_EVENTS, 20, {"tick": 20, "name": "stylet-insert"}),
                (ss.TOPIC_EVENTS, 25, {"tick": 25, "name": "xray-on"}),
                (ss.TOPIC_TICKS, 0, encode_block(ticks)),
            ])
            s = read_session(p)
        tools = tool_in_hand(s)
        self.assertEqual(tools["tool"], ["needle"] * 10 + ["finger"] * 10 + ["needle"] * 10)
        self.assertEqual(tools["tool_gauge"], [20] * 10 + [None] * 10 + [16] * 10)
        self.assertEqual(tools["tool_length_mm"], [100.0] * 10 + [None] * 10 + [200.0] * 10)
        # The tool event at 20 brings the stylet out; the insertion at the same tick comes after it.
        self.assertEqual(tools["tool_stylet_in"], [True] * 10 + [None] * 10 + [True] * 10)
        self.assertEqual(s.events["t_s"], [0.02, 0.04, 0.04, 0.05])


class HandMadeFiles(unittest.TestCase):
    """Files made here with the official mcap writer: what the reader accepts and refuses."""

    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.addCleanup(self.dir.cleanup)
        self.n = 0

    def write(self, messages, **kw):
        self.n += 1
        p = os.path.join(self.dir.name, f"s{self.n}.mcap")
        write_file(p, messages, **kw)
        return p

    def refused(self, messages, pattern, **kw):
        p = self.write(messages, **kw)
        with self.assertRaisesRegex(SessionFormatError, pattern):
            read_session(p)

    def test_blocks_of_both_codecs_with_a_gap_and_lz4(self):
        ticks = synthetic_ticks(40, 3)
        for t in ticks[:10]:
            t["force_y_n"] = float.fromhex("0x1.123456789abcdp-3")  # bits a rounded block would lose
        ticks[12]["buttons"] = 0xFFFFFFFF
        ticks[13]["tip_label"] = 0xFFFF
        ticks[14]["pos_x_mm"] = -0.0
        blocks = [ticks[:10], ticks[10:25], ticks[30:]]
        for compression in (CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE):
            with self.subTest(compression=compression):
                p = self.write([
                    (ss.TOPIC_TICKS, 0, encode_block(blocks[0])),
                    (ss.TOPIC_TICKS, 10, encode_block(blocks[1], rounded_outputs=True)),
                    (ss.TOPIC_TICKS, 30, encode_block(blocks[2], rounded_outputs=True)),
                    (ss.TOPIC_ANNOTATIONS, 31, {"tick": 31, "text": "a note, with \"quotes\"\nand a line"}),
                ], compression=compression)
                s = read_session(p)
                self.assertEqual(s.ticks["tick"], list(range(25)) + list(range(30, 40)))
                self.assertEqual(s.blocks["codec"], [ss.CODEC_EXACT, ss.CODEC_ROUNDED, ss.CODEC_ROUNDED])
                self.assertEqual(s.ticks["t_s"][-1], 39 / 500)
                got = rows(s.ticks)
                for g, exp in zip(got, blocks[0] + blocks[1] + blocks[2]):
                    for c, v in exp.items():
                        if c in ss.OUTPUT_COLUMNS and g["tick"] >= 10:
                            v = rounded(v, ss.FORCE_STEPS_PER_N if c[0] == "f" else ss.TORQUE_STEPS_PER_NMM)
                        self.assertEqual(bits(float(g[c])), bits(float(v)), f"{g['tick']} {c}")
                self.assertEqual(s.annotations["text"], ["a note, with \"quotes\"\nand a line"])

    def test_refused(self):
        t = synthetic_ticks(10, 2)
        block = encode_block(t)
        cases = [
            ({**block, "codec": "stylet-columns-v9"}, "unknown column codec"),
            ({**block, "outputs_digest": 1}, "with an outputs digest"),
            ({**encode_block(t, True), "outputs_digest": None}, "without its outputs digest"),
            ({**block, "count": 11}, "column '.*' has 80 bytes, not 88"),
            ({**block, "count": 0}, "block of 0 ticks"),
            ({**block, "columns": {k: v for k, v in block["columns"].items() if k != "q_w"}}, "lacks column 'q_w'"),
            ({**block, "columns": {**block["columns"], "pos_y_mm": "text"}}, "not a byte string"),
            ({**block, "first_tick": -1}, "first_tick"),
            ({**block, "first_tick": True}, "first_tick"),
            (encode_block([dict(x, pos_z_mm=math.nan) for x in t]), "position .* is not finite"),
            (encode_block([dict(x, q_w=0.0, q_y=0.0) for x in t]), "orientation is all zero"),
        ]
        big = encode_block(t, True)
        big["columns"]["force_x_n"] = encode_predicted([1 << 53] + [0] * 9)
        cases.append((big, "step count out of range"))
        for bad, pattern in cases:
            with self.subTest(pattern=pattern):
                self.refused([(ss.TOPIC_TICKS, 0, bad)], pattern)
        # Blocks out of order.
        self.refused([(ss.TOPIC_TICKS, 0, block), (ss.TOPIC_TICKS, 5, encode_block(t[5:]))], "tick 5 after tick 9")
        for event, pattern in [
            ({"tick": 1, "name": "sneeze"}, "unknown event 'sneeze'"),
            ({"tick": 1, "name": "tool"}, "tool event without a tool"),
            ({"tick": 1, "name": "tool", "tool": "scalpel"}, "unknown tool"),
            ({"tick": 1, "name": "tool", "tool": "needle", "gauge": 17, "length_mm": 1.0, "stylet_in": True}, "gauge 17"),
            ({"tick": 1, "name": "tool", "tool": "needle", "gauge": 18, "length_mm": -1.0, "stylet_in": True}, "valid length"),
            ({"tick": 1, "name": "contrast-inject"}, "without ml"),
            ({"tick": 1, "name": "wire-in", "wire": "0.038 j"}, "is not \"<0.018|0.035> <j|straight>\""),
            ({"tick": 1, "name": "wire-in"}, "wire 'None' is not"),
            ({"tick": 1, "name": "dilator-in"}, "dilator-in of size None F"),
            ({"tick": 1, "name": "dilator-in", "size_fr": 7}, "dilator-in of size 7 F \\(sizes: 6, 8, 10, 12\\)"),
            ({"tick": 1, "name": "catheter-in", "size_fr": 12}, "catheter-in of size 12 F"),
            ({"tick": 1, "name": "catheter-in", "size_fr": 300}, "not an unsigned 8-bit"),
            ({"tick": 1, "name": "x" * 65}, "longer than 64"),
            ({"name": "xray-on"}, "lacks 'tick'"),
            ([1, 2], "not a CBOR map"),
        ]:
            with self.subTest(event=event):
                self.refused([(ss.TOPIC_EVENTS, 1, event), (ss.TOPIC_TICKS, 0, block)], pattern)
        self.refused([(ss.TOPIC_ANNOTATIONS, 1, {"tick": 1, "text": "x" * 2001})], "longer than 2000")
        self.refused([(ss.TOPIC_DIGESTS, 1, {"tick": 1, "digest": 1 << 64})], "not an unsigned 64-bit")
        self.refused([(ss.TOPIC_PREVIEW, 1, {"tick": 1, "t_s": 0.0})], "preview at tick 1 lacks")

    def test_headers_refused(self):
        for change, pattern in [
            ({"schema_version": "5"}, "schema version 5"),
            ({"hand2.device": "touch"}, "lacks 'hand2.tool'"),
            ({"hand2.device": "touch", "hand2.tool": "needle"}, "cannot hold 'needle'"),
            ({"schema_version": "x"}, "not a number"),
            ({"tick_rate_hz": "0"}, "tick_rate_hz 0 is out of range"),
            ({"tool": "spoon"}, "unknown tool 'spoon'"),
            ({"tool_gauge": "17"}, "gauge 17"),
        ]:
            with self.subTest(change=change):
                self.refused([], pattern, header={**HEADER, **change})
        header = dict(HEADER)
        del header["scenario"]
        self.refused([], "lacks 'scenario'", header=header)

    def test_a_file_without_an_end_record_reads(self):
        s = read_session(self.write([(ss.TOPIC_TICKS, 0, encode_block(synthetic_ticks(3, 1)))], end=False))
        self.assertIsNone(s.end)
        self.assertEqual(len(s.ticks["tick"]), 3)


class Damage(unittest.TestCase):
    """Damaged files raise SessionFormatError, never anything else and never return garbage."""

    def check_refused(self, data, what):
        with tempfile.TemporaryDirectory() as d:
            p = os.path.join(d, "s.mcap")
            with open(p, "wb") as f:
                f.write(data)
            try:
                read_session(p)
            except SessionFormatError as e:
                self.assertIn(p, str(e))
                return str(e)
            self.fail(f"{what}: read without an error")

    def offsets(self, n):
        rng = random.Random(7)
        return sorted({*range(0, n, 4096), *rng.sample(range(n), 60), 1, 8, 9, n - 1, n - 8, n - 12, n - 20})

    def test_truncated_files(self):
        data = V2.read_bytes()
        for cut in self.offsets(len(data)):
            with self.subTest(cut=cut):
                self.check_refused(data[:cut], f"cut at {cut}")
        e = self.check_refused(data[: len(data) // 2], "half")
        self.assertRegex(e, "cut short|damaged")

    def test_bit_flips(self):
        for path in (V1, PHYSICS_V13 / "needle-contrast.mcap"):
            data = path.read_bytes()
            for off in self.offsets(len(data)):
                with self.subTest(path=path.name, offset=off):
                    flipped = bytearray(data)
                    flipped[off] ^= 0x10
                    self.check_refused(bytes(flipped), f"flip at {off}")

    def test_garbage(self):
        e = self.check_refused(b"", "empty")
        self.assertIn("magic", e)
        self.check_refused(b"hello world, not mcap", "text")
        # A record claiming 2^60 bytes right after the magic.
        self.check_refused(b"\x89MCAP0\r\n\x01" + (1 << 60).to_bytes(8, "little"), "huge record")
        self.check_refused(V2.read_bytes() + b"\0", "a byte after the closing magic")

    def test_crc_mismatches_are_named(self):
        data = bytearray(V2.read_bytes())
        with open(V2, "rb") as f:
            summary = make_reader(f).get_summary()
        chunk = summary.chunk_indexes[1]
        # A byte inside a chunk's compressed records, and one inside the summary.
        data[chunk.chunk_start_offset + chunk.chunk_length - 20] ^= 1
        e = self.check_refused(bytes(data), "chunk byte")
        self.assertRegex(e, "crc|CRC|decompress|damaged")
        data = bytearray(V2.read_bytes())
        footer_start = len(data) - 8 - 29
        data[footer_start - 3] ^= 1
        e = self.check_refused(bytes(data), "summary byte")
        self.assertIn("summary CRC", e)


class CommandLine(unittest.TestCase):
    def test_csv_output_parses_back(self):
        with tempfile.TemporaryDirectory() as d:
            ticks_csv = os.path.join(d, "ticks.csv")
            events_csv = os.path.join(d, "events.csv")
            out = io.StringIO()
            with redirect_stdout(out):
                rc = ss.main([str(PHYSICS_V13 / "needle-contrast.mcap"), "--csv", ticks_csv, "--events-csv", events_csv])
            self.assertEqual(rc, 0)
            self.assertIn("9000", out.getvalue())
            s = read_session(PHYSICS_V13 / "needle-contrast.mcap")
            with open(ticks_csv, newline="") as f:
                r = list(csv.DictReader(f))
            self.assertEqual(list(r[0]), list(ss.TICK_COLUMNS))
            self.assertEqual(len(r), 9000)
            for c in ss.TICK_COLUMNS:
                conv = int if c in ("tick", "buttons", "tip_label") else float
                # Shortest round-trip form: every value parses back to the same number.
                self.assertEqual([conv(row[c]) for row in r], s.ticks[c], c)
            with open(events_csv, newline="") as f:
                ev = list(csv.DictReader(f))
            self.assertEqual(list(ev[0]), list(ss.EVENT_COLUMNS))
            self.assertEqual([(e["tick"], e["name"], e["ml"]) for e in ev],
                             [("6300", "stylet-remove", ""), ("6500", "contrast-inject", "2.0")])

    def test_bad_file_exits_1(self):
        err = io.StringIO()
        from contextlib import redirect_stderr
        with redirect_stderr(err), redirect_stdout(io.StringIO()):
            rc = ss.main([__file__])
        self.assertEqual(rc, 1)
        self.assertIn("MCAP magic", err.getvalue())


if __name__ == "__main__":
    unittest.main()
