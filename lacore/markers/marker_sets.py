"""Standard marker-set names as hints for a humanoid: an atlas of anatomical landmarks and cluster regions.

Motion-capture labs name markers by conventions (Plug-in Gait full and lower body,
Helen Hayes, CGM 2.x, Cleveland-style static sets, CAST-style clusters on thigh, shank,
foot and pelvis).  :func:`match_label` maps a label to a canonical landmark (``LASI``,
``RKNE``, ``HEAD_TOP``...) or, for cluster markers (``RTH1..4``, ``LSK2``, ``PV3``), to a
region; :func:`place_hints` puts them on a humanoid model's reference mesh.

The atlas (:data:`LANDMARKS`, :data:`REGIONS`) holds the landmarks of the CC0 sample
body in a normalized frame: origin on the floor below the centre of the body's bounding
box, unit = the body's height, axes (left, up, forward).  On another humanoid mesh in a
similar rest pose (A- or T-pose, facing ``forward``) a landmark is the surface point
nearest to the atlas point scaled to that mesh; for the sample body it is the landmark
itself.  Made by ``scripts/make_marker_atlas.py`` (rays from the skeleton to the skin).

Hints seed the calibration (:mod:`lacore.markers.calibration`): a rough placement, the
performer's size and a prior on where a marker sits; every marker is then bound where
the data put it.  Labels no convention names get no hint (any creature: see
:func:`lacore.markers.calibration.calibrate`).
"""

import re
from dataclasses import dataclass

import numpy as np

from .binding import closest_surface_points

__all__ = ["LANDMARKS", "REGIONS", "match_label", "MarkerHint", "place_hints", "humanoid_frame", "AXES"]

#: Landmark name -> atlas point (left, up, forward) in body heights (see the module docstring).
LANDMARKS = {
    "HEAD_TOP": (+0.0000, +0.9992, -0.0471),
    "HEAD_FRONT": (+0.0000, +0.9706, +0.0181),
    "HEAD_BACK": (+0.0000, +0.9566, -0.0884),
    "C7": (+0.0000, +0.8490, -0.0789),
    "T10": (+0.0000, +0.7041, -0.0819),
    "CLAV": (+0.0000, +0.8470, -0.0232),
    "STRN": (+0.0000, +0.7689, +0.0045),
    "SACR": (+0.0000, +0.5771, -0.0993),
    "LFHD": (+0.0325, +0.9562, +0.0061),
    "RFHD": (-0.0325, +0.9562, +0.0061),
    "LBHD": (+0.0141, +0.9562, -0.0872),
    "RBHD": (-0.0141, +0.9562, -0.0872),
    "LBAK": (+0.0583, +0.8035, -0.0978),
    "RBAK": (-0.0583, +0.8035, -0.0978),
    "LASI": (+0.0702, +0.5551, -0.0009),
    "RASI": (-0.0702, +0.5551, -0.0009),
    "LPSI": (+0.0314, +0.5691, -0.1073),
    "RPSI": (-0.0314, +0.5691, -0.1073),
    "LGRT": (+0.1037, +0.5069, -0.0580),
    "RGRT": (-0.1037, +0.5069, -0.0580),
    "LSHO": (+0.1018, +0.8320, -0.0556),
    "RSHO": (-0.1018, +0.8320, -0.0556),
    "LUPA": (+0.1606, +0.7624, -0.0626),
    "RUPA": (-0.1606, +0.7624, -0.0626),
    "LELB": (+0.1920, +0.7000, -0.0721),
    "RELB": (-0.1920, +0.7000, -0.0721),
    "LFRM": (+0.2395, +0.6736, -0.0093),
    "RFRM": (-0.2395, +0.6736, -0.0093),
    "LWRA": (+0.2588, +0.6458, +0.0394),
    "RWRA": (-0.2588, +0.6458, +0.0394),
    "LWRB": (+0.2685, +0.6115, +0.0387),
    "RWRB": (-0.2685, +0.6115, +0.0387),
    "LWRI": (+0.2643, +0.6402, +0.0394),
    "RWRI": (-0.2643, +0.6402, +0.0394),
    "LFIN": (+0.2611, +0.6414, +0.0522),
    "RFIN": (-0.2611, +0.6414, +0.0522),
    "LTHI": (+0.1176, +0.3940, -0.0453),
    "RTHI": (-0.1176, +0.3940, -0.0453),
    "LTHAP": (+0.1012, +0.4442, -0.0024),
    "RTHAP": (-0.1012, +0.4442, -0.0024),
    "LTHAD": (+0.1063, +0.3438, -0.0103),
    "RTHAD": (-0.1063, +0.3438, -0.0103),
    "LKNE": (+0.1221, +0.2685, -0.0468),
    "RKNE": (-0.1221, +0.2685, -0.0468),
    "LMKN": (+0.0632, +0.2685, -0.0468),
    "RMKN": (-0.0632, +0.2685, -0.0468),
    "LTTB": (+0.0986, +0.2460, -0.0218),
    "RTTB": (-0.0986, +0.2460, -0.0218),
    "LTIB": (+0.1388, +0.1558, -0.0490),
    "RTIB": (-0.1388, +0.1558, -0.0490),
    "LTIAP": (+0.1132, +0.2009, -0.0346),
    "RTIAP": (-0.1132, +0.2009, -0.0346),
    "LTIAD": (+0.1272, +0.1108, -0.0446),
    "RTIAD": (-0.1272, +0.1108, -0.0445),
    "LANK": (+0.1557, +0.0432, -0.0666),
    "RANK": (-0.1557, +0.0432, -0.0666),
    "LMMA": (+0.1161, +0.0432, -0.0666),
    "RMMA": (-0.1161, +0.0432, -0.0666),
    "LHEE": (+0.1318, +0.0383, -0.0912),
    "RHEE": (-0.1318, +0.0383, -0.0912),
    "LTOE": (+0.1382, +0.0176, +0.0129),
    "RTOE": (-0.1382, +0.0176, +0.0129),
    "LFMH": (+0.1075, +0.0193, +0.0131),
    "RFMH": (-0.1075, +0.0193, +0.0131),
    "LVMH": (+0.1576, +0.0166, -0.0011),
    "RVMH": (-0.1576, +0.0166, -0.0011),
    "LPM1": (+0.1158, +0.0377, -0.0298),
    "RPM1": (-0.1158, +0.0377, -0.0298),
    "LDFT": (+0.1390, +0.0099, +0.0433),
    "RDFT": (-0.1390, +0.0099, +0.0433),
}
#: Region name -> (atlas centre, radius) in body heights: where a marker cluster may sit.
REGIONS = {
    "PELVIS": ((+0.0000, +0.6098, -0.0611), 0.1385),
    "HEAD": ((+0.0000, +0.9519, -0.0587), 0.0687),
    "TRUNK": ((+0.0000, +0.7041, -0.0604), 0.1129),
    "LTHIGH": ((+0.0806, +0.3940, -0.0527), 0.1517),
    "RTHIGH": ((-0.0806, +0.3940, -0.0527), 0.1517),
    "LSHANK": ((+0.1134, +0.1558, -0.0567), 0.1375),
    "RSHANK": ((-0.1134, +0.1558, -0.0567), 0.1375),
    "LFOOT": ((+0.1352, +0.0266, -0.0257), 0.0797),
    "RFOOT": ((-0.1352, +0.0266, -0.0257), 0.0797),
    "LARM": ((+0.1443, +0.7526, -0.0577), 0.0820),
    "RARM": ((-0.1443, +0.7526, -0.0577), 0.0820),
    "LFOREARM": ((+0.2233, +0.6687, -0.0093), 0.0815),
    "RFOREARM": ((-0.2233, +0.6687, -0.0093), 0.0815),
}

