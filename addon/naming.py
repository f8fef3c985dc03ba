# SPDX-License-Identifier: GPL-3.0-or-later
"""Names the add-on gives to what it creates, and the typed lists its operators read (no bpy).

Everything the add-on creates in a scene starts with :data:`OWN_PREFIX` (``"LA "``), so it is never
taken for the user's own data (a shape model's training keys, a bake's keyframed keys):

* in-betweens ``"LA <from>><to> <t>"`` (:func:`inbetween_key_name`, e.g. ``"LA Basis>Bend 0.250"``);
  re-running with the same keys and factors overwrites those keys in place;
* baked keys ``"LA bake <frame>"`` (:func:`bake_key_name`, e.g. ``"LA bake 012"``);
* fitted frames ``"LA fit <frame>"`` (:func:`fit_key_name`), the Mesh Cache modifier
  :data:`FIT_MODIFIER` and the slider preview key :data:`PREVIEW_KEY`;
* the live-mixing key :data:`LIVE_MIX_KEY` (:mod:`.live_mix`).

Shape-key names hold at most 63 bytes (Blender's limit); key names inside an in-between's name are
shortened to fit.

Typed lists (for scripts): factors and frames are numbers separated by spaces, commas or semicolons,
key names are separated by commas, a name holding a comma in double quotes or matched against the mesh's keys
(:func:`parse_factors`, :func:`parse_frames`, :func:`parse_key_list`).
"""

import math
import re

from ..lacore.errors import InputError

__all__ = ["OperatorInputError", "OWN_PREFIX", "INBETWEEN_PREFIX", "BAKE_PREFIX", "FIT_PREFIX", "PREVIEW_KEY",
           "FIT_MODIFIER", "LIVE_MIX_KEY", "is_own_key", "is_fit_key", "inbetween_key_name", "bake_key_name",
           "fit_key_name", "parse_factors", "parse_key_list", "parse_frames"]

OWN_PREFIX = "LA "
INBETWEEN_PREFIX = OWN_PREFIX
BAKE_PREFIX = OWN_PREFIX + "bake "
FIT_PREFIX = OWN_PREFIX + "fit "
PREVIEW_KEY = OWN_PREFIX + "model preview"
FIT_MODIFIER = "LA Fit"
LIVE_MIX_KEY = OWN_PREFIX + "live mix"
_NAME_BYTES = 63  # Blender's shape-key names hold 63 bytes


class OperatorInputError(InputError):
    """Unusable operator input (an unknown key, a factor list that does not parse ...)."""


def is_own_key(name):
    """Whether the shape key ``name`` was made by the add-on (in-between, bake, fit, preview, live mix)."""
    return name.startswith(OWN_PREFIX)


def _fit(name, n_bytes):
    data = name.encode("utf-8")
    return name if len(data) <= n_bytes else data[: max(n_bytes - 1, 1)].decode("utf-8", "ignore") + "~"


def inbetween_key_name(key_from, key_to, t):
    """``"LA <from>><to> <t:.3f>"``, the key names shortened if needed to fit 63 bytes.

    >>> inbetween_key_name("Basis", "Bend", 0.25)
    'LA Basis>Bend 0.250'
    """
    suffix = f" {t:.3f}"
    room = _NAME_BYTES - len((INBETWEEN_PREFIX + ">" + suffix).encode("utf-8"))
    a, b = key_from, key_to
    if len(a.encode()) + len(b.encode()) > room:
        half = room // 2
        a, b = _fit(a, half), _fit(b, room - half)
    return f"{INBETWEEN_PREFIX}{a}>{b}{suffix}"


def bake_key_name(frame):
    """``"LA bake 012"``.

    >>> bake_key_name(12)
    'LA bake 012'
    """
    return f"{BAKE_PREFIX}{frame:03d}"


def fit_key_name(frame):
    """``"LA fit <frame>"``.

    >>> fit_key_name(7)
    'LA fit 7'
    """
    return f"{FIT_PREFIX}{int(frame)}"


def is_fit_key(name):
    """Whether ``name`` is a fitted frame's key (:func:`fit_key_name`).

    >>> is_fit_key("LA fit 7"), is_fit_key("LA fit -3"), is_fit_key("LA fit quality"), is_fit_key("Bend")
    (True, True, False, False)
    """
    return re.fullmatch(re.escape(FIT_PREFIX) + r"-?\d+", name) is not None


