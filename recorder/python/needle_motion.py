#!/usr/bin/env python3
"""PerkTutor's needle-motion metrics recomputed from a Stylet session file.

An independent check of `stylet score` (scoring/src/needle_motion.rs): it reads only the
recorded pose stream (device position = the rigid needle's tip, orientation: the needle's axis
is q·(0, 0, 1)), the recorded `inserted_mm` and the tool events, and follows PerkTutor's metric
scripts (github.com/PerkTutor/PythonMetrics: PathLength, TissuePath, TissueTime, TissueDamage on
branch Core; MotionSmoothness, DepthPerception, RotationalActions on master), as docs/metrics.md
"Needle motion (PerkTutor)" describes them:

- samples: the ticks with the needle in hand, intervals (tick − previous tick) / rate; another tool in hand ends the
  stream (its pose is not the needle's) and the next needle starts a new one;
- "in tissue": inserted_mm > 0 at the sample (PerkTutor: the tip inside the tissue surface);
- each sample adds its step from the previous one, counted by its own state.

    python3 needle_motion.py SESSION.mcap     # prints the metrics as JSON
"""

import json
import math
import sys

from stylet_session import SessionFormatError, read_session, tool_in_hand

ROTATION_SPEED_DEG_PER_S = 50.0
ACTION_MIN_S = 0.2


def _sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def _norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _axis(q):
    """(0, 0, 1) rotated by the unit quaternion q = (w, x, y, z): the rotation matrix's 3rd column."""
    w, x, y, z = q
    return [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]


def _rotation_deg(a, b):
    """Angle of the rotation b·a⁻¹ in degrees, folded to 0…180."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    # b · conj(a)
    w = bw * aw + bx * ax + by * ay + bz * az
    x = -bw * ax + bx * aw - by * az + bz * ay
    y = -bw * ay + bx * az + by * aw - bz * ax
    z = -bw * az - bx * ay + by * ax + bz * aw
    return math.degrees(2 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w)))


def _triangle(a, b, c):
    return 0.5 * _norm(_cross(_sub(b, a), _sub(c, a)))


def samples(session):
    """Per tick: None when another tool is in hand, else (tick, tip, q, inserted_mm)."""
    ticks = session.ticks
    tools = tool_in_hand(session)
    for i in range(len(ticks["tick"])):
        if tools["tool"][i] != "needle":
            yield None
            continue
        yield (
            ticks["tick"][i],
            [ticks["pos_x_mm"][i], ticks["pos_y_mm"][i], ticks["pos_z_mm"][i]],
            (ticks["q_w"][i], ticks["q_x"][i], ticks["q_y"][i], ticks["q_z"][i]),
            ticks["inserted_mm"][i],
        )


def needle_motion(session):
    """The metrics of a session read by stylet_session.read_session."""
    return needle_motion_of(samples(session), float(session.tick_rate_hz))


def needle_motion_of(stream, rate):
    """The metrics of a sample stream (see samples()) at `rate` ticks per second."""
    m = dict(
        path_length_mm=0.0,
        path_in_tissue_mm=0.0,
        path_outside_tissue_mm=0.0,
        time_in_tissue_s=0.0,
        tissue_damage_mm2=0.0,
        jerk_mm_per_s2_5=0.0,
        depth_perception_mm=0.0,
        reorientations=0,
    )
    squared_jerk = 0.0
    history = []  # newest first: (tick, p)
    prev = None
    action = None  # (moving, time of the last sample agreeing with it), in tissue only
    for s in stream:
        if s is None:
            prev, history, action = None, [], None
            continue
        tick, p, q, inserted = s
        inside = inserted > 0
        if prev is not None:
            ptick, pp, pq, pinserted = prev
            dt = (tick - ptick) / rate  # intervals from tick counts, exactly as the Rust side
            step = _norm(_sub(p, pp))
            m["path_length_mm"] += step  # PathLength
            if inside:  # TissuePath, TissueTime: the sample's own state
                m["path_in_tissue_mm"] += step
                m["time_in_tissue_s"] += dt
            else:
                m["path_outside_tissue_mm"] += step
            n = _axis(q)  # DepthPerception: along the current axis
            d = _sub(p, pp)
            m["depth_perception_mm"] += abs(d[0] * n[0] + d[1] * n[1] + d[2] * n[2])
            if inside and pinserted > 0:  # TissueDamage: both tips inside
                pn = _axis(pq)
                e = [p[k] - inserted * n[k] for k in range(3)]
                pe = [pp[k] - pinserted * pn[k] for k in range(3)]
                m["tissue_damage_mm2"] += _triangle(p, pp, e) + _triangle(e, pp, pe)
            if len(history) == 3:  # MotionSmoothness: backward differences, latest interval
                (k1, p1), (k2, p2), (k3, p3) = history
                d01, d12, d23 = (tick - k1) / rate, (k1 - k2) / rate, (k2 - k3) / rate
                v0 = [(p[k] - p1[k]) / d01 for k in range(3)]
                v1 = [(p1[k] - p2[k]) / d12 for k in range(3)]
                v2 = [(p2[k] - p3[k]) / d23 for k in range(3)]
                a0 = [(v0[k] - v1[k]) / d01 for k in range(3)]
                a1 = [(v1[k] - v2[k]) / d12 for k in range(3)]
                j = [(a0[k] - a1[k]) / d01 for k in range(3)]
                squared_jerk += (j[0] ** 2 + j[1] ** 2 + j[2] ** 2) * d01
            if not inside:  # RotationalActions, while in tissue
                action = None
            elif action is None:
                action = (False, tick)
            else:
                moving, since = action
                now = _rotation_deg(pq, q) / dt > ROTATION_SPEED_DEG_PER_S
                if now == moving:
                    action = (moving, tick)
                elif (tick - since) / rate > ACTION_MIN_S:
                    action = (now, tick)
                    if now:
                        m["reorientations"] += 1
        prev = s
        history = [(tick, p)] + history[:2]
    m["jerk_mm_per_s2_5"] = math.sqrt(squared_jerk)
    return m


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: needle_motion.py SESSION.mcap", file=sys.stderr)
        return 2
    try:
        session = read_session(argv[0])
    except (SessionFormatError, OSError) as e:
        print(f"needle_motion.py: {e}", file=sys.stderr)
        return 1
    print(json.dumps(needle_motion(session), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