# label (without side prefix, upper case, dots and underscores removed) -> landmark suffix
_SIDED = {
    "ASI": "ASI", "ASIS": "ASI", "FWT": "ASI", "PSI": "PSI", "PSIS": "PSI", "BWT": "PSI",
    "GRT": "GRT", "GTR": "GRT", "TRO": "GRT", "TROC": "GRT",
    "THI": "THI", "THIGH": "THI", "THAP": "THAP", "THAD": "THAD",
    "KNE": "KNE", "KNEE": "KNE", "LFC": "KNE", "KNL": "KNE", "MKN": "MKN", "MFC": "MKN", "KNM": "MKN", "MKNE": "MKN",
    "TIB": "TIB", "SHN": "TIB", "SHA": "TIB", "SHANK": "TIB", "TTB": "TTB", "TIAP": "TIAP", "TIAD": "TIAD",
    "ANK": "ANK", "LMA": "ANK", "LMAL": "ANK", "MMA": "MMA", "MMAL": "MMA", "MED": "MMA",
    "HEE": "HEE", "HEEL": "HEE", "CAL": "HEE", "TOE": "TOE", "TO": "TOE", "MT2": "TOE", "FMH": "FMH", "MT1": "FMH",
    "VMH": "VMH", "MT5": "VMH", "PM1": "PM1", "DFT": "DFT",
    "SHO": "SHO", "SHOU": "SHO", "ACR": "SHO", "UPA": "UPA", "ELB": "ELB", "ELBW": "ELB", "FRM": "FRM",
    "WRA": "WRA", "WRB": "WRB", "WRI": "WRI", "WRIST": "WRI", "FIN": "FIN", "HAND": "FIN",
    "FHD": "FHD", "BHD": "BHD", "BAK": "BAK", "OFF": "BAK",
}
# whole labels (Helen Hayes head markers: R = rear, not right) and centre landmarks
_WHOLE = {"THEA": "HEAD_TOP", "FHEA": "HEAD_FRONT", "RHEA": "HEAD_BACK", "C7": "C7", "T10": "T10", "CLAV": "CLAV",
          "STRN": "STRN", "SACR": "SACR", "SACRUM": "SACR", "VSAC": "SACR", "SAC": "SACR"}
