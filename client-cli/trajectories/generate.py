#!/usr/bin/env python3
"""Writes the bundled block, inter-hemispheric and Sylvian trajectories (1 kHz poses;
sylvian-open-* are older and not written here).

Run from this folder: `python3 generate.py`. Output: CSV files with the header
`t_s,x_m,y_m,z_m,qw,qx,qy,qz` (s, m, unit quaternion w x y z); the pose is the
handle point of the instrument frame (origin at the base centre of the plate,
+z along the length to the tip, +x the outward normal of face A).

Moves are cosine-eased: s(u) = (1 - cos(pi u)) / 2 for u in [0, 1], so the
velocity is zero at both ends of every move. The exception is the fast-travel
case, which moves at a constant 0.375 m/s: 7.5 mm per 20 ms deformation step,
five times the 1.5 mm thickness of the valley scenes' plate.
"""

import math

RATE_HZ = 1000.0
TIP_DOWN = (0.0, 1.0, 0.0, 0.0)  # 180 deg about x: tip towards -z, face A +x


def ease(u):
    u = min(max(u, 0.0), 1.0)
    return 0.5 * (1.0 - math.cos(math.pi * u))


def qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def about_y(theta):
    return (math.cos(theta / 2), 0.0, math.sin(theta / 2), 0.0)


def rot_y(v, theta):
    c, s = math.cos(theta), math.sin(theta)
    return (c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2])


def write(name, duration_s, pose_at):
    n = int(round(duration_s * RATE_HZ))
    with open(f"{name}.csv", "w") as f:
        f.write("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n")
        for i in range(n + 1):
            t = i / RATE_HZ
            (x, y, z), q = pose_at(t)
            f.write(
                f"{t:.3f},{x:.7f},{y:.7f},{z:.7f},"
                f"{q[0]:.12f},{q[1]:.12f},{q[2]:.12f},{q[3]:.12f}\n"
            )


def segments(t, keys):
    """Piecewise eased interpolation of scalar keys [(t0, v0), (t1, v1), ...]."""
    if t <= keys[0][0]:
        return keys[0][1]
    for (t0, v0), (t1, v1) in zip(keys, keys[1:]):
        if t <= t1:
            return v0 + (v1 - v0) * ease((t - t0) / (t1 - t0))
    return keys[-1][1]


# Inter-hemispheric fissure: entry (0, 0, 0.058), 25 mm deep along -z, walls
# facing +-x 3 mm apart. Plate 1 mm thick, 30 mm long, home (0, 0, 0.093): tip
# 5 mm above the entry. Insert 20 mm (tip 15 mm deep), then push the +x wall
# 3 mm sideways with face A (2 mm beyond the 1 mm gap), hold.
def interhemispheric(t):
    z = segments(t, [(0.2, 0.093), (0.8, 0.073)])
    x = segments(t, [(0.9, 0.0), (1.5, 0.003)])
    return (x, 0.0, z), TIP_DOWN


write("interhemispheric-open-left", 2.0, interhemispheric)

# V valley: groove along y at x = 30 mm, 24 mm wide at the top (z = 30 mm),
# its bottom edge at z = 10 mm. Plate 1.5 mm thick, 30 mm long, home (0.030,
# 0.015, 0.065): tip at z = 35 mm. Insert the tip to z = 10.3 mm: the V is
# narrower than the plate below z = 11.25 mm, so both faces push both walls
# (up to 0.7 mm each at the tip), then hold.
V_TIP_LOW = 0.0103


def v_insert(t):
    z = segments(t, [(0.2, 0.065), (1.2, V_TIP_LOW + 0.030)])
    return (0.030, 0.015, z), TIP_DOWN


write("v-valley-insert-left", 1.6, v_insert)


# The fast-travel case: the same insertion at a constant 0.375 m/s (7.5 mm per
# 20 ms deformation step, 5 plate thicknesses), then hold.
def v_fast(t):
    start, z0, z1, v = 0.1, 0.065, V_TIP_LOW + 0.030, 0.375
    z = max(z1, z0 - v * max(0.0, t - start))
    return (0.030, 0.015, z), TIP_DOWN


write("v-valley-fast-left", 0.6, v_fast)

# U valley: the groove is a half-ellipse 24 mm wide and 20 mm deep (bottom at
# z = 10 mm). Insert the tip to z = 13 mm (no contact: the groove is 12.6 mm
# wide there), then rotate the plate about the groove axis (a line along y
# through the groove's top centre, (0.030, *, 0.030)) by -35 deg, so that the
# tip swings to +x and face A presses the +x wall, then through to +35 deg so
# that face B presses the -x wall, and back to upright.
PIVOT = (0.030, 0.015, 0.030)
U_TIP = 0.013
DEG = math.pi / 180.0


def u_rotate(t):
    z = segments(t, [(0.2, 0.065), (1.0, U_TIP + 0.030)])
    theta = segments(
        t,
        [(1.1, 0.0), (1.7, -35 * DEG), (2.0, -35 * DEG), (2.9, 35 * DEG), (3.2, 35 * DEG), (3.8, 0.0)],
    )
    handle = (0.030, 0.015, z)
    rel = tuple(h - p for h, p in zip(handle, PIVOT))
    r = rot_y(rel, theta)
    pos = tuple(p + d for p, d in zip(PIVOT, r))
    return pos, qmul(about_y(theta), TIP_DOWN)


write("u-valley-rotate-left", 4.0, u_rotate)


