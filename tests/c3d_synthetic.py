"""A minimal, independent C3D writer for tests: every processor format and storage.

The shared sample files cover Intel-float, DEC-integer and SGI/MIPS-integer storage only, and the
``c3d`` package writes Intel floats only.  This writer builds the other combinations from the C3D
specification (https://www.c3d.org, "The C3D File Format User Guide"): a 512-byte header, one
parameter section (groups POINT and ANALOG) and the point data, each number encoded in the
processor's own format:

* Intel (84): little-endian integers, IEEE floats;
* DEC (85): little-endian integers, DEC F-floats (the IEEE bits of ``4 x`` with the two 16-bit
  words swapped);
* SGI/MIPS (86): big-endian integers and IEEE floats.

Not used by lacore; tests compare lacore.markers.io and the ``c3d`` package on these files.
"""

import struct

import numpy as np

PROCESSORS = {"intel": 84, "dec": 85, "mips": 86}


def _int16(proc, values):
    return np.asarray(values, dtype=">i2" if proc == "mips" else "<i2").tobytes()


def _float32(proc, values):
    v = np.asarray(values, dtype=np.float32)
    if proc == "mips":
        return v.astype(">f4").tobytes()
    if proc == "dec":
        bits = (v * np.float32(4.0)).view(np.uint32)  # DEC value = IEEE bits / 4
        swapped = ((bits & 0xFFFF) << 16) | (bits >> 16)
        return swapped.astype("<u4").tobytes()
    return v.astype("<f4").tobytes()


def _param(proc, group_id, name, type_code, dims, data, last=False):
    """One parameter record (type -1 char, 2 int16, 4 float)."""
    name_b = name.encode()
    body = struct.pack("b", type_code) + struct.pack("B", len(dims)) + bytes(dims) + data + b"\x00"  # no description
    offset = 0 if last else 2 + len(body)
    return struct.pack("bb", len(name_b), group_id) + name_b + _int16(proc, [offset]) + body


def _group(proc, group_id, name):
    name_b = name.encode()
    body = b"\x00"  # empty description
    return struct.pack("bb", len(name_b), -group_id) + name_b + _int16(proc, [2 + len(body)]) + body


def _chars(strings, width):
    return b"".join(s.ljust(width).encode()[:width] for s in strings)


def write_c3d_file(path, positions_mm, labels, rate, proc="intel", storage="float", first_frame=1,
                   model_outputs=(), units="mm", analog=None):
    """Write ``positions_mm`` (T, M, 3; NaN = invalid) with ``labels`` as a C3D file.

    ``storage``: ``"float"`` (POINT:SCALE = -scale) or ``"int"`` (int16 times scale); ``model_outputs``
    are labels also listed in POINT:ANGLES; ``analog=(used, rate)`` writes ANALOG:USED and ANALOG:RATE as given
    (no analog samples: for files with damaged analog parameters).  Returns the scale used (quantum of integer
    storage).
    """
    pos = np.asarray(positions_mm, np.float64)
    T, M, _ = pos.shape
    valid = np.isfinite(pos).all(axis=2)
    peak = float(np.nanmax(np.abs(pos))) if valid.any() else 1.0
    scale = np.float32(peak / 30000.0)
    point_scale = -scale if storage == "float" else scale

    # parameter section (block 2), data from block 2 + n_param_blocks
    width = max(len(s) for s in labels)
    params = [_group(proc, 1, "POINT"), _group(proc, 2, "ANALOG"),
              _param(proc, 1, "USED", 2, [], _int16(proc, [M])),
              _param(proc, 1, "SCALE", 4, [], _float32(proc, [point_scale])),
              _param(proc, 1, "RATE", 4, [], _float32(proc, [rate])),
              _param(proc, 1, "FRAMES", 2, [], _int16(proc, [T])),
              _param(proc, 1, "UNITS", -1, [len(units)], units.encode()),
              _param(proc, 1, "LABELS", -1, [width, M], _chars(labels, width))]
    if model_outputs:
        w = max(len(s) for s in model_outputs)
        params.append(_param(proc, 1, "ANGLES", -1, [w, len(model_outputs)], _chars(model_outputs, w)))
    # ANALOG:RATE left out (no analog data): the c3d package decodes a DEC 0.0 as -1.7e38
    if analog is not None:
        params.append(_param(proc, 2, "RATE", 4, [], _float32(proc, [analog[1]])))
    params += [_param(proc, 2, "USED", 2, [], _int16(proc, [0 if analog is None else analog[0]]),
                      last=True)]  # offset 0: the end
    body_len = 4 + sum(len(p) for p in params) + 32  # + DATA_START (inserted below)
    n_blocks = -(-body_len // 512)
    data_block = 2 + n_blocks
    params.insert(2, _param(proc, 1, "DATA_START", 2, [], _int16(proc, [data_block])))
    section = bytes([0x01, 0x50, n_blocks, PROCESSORS[proc]]) + b"".join(params)
    assert len(section) <= 512 * n_blocks
    section = section.ljust(512 * n_blocks, b"\x00")

    # header (block 1)
    header = bytearray(512)
    header[0], header[1] = 2, 0x50
    header[2:4] = _int16(proc, [M])
    header[4:6] = _int16(proc, [0])
    header[6:8] = _int16(proc, [first_frame])
    header[8:10] = _int16(proc, [first_frame + T - 1])
    header[10:12] = _int16(proc, [0])
    header[12:16] = _float32(proc, [point_scale])
    header[16:18] = _int16(proc, [data_block])
    header[18:20] = _int16(proc, [0])
    header[20:24] = _float32(proc, [rate])

    # point data: x, y, z, residual word per marker and frame
    residual = np.where(valid, 3.0, -1.0)  # residual 3 * |scale| (camera byte 0); -1 = invalid
    if storage == "float":
        words = np.zeros((T, M, 4), np.float32)
        words[:, :, :3] = np.where(valid[:, :, None], pos, 0.0)
        words[:, :, 3] = residual
        data = _float32(proc, words.ravel())
    else:
        words = np.zeros((T, M, 4), np.int64)
        words[:, :, :3] = np.where(valid[:, :, None], np.round(np.nan_to_num(pos) / float(scale)), 0)
        words[:, :, 3] = residual.astype(np.int64)
        data = _int16(proc, words.ravel())
    blob = bytes(header) + section + data
    blob = blob.ljust(-(-len(blob) // 512) * 512, b"\x00")
    with open(path, "wb") as fh:
        fh.write(blob)
    return float(scale)
