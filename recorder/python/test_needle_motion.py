"""Hand-computed checks of needle_motion.py's PerkTutor metrics on synthetic sample streams
(tick, tip, quaternion (w, x, y, z), inserted_mm) at 1 kHz."""

import math
import unittest

import contextlib
import io
import os
import tempfile

from needle_motion import _rotation_deg, main, needle_motion_of

RATE = 1000.0
IDENTITY = (1.0, 0.0, 0.0, 0.0)


def about_x(angle):
    return (math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0)


class HandComputed(unittest.TestCase):
    def test_straight_push(self):
        # 0.1 mm a tick along the axis (+z): 10 ticks outside, then 20 in tissue.
        stream = [(i, [0.0, 0.0, 0.1 * i], IDENTITY, max(0.1 * i - 1.0, 0.0)) for i in range(31)]
        m = needle_motion_of(stream, RATE)
        self.assertAlmostEqual(m["path_length_mm"], 3.0, places=12)
        self.assertAlmostEqual(m["path_in_tissue_mm"], 2.0, places=12)
        self.assertAlmostEqual(m["path_outside_tissue_mm"], 1.0, places=12)
        self.assertAlmostEqual(m["time_in_tissue_s"], 0.020, places=12)
        self.assertAlmostEqual(m["depth_perception_mm"], 3.0, places=12)
        self.assertAlmostEqual(m["tissue_damage_mm2"], 0.0, places=9)

    def test_lateral_shift_sweeps_shift_times_depth(self):
        # 40 mm in, 5 mm sideways in 50 ticks: a 5 × 40 mm parallelogram, no axial motion.
        stream = [(i, [0.1 * i, 0.0, 40.0], IDENTITY, 40.0) for i in range(51)]
        m = needle_motion_of(stream, RATE)
        self.assertAlmostEqual(m["tissue_damage_mm2"], 200.0, places=9)
        self.assertAlmostEqual(m["depth_perception_mm"], 0.0, places=12)

    def test_jerk_of_a_start_and_a_stop(self):
        # Rest, 100 mm/s for 100 ticks, rest: sqrt(4 v² / Δt³).
        v, dt = 100.0, 1e-3
        x = lambda i: v * dt * (min(max(i, 10), 110) - 10)
        m = needle_motion_of([(i, [x(i), 0.0, 0.0], IDENTITY, 0.0) for i in range(200)], RATE)
        self.assertAlmostEqual(m["jerk_mm_per_s2_5"] / math.sqrt(4 * v * v / dt**3), 1.0, places=9)

    def test_one_rotational_action_in_tissue(self):
        # 300 ms still, 400 ms at 100 °/s, then still; in tissue: one action. Out of tissue: none.
        step = math.radians(0.1)
        angle = lambda i: step * (min(max(i, 300), 700) - 300)
        inside = [(i, [0.0, 0.0, 30.0], about_x(angle(i)), 30.0) for i in range(1200)]
        self.assertEqual(needle_motion_of(inside, RATE)["reorientations"], 1)
        outside = [(i, [0.0, 0.0, 0.0], about_x(angle(i)), 0.0) for i in range(1200)]
        self.assertEqual(needle_motion_of(outside, RATE)["reorientations"], 0)

    def test_another_tool_ends_the_stream(self):
        stream = [(i, [float(i), 0.0, 0.0], IDENTITY, 0.0) for i in range(5)]
        stream += [None] + [(i, [50.0 + i, 0.0, 0.0], IDENTITY, 0.0) for i in range(6, 10)]
        self.assertAlmostEqual(needle_motion_of(stream, RATE)["path_length_mm"], 7.0, places=12)

    def test_rotation_angles(self):
        self.assertAlmostEqual(_rotation_deg(IDENTITY, about_x(math.pi)), 180.0, places=9)
        self.assertAlmostEqual(_rotation_deg(about_x(0.3), about_x(0.3 + 1e-7)), math.degrees(1e-7), places=15)
        q = about_x(0.3)
        self.assertAlmostEqual(_rotation_deg(q, tuple(-c for c in q)), 0.0, places=12)


class BadInput(unittest.TestCase):
    def test_a_file_that_is_not_a_session_is_named_and_refused(self):
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "garbage.mcap")
            with open(path, "wb") as f:
                f.write(b"not a session at all")
            err = io.StringIO()
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()) as out:
                self.assertEqual(main([path]), 1)
            self.assertIn("garbage.mcap", err.getvalue())
            self.assertEqual(out.getvalue(), "")
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                self.assertEqual(main([os.path.join(d, "missing.mcap")]), 1)


if __name__ == "__main__":
    unittest.main()
