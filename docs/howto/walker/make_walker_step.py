"""Write walker_step.csv: one step of RABBIT's default gait (the toolkit's reference gait
at 0.75 m/s) as a tool driving walker.urdf would log it, in the walker's own joint
angles: the torso's pitch, hip and knee angles per leg (zero: legs along +z of the torso
frame), the left leg in stance, and the torso frame's origin x, z.

The conversion is written out by hand here (it is the algebra the importer finds from
the URDF by itself): the walker's hip angle is the model's hip angle plus pi (its legs
point up at zero), its knee angle the model's; the model reads the stance leg from the
foot up, so its stance joints are the negatives.

    python docs/howto/walker/make_walker_step.py      # rewrites walker_step.csv
"""
from pathlib import Path

import numpy as np

from biped_casadi import robot
from gait_opt import optimize_gait

NODES = 41

m = robot("rabbit")
g = optimize_gait(m, cache=True)
t = np.linspace(0.0, g.T, NODES)
q, dq, _ = g.evaluate(t)
Lf, Lt = (link.length for link in m.description.leg)

cols = {"t": t}
for rate in ("", "d"):
    a = q if rate == "" else dq
    # q = (stance tibia absolute, stance knee, stance hip, swing hip, swing knee)
    cols[f"{rate}pitch"] = a[0] + a[1] + a[2]                # the torso's absolute angle
    cols[f"{rate}hip_left"] = (np.pi if rate == "" else 0.0) - a[2]     # stance leg
    cols[f"{rate}knee_left"] = -a[1]
    cols[f"{rate}hip_right"] = (np.pi if rate == "" else 0.0) + a[3]    # swing leg
    cols[f"{rate}knee_right"] = a[4]
phi1, phi2 = q[0], q[0] + q[1]
dphi1, dphi2 = dq[0], dq[0] + dq[1]
cols["x"] = Lt * np.sin(phi1) + Lf * np.sin(phi2)             # the torso frame's origin
cols["z"] = Lt * np.cos(phi1) + Lf * np.cos(phi2)             # is the hip
cols["dx"] = Lt * np.cos(phi1) * dphi1 + Lf * np.cos(phi2) * dphi2
cols["dz"] = -Lt * np.sin(phi1) * dphi1 - Lf * np.sin(phi2) * dphi2

order = ["t", "pitch", "hip_left", "knee_left", "hip_right", "knee_right", "dpitch",
         "dhip_left", "dknee_left", "dhip_right", "dknee_right", "x", "z", "dx", "dz"]
rows = np.column_stack([cols[c] for c in order])
text = ",".join(order) + "\n" + "\n".join(",".join(f"{v:.12g}" for v in r) for r in rows)
Path(__file__).with_name("walker_step.csv").write_text(text + "\n")
print(f"wrote walker_step.csv: {NODES} nodes, T = {g.T:.6f} s")