# cluster prefixes (side + prefix + number) -> region suffix
_CLUSTERS = {"TH": "THIGH", "SK": "SHANK", "SH": "SHANK", "FT": "FOOT", "UA": "ARM", "FA": "FOREARM"}
_PELVIS_CLUSTER = re.compile(r"(PV|PEL|PELV)\d+")


@dataclass(frozen=True)
class MarkerHint:
    """Where a labelled marker sits on a humanoid: ``kind`` (``"landmark"`` or ``"region"``) and canonical ``name``."""

    kind: str
    name: str


def match_label(label):
    """The :class:`MarkerHint` of a marker label, or None if no convention names it.

    Subject prefixes (``"Subject:LASI"``), repeats (``"LKNE#2"``), dots and
    underscores (``"R.TO"``) and case are ignored.

    Examples
    --------
    >>> match_label("R.TO")
    MarkerHint(kind='landmark', name='RTOE')
    >>> match_label("LTH3")
    MarkerHint(kind='region', name='LTHIGH')
    """
    s = str(label).split(":")[-1].split("#")[0].strip().upper().replace(".", "").replace("_", "")
    if s in _WHOLE:
        return MarkerHint("landmark", _WHOLE[s])
    if len(s) > 1 and s[0] in "LR":
        side, rest = s[0], s[1:]
        if rest in _SIDED and side + _SIDED[rest] in LANDMARKS:
            return MarkerHint("landmark", side + _SIDED[rest])
        m = re.fullmatch(r"([A-Z]+?)(\d+)", rest)
        if m and m.group(1) in _CLUSTERS:
            return MarkerHint("region", side + _CLUSTERS[m.group(1)])
    if _PELVIS_CLUSTER.fullmatch(s):
        return MarkerHint("region", "PELVIS")
    return None


#: Axis names accepted for ``up`` and ``forward``.
AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "+x": (1, 0, 0), "+y": (0, 1, 0), "+z": (0, 0, 1),
        "-x": (-1, 0, 0), "-y": (0, -1, 0), "-z": (0, 0, -1)}


def humanoid_frame(vertices, up="y", forward="z"):
    """Atlas frame of a humanoid mesh: ``origin (3,)``, ``axes (3, 3)`` (rows left, up, forward), ``height``."""
    X = np.asarray(vertices, float)
    u, f = np.asarray(AXES[str(up).lower()], float), np.asarray(AXES[str(forward).lower()], float)
    if abs(u @ f) > 1e-9:
        raise ValueError(f"up {up!r} and forward {forward!r} must be different axes")
    left = np.cross(u, f)
    axes = np.stack([left, u, f])
    Q = X @ axes.T
    lo, hi = Q.min(0), Q.max(0)
    height = float(hi[1] - lo[1])
    origin = np.array([0.5 * (lo[0] + hi[0]), lo[1], 0.5 * (lo[2] + hi[2])]) @ axes
    return origin, axes, height


def place_hints(vertices, faces, hints, up="y", forward="z"):
    """Surface points of landmark hints and candidate faces of region hints on a humanoid mesh.

    Parameters
    ----------
    vertices : (V, 3) array_like
        The model's reference (rest) mesh.
    faces : (F, 3) array_like
    hints : sequence of MarkerHint or None
    up, forward : str
        Axes of the mesh (default ``y`` up, ``z`` forward).

    Returns
    -------
    points : (M, 3) ndarray
        Landmark surface point, region centre, or NaN without a hint.
    faces_of : list of M (face (int), barycentric (3,)) pairs, (F_r,) int arrays (regions) or None
    height : float
        The mesh's height along ``up``.
    """
    X = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    origin, axes, height = humanoid_frame(X, up, forward)
    M = len(hints)
    points = np.full((M, 3), np.nan)
    out = [None] * M
    lm = [m for m, h in enumerate(hints) if h is not None and h.kind == "landmark"]
    if lm:
        targets = np.array([origin + height * (np.asarray(LANDMARKS[hints[m].name]) @ axes) for m in lm])
        q, f, b = closest_surface_points(X, F, targets)
        for i, m in enumerate(lm):
            points[m] = q[i]
            out[m] = (int(f[i]), b[i])
    centres = X[F].mean(1)
    local = (centres - origin) @ axes.T / height        # face centroids in atlas coordinates
    for m, h in enumerate(hints):
        if h is not None and h.kind == "region":
            c, r = REGIONS[h.name]
            c = np.asarray(c, float)
            near = np.linalg.norm(local - c, axis=1) <= r
            if c[0] > 0.02:
                near &= local[:, 0] > 0.0
            elif c[0] < -0.02:
                near &= local[:, 0] < 0.0
            sel = np.flatnonzero(near)
            if not len(sel):
                sel = np.array([int(np.argmin(np.linalg.norm(local - c, axis=1)))])
            out[m] = sel
            points[m] = origin + height * (c @ axes)
    return points, out, height