def _items(text):
    return [s for s in re.split(r"[\s,;]+", text.strip()) if s]


def parse_factors(text):
    """``"0.25 0.5, 0.75 1.5"`` -> ``[0.25, 0.5, 0.75, 1.5]`` (spaces and/or commas separate).

    >>> parse_factors("0.25 0.5, 0.75 1.5")
    [0.25, 0.5, 0.75, 1.5]
    """
    factors = []
    for s in _items(text):
        try:
            t = float(s)
        except ValueError:
            raise OperatorInputError(f"Factors: cannot read {s!r} as a number (use numbers separated by "
                                     "spaces or commas, e.g. \"0.25 0.5 0.75 1.5\")") from None
        if not math.isfinite(t):
            raise OperatorInputError(f"Factors: {s!r} is not a finite number")
        factors.append(t)
    if not factors:
        raise OperatorInputError("Factors: no numbers given")
    return factors


def _key_items(text):
    """The comma-separated items of ``text`` as ``(name, quoted, start, end)``: a name in double quotes is taken as
    written (commas and spaces included; ``""`` inside stands for one ``"``), others are stripped of spaces and span
    ``text[start:end]``."""
    items, i, n = [], 0, len(text)
    while True:
        while i < n and text[i].isspace():
            i += 1
        if i < n and text[i] == '"':
            name, i = [], i + 1
            while True:
                if i >= n:
                    raise OperatorInputError(f"Keys: a quote is not closed in {text!r} (put each name in a pair "
                                             "of double quotes)")
                if text[i] == '"' and text[i + 1:i + 2] == '"':
                    name.append('"')
                    i += 2
                elif text[i] == '"':
                    i += 1
                    break
                else:
                    name.append(text[i])
                    i += 1
            while i < n and text[i].isspace():
                i += 1
            if i < n and text[i] != ",":
                raise OperatorInputError(f"Keys: {text[i:]!r} follows the quoted name \"{''.join(name)}\" in "
                                         f"{text!r}: separate names by commas")
            items.append(("".join(name), True, None, None))
        else:
            j = text.find(",", i)
            j = n if j < 0 else j
            items.append((text[i:j].strip(), False, i, j))
            i = j
        if i >= n:
            return items
        i += 1  # the comma


def parse_key_list(text, names=()):
    """Shape-key names typed in ``text``, separated by commas (names may hold spaces).

    A name holding a comma is given in double quotes (``""`` inside stands for a ``"``), or as it is when it is one
    of ``names`` (the mesh's keys): unquoted items joined with their commas are taken as the longest such name
    (so "Arm, left" is one key where the mesh has a key of that name).

    >>> parse_key_list("Basis, Left arm up")
    ['Basis', 'Left arm up']
    >>> parse_key_list('Basis, "Arm, left", Bend')
    ['Basis', 'Arm, left', 'Bend']
    >>> parse_key_list("Basis, Arm, left, Bend", names=["Basis", "Arm, left", "Bend"])
    ['Basis', 'Arm, left', 'Bend']
    """
    items = _key_items(text)
    if all(not quoted and not name for name, quoted, _, _ in items):
        raise OperatorInputError("Keys: no shape-key names given (separate them by commas)")
    known = set(names)
    out, i = [], 0
    while i < len(items):
        name, quoted, start, _ = items[i]
        if not name:
            raise OperatorInputError(f"Keys: empty name in {text!r} (separate names by single commas)")
        last = i
        if not quoted:
            for j in range(len(items) - 1, i, -1):  # the longest run of unquoted items naming a key
                if not any(items[k][1] for k in range(i, j + 1)) and text[start:items[j][3]].strip() in known:
                    last = j
                    break
            name = text[start:items[last][3]].strip()
        out.append(name)
        i = last + 1
    return out


def parse_frames(text):
    """``"1, 12 24"`` -> ``[1, 12, 24]`` (integers separated by spaces or commas).

    >>> parse_frames("1, 12 24")
    [1, 12, 24]
    """
    items = _items(text)
    if not items:
        raise OperatorInputError("Frames: no frame numbers given")
    frames = []
    for s in items:
        try:
            value = float(s)
        except ValueError:
            raise OperatorInputError(f"Frames: cannot read {s!r} as a frame number") from None
        if not math.isfinite(value) or value != int(value):
            raise OperatorInputError(f"Frames: {s!r} is not a whole frame number")
        frames.append(int(value))
    return frames
