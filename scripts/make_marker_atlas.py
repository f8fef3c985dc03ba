#!/usr/bin/env python3
"""Print the humanoid landmark atlas of ``lacore.markers.marker_sets`` from the CC0 sample body.

Every landmark is placed on the sample body (``lacore.samples.human``, rest pose) by a ray
from a point on a bone (``head + s (tail - head) + lift``) along a direction (``+x`` the
body's left, ``+y`` up, ``+z`` forward) to the first skin it meets (faces skinned to the
listed bones); regions (marker clusters) are a centre inside the limb and a radius.  The
printed table holds the points in the atlas frame: origin on the floor below the centre of
the body's bounding box, unit = the body's height, axes (left, up, forward).

usage: python scripts/make_marker_atlas.py  (paste the output into lacore/markers/marker_sets.py)
"""

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from lacore.markers.binding import closest_surface_points
from lacore.samples.human import load_human

# name -> (bones, s, direction, lift); "L" names get a mirrored "R" twin
CENTRE = {
    "HEAD_TOP": (("Head",), 1.0, (0, 1, 0), (0, 0, 0)),
    "HEAD_FRONT": (("Head",), 0.45, (0, 0.3, 1), (0, 0, 0)),
    "HEAD_BACK": (("Head",), 0.45, (0, 0.3, -1), (0, 0, 0)),
    "C7": (("Neck", "Spine1"), 0.0, (0, 0.3, -1), (0, 0, 0)),
    "T10": (("Spine", "LowerBack"), 0.5, (0, 0, -1), (0, 0, 0)),
    "CLAV": (("Spine1", "Neck"), 0.95, (0, 0.2, 1), (0, 0, 0)),
    "STRN": (("Spine1", "Spine"), 0.2, (0, 0, 1), (0, 0, 0)),
    "SACR": (("LowerBack", "Hips", "LHipJoint", "RHipJoint"), 0.1, (0, 0.2, -1), (0, 0, 0)),
}
LEFT = {
    "LFHD": (("Head",), 0.55, (0.5, 0, 1), (0, 0, 0)),
    "LBHD": (("Head",), 0.55, (0.5, 0, -1), (0, 0, 0)),
    "LBAK": (("LeftShoulder", "Spine1"), 0.5, (0, 0, -1), (0, 0, 0)),
    "LASI": (("LHipJoint", "Hips", "LowerBack", "LeftUpLeg"), 0.8, (0.3, 0.1, 1), (0, 0.45, 0)),
    "LPSI": (("LHipJoint", "Hips", "LowerBack", "LeftUpLeg"), 0.4, (0.1, 0.1, -1), (0, 0.6, 0)),
    "LGRT": (("LeftUpLeg", "LHipJoint", "Hips"), 0.05, (1, 0, 0), (0, 0, 0)),
    "LSHO": (("LeftShoulder", "LeftArm"), 0.95, (0.2, 1, 0), (0, 0, 0)),
    "LUPA": (("LeftArm",), 0.5, (1, 0.6, -0.3), (0, 0, 0)),
    "LELB": (("LeftArm", "LeftForeArm"), 1.0, (0.3, 0, -1), (0, 0, 0)),
    "LFRM": (("LeftForeArm",), 0.5, (1, 0.3, 0), (0, 0, 0)),
    "LWRA": (("LeftForeArm", "LeftHand"), 1.0, (0, 1, 0), (0, 0, 0)),
    "LWRB": (("LeftForeArm", "LeftHand"), 1.0, (0, -1, 0), (0, 0, 0)),
    "LWRI": (("LeftForeArm", "LeftHand"), 1.0, (1, 0.5, 0), (0, 0, 0)),
    "LFIN": (("LeftHand", "LeftFingerBase"), 1.0, (0.2, 1, 0), (0, 0, 0)),
    "LTHI": (("LeftUpLeg",), 0.5, (1, 0, 0.2), (0, 0, 0)),
    "LTHAP": (("LeftUpLeg",), 0.3, (0.5, 0, 1), (0, 0, 0)),
    "LTHAD": (("LeftUpLeg",), 0.7, (0.5, 0, 1), (0, 0, 0)),
    "LKNE": (("LeftUpLeg", "LeftLeg"), 1.0, (1, 0, 0), (0, 0, 0)),
    "LMKN": (("LeftUpLeg", "LeftLeg"), 1.0, (-1, 0, 0), (0, 0, 0)),
    "LTTB": (("LeftLeg",), 0.1, (0, 0, 1), (0, 0, 0)),
    "LTIB": (("LeftLeg",), 0.5, (1, 0, 0.3), (0, 0, 0)),
    "LTIAP": (("LeftLeg",), 0.3, (0.4, 0, 1), (0, 0, 0)),
    "LTIAD": (("LeftLeg",), 0.7, (0.4, 0, 1), (0, 0, 0)),
    "LANK": (("LeftLeg", "LeftFoot"), 1.0, (1, 0, 0), (0, 0, 0)),
    "LMMA": (("LeftLeg", "LeftFoot"), 1.0, (-1, 0, 0), (0, 0, 0)),
    "LHEE": (("LeftFoot", "LeftLeg"), 0.0, (0, -0.2, -1), (0, 0, 0)),
    "LTOE": (("LeftFoot", "LeftToeBase"), 0.95, (0, 1, 0.3), (0, 0, 0)),
    "LFMH": (("LeftFoot", "LeftToeBase"), 0.9, (-1, 0.2, 0.2), (0, 0, 0)),
    "LVMH": (("LeftFoot", "LeftToeBase"), 0.8, (1, 0, 0), (0, 0, 0)),
    "LPM1": (("LeftFoot",), 0.45, (-1, 0.5, 0), (0, 0, 0)),
    "LDFT": (("LeftToeBase", "LeftFoot"), 1.0, (0, 0, 1), (0, 0, 0)),
}
# regions of marker clusters: bone whose middle is the centre, radius in bone lengths
REGIONS_LEFT = {"LTHIGH": ("LeftUpLeg", 0.6), "LSHANK": ("LeftLeg", 0.6), "LFOOT": ("LeftFoot", 0.9),
                "LARM": ("LeftArm", 0.6), "LFOREARM": ("LeftForeArm", 0.6)}