# Cube: the 40 mm block's top face is at z = 40 mm. The left plate lies flat,
# face A down (orientation (0.5, -0.5, 0.5, 0.5)), 1.5 mm thick: face A is at
# the handle's z - 0.75 mm; at home (0.011, 0.005, 0.04275) it is 2 mm above
# the top. Press face A 3 mm into the block over 0.5 s (handle z = 37.75 mm),
# hold 0.5 s, lift over 1 s back home: a frictionless elastic block pushes
# back at the same force at every depth on the way out as on the way in,
# until the plate leaves the rest surface (0.564 s into the lift).
CUBE_FLAT = (0.5, -0.5, 0.5, 0.5)
CUBE_HOME_Z = 0.04275
CUBE_PRESSED_Z = 0.04 + 0.00075 - 0.003


def cube_press_hold_retract(t):
    z = segments(t, [(0.0, CUBE_HOME_Z), (0.5, CUBE_PRESSED_Z), (1.0, CUBE_PRESSED_Z), (2.0, CUBE_HOME_Z)])
    return (0.011, 0.005, z), CUBE_FLAT


write("cube-press-hold-retract-left", 2.0, cube_press_hold_retract)


# Sylvian fissure with its arachnoid (scene sylvian-arachnoid): entry at
# x = -65.7 mm, walls facing +-z 3 mm apart, the fissure running along +x.
# Both instruments lie in the fissure's plane (tip along +x, face A +z) with
# their handles at (-100.7, 18, 0) mm at home (tip 5 mm outside the entry).
# The spatula is 1 mm thick: its face A meets the upper wall after 1 mm of
# lift. A session in three acts:
# 1. open against intact trabeculae: insert 20 mm, lift 2 mm (the upper
#    wall 1 mm), hold, lower back to the mid-plane;
# 2. cut: the blade enters 22 mm along the spatula's path (its tip edge
#    sweeps the trabeculae of that band) and withdraws;
# 3. open again to the same lift: the released wall takes less force.
SYL_HOME = (-0.1007, 0.018, 0.0)
SYL_ALONG_X = (0.0, 0.7071067811865476, 0.0, 0.7071067811865476)


def syl_spatula(t):
    x = segments(t, [(0.2, SYL_HOME[0]), (0.8, SYL_HOME[0] + 0.020)])
    z = segments(
        t,
        [(0.9, 0.0), (1.7, 0.002), (2.0, 0.002), (2.6, 0.0), (4.1, 0.0), (4.9, 0.002)],
    )
    return (x, SYL_HOME[1], z), SYL_ALONG_X


def syl_blade(t):
    x = segments(t, [(2.7, SYL_HOME[0]), (3.3, SYL_HOME[0] + 0.022), (3.4, SYL_HOME[0] + 0.022), (4.0, SYL_HOME[0])])
    return (x, SYL_HOME[1], 0.0), SYL_ALONG_X


# The careless opening: no cut, the spatula lifted 11 mm (the upper wall 10 mm)
# in 0.6 s and held: the trabeculae and a bridging vessel tear.
def syl_careless(t):
    x = segments(t, [(0.2, SYL_HOME[0]), (0.8, SYL_HOME[0] + 0.020)])
    z = segments(t, [(0.9, 0.0), (1.5, 0.011)])
    return (x, SYL_HOME[1], z), SYL_ALONG_X


write("sylvian-arachnoid-spatula", 5.2, syl_spatula)
write("sylvian-arachnoid-blade", 5.2, syl_blade)
write("sylvian-arachnoid-careless-spatula", 2.0, syl_careless)


# Sylvian fissure (scene sylvian), both spatulas (left at y = 18 mm lifting
# +z, right at y = 2 mm lowering -z), for the assessment's two sessions. The
# walls are 1.5 mm from the mid-plane and each plate 1 mm thick, so a lift
# of L pushes its wall L - 1 mm.
# * expert: insert 20 mm, open gently (lift 1.8 mm: 0.8 mm into each wall)
#   over 1 s, hold 1.1 s, close, withdraw;
# * careless: insert 25 mm (deeper) in 0.4 s, lift 9 mm (8 mm into each
#   wall) in 0.4 s, hold 2.9 s (longer), close, withdraw.
SYL_OPEN_HOME_X = -0.1007412


def syl_open(side, y, insert_keys, lift_keys):
    def pose_at(t):
        x = segments(t, [(k, SYL_OPEN_HOME_X + v) for k, v in insert_keys])
        z = side * segments(t, lift_keys)
        return (x, y, z), SYL_ALONG_X

    return pose_at


EXPERT_INSERT = [(0.2, 0.0), (0.8, 0.020), (3.7, 0.020), (4.3, 0.0)]
EXPERT_LIFT = [(0.9, 0.0), (1.9, 0.0018), (3.0, 0.0018), (3.6, 0.0)]
CARELESS_INSERT = [(0.2, 0.0), (0.6, 0.025), (4.4, 0.025), (4.9, 0.0)]
CARELESS_LIFT = [(0.7, 0.0), (1.1, 0.009), (4.0, 0.009), (4.3, 0.0)]
write("sylvian-expert-left", 4.4, syl_open(1.0, 0.018, EXPERT_INSERT, EXPERT_LIFT))
write("sylvian-expert-right", 4.4, syl_open(-1.0, 0.002, EXPERT_INSERT, EXPERT_LIFT))
write("sylvian-careless-left", 5.0, syl_open(1.0, 0.018, CARELESS_INSERT, CARELESS_LIFT))
write("sylvian-careless-right", 5.0, syl_open(-1.0, 0.002, CARELESS_INSERT, CARELESS_LIFT))