REGIONS_CENTRE = {"PELVIS": ("LowerBack", 1.4), "HEAD": ("Head", 0.8), "TRUNK": ("Spine", 1.2)}


def mirror_bone(b):
    if b.startswith("Left"):
        return "Right" + b[4:]
    return "RHip" + b[4:] if b.startswith("LHip") else b


def ray_hit(X, F, origin, direction):
    A, B, C = X[F[:, 0]], X[F[:, 1]], X[F[:, 2]]
    e1, e2 = B - A, C - A
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - A
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    if not hit.any():
        return None
    i = np.flatnonzero(hit)[np.argmin(t[hit])]
    return (1 - u[i] - v[i]) * A[i] + u[i] * B[i] + v[i] * C[i]


def main():
    body = load_human()
    X, F = body.vertices, body.faces
    index = {b: i for i, b in enumerate(body.bones)}
    face_bone = body.vertex_bone[F]
    lo, hi = X.min(0), X.max(0)
    height = hi[1] - lo[1]
    origin = np.array([0.5 * (lo[0] + hi[0]), lo[1], 0.5 * (lo[2] + hi[2])])
    specs = dict(CENTRE)
    for k, (bones, s, d, lift) in LEFT.items():
        specs[k] = (bones, s, d, lift)
        specs["R" + k[1:]] = (tuple(mirror_bone(b) for b in bones), s, (-d[0], d[1], d[2]),
                              (-lift[0], lift[1], lift[2]))
    print("LANDMARKS = {")
    for name, (bones, s, d, lift) in specs.items():
        b0 = index[bones[0]]
        p = body.heads[b0] + s * (body.tails[b0] - body.heads[b0]) + np.asarray(lift, float)
        d = np.asarray(d, float) / np.linalg.norm(d)
        cand = np.flatnonzero(np.isin(face_bone, [index[b] for b in bones]).any(1))
        q = ray_hit(X, F[cand], p, d)
        if q is None:
            q = closest_surface_points(X, F[cand], (p + 2.0 * d)[None])[0][0]
        a = np.round((q - origin) / height, 4) + 0.0
        print(f'    "{name}": ({a[0]:+.4f}, {a[1]:+.4f}, {a[2]:+.4f}),')
    print("}")
    regions = dict(REGIONS_CENTRE)
    for k, (b, r) in REGIONS_LEFT.items():
        regions[k] = (b, r)
        regions["R" + k[1:]] = (mirror_bone(b), r)
    print("REGIONS = {")
    for name, (bone, r) in regions.items():
        b0 = index[bone]
        c = 0.5 * (body.heads[b0] + body.tails[b0])
        a = np.round((c - origin) / height, 4) + 0.0
        rad = r * np.linalg.norm(body.tails[b0] - body.heads[b0]) / height
        print(f'    "{name}": (({a[0]:+.4f}, {a[1]:+.4f}, {a[2]:+.4f}), {rad:.4f}),')
    print("}")


if __name__ == "__main__":
    main()
