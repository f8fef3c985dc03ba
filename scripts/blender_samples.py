# SPDX-License-Identifier: GPL-3.0-or-later
"""Reproducible Blender sample objects with shape keys (used by the demo, `make samples` and the tests).

Every function builds its mesh from explicit coordinates and quads (no random
numbers, no dependence on operator defaults), links a new object into the
current scene, makes it active and returns it.  Needs ``bpy`` (Blender or the
``bpy`` module).
"""

import math

import bpy
import numpy as np

__all__ = ["make_object", "add_shape_key", "make_cube", "make_bar", "make_wave_grid", "build_demo_scene"]


def make_object(name, vertices, polygons, collection=None):
    """A mesh object from ``(V, 3)`` vertices and a list of polygons (vertex index lists)."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(map(float, v)) for v in np.asarray(vertices)], [], [list(map(int, p)) for p in polygons])
    mesh.update(calc_edges=True)
    obj = bpy.data.objects.new(name, mesh)
    (collection or bpy.context.scene.collection).objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


def add_shape_key(obj, name, coords=None):
    """Add a shape key (the first one becomes the Basis) with ``(V, 3)`` coordinates."""
    key = obj.shape_key_add(name=name, from_mix=False)
    key.value = 0.0  # the object shows its Basis until the user dials a key in
    if coords is not None:
        key.points.foreach_set("co", np.asarray(coords, dtype=np.float32).ravel())
    obj.data.update()
    return key


def basis_coords(obj):
    mesh = obj.data
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def rotation_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def make_cube(name="Cube", size=2.0):
    """An axis-aligned cube with 6 outward-facing quads (edge length ``size``).

    Shape keys: ``Basis``, ``Scaled`` (x1.5 about the centre) and ``Rigid``
    (rotated 30 degrees about z and translated): lengths and angles of ``Rigid``
    equal those of ``Basis``.
    """
    h = size / 2
    verts = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)])
    # index = 4 i + 2 j + k for (x, y, z) = (+-h); quads counter-clockwise seen from outside
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    obj = make_object(name, verts, quads)
    add_shape_key(obj, "Basis")
    add_shape_key(obj, "Scaled", 1.5 * verts)
    add_shape_key(obj, "Rigid", verts @ rotation_z(math.radians(30)).T + np.array([0.5, -0.25, 1.0]))
    return obj


def _bar_surface(nx, length, width):
    """Closed quad surface of a box bar along x: ``nx`` segments, square cross-section."""
    w = width / 2
    ring = np.array([[-w, -w], [w, -w], [w, w], [-w, w]])  # (y, z), counter-clockwise seen from +x
    xs = np.linspace(-length / 2, length / 2, nx + 1)
    verts = np.array([[x, y, z] for x in xs for (y, z) in ring])
    quads = []
    for i in range(nx):
        a, b = 4 * i, 4 * (i + 1)
        for k in range(4):
            k1 = (k + 1) % 4
            quads.append((a + k, a + k1, b + k1, b + k))  # outward normals
    quads.append((3, 2, 1, 0))  # cap at -x
    quads.append((4 * nx, 4 * nx + 1, 4 * nx + 2, 4 * nx + 3))  # cap at +x
    return verts, quads


def bend(verts, angle, length):
    """Bend the bar along x into an arc of total ``angle`` (radians) in the x-z plane, lengths along x kept."""
    if abs(angle) < 1e-12:
        return verts.copy()
    radius = length / angle
    x, y, z = verts[:, 0], verts[:, 1], verts[:, 2]
    phi = x / radius
    r = radius - z
    return np.stack([r * np.sin(phi), y, radius - r * np.cos(phi)], axis=1)


def twist(verts, angle, length):
    """Twist about the x axis, linearly from -angle/2 to +angle/2."""
    phi = verts[:, 0] / length * angle
    c, s = np.cos(phi), np.sin(phi)
    y, z = verts[:, 1], verts[:, 2]
    return np.stack([verts[:, 0], c * y - s * z, s * y + c * z], axis=1)


def make_bar(name="Bar", segments=12, length=6.0, width=1.0):
    """A closed quad bar with keys ``Basis``, ``Bend`` (90 degrees), ``Twist`` (90 degrees) and ``Rigid``."""
    verts, quads = _bar_surface(segments, length, width)
    obj = make_object(name, verts, quads)
    add_shape_key(obj, "Basis")
    add_shape_key(obj, "Bend", bend(verts, math.pi / 2, length))
    add_shape_key(obj, "Twist", twist(verts, math.pi / 2, length))
    add_shape_key(obj, "Rigid", verts @ rotation_z(math.radians(-40)).T + np.array([0.0, 2.0, 0.5]))
    return obj


def make_wave_grid(name="Grid", n=10, size=2.0):
    """An open ``n`` x ``n`` quad grid (disk topology) with keys ``Basis``, ``Wave`` and ``Roll``."""
    t = np.linspace(-size / 2, size / 2, n + 1)
    verts = np.array([[x, y, 0.0] for y in t for x in t])
    quads = [(j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
             for j in range(n) for i in range(n)]
    obj = make_object(name, verts, quads)
    add_shape_key(obj, "Basis")
    wave = verts.copy()
    wave[:, 2] = 0.15 * size * np.sin(math.pi * verts[:, 0] / size * 2) * np.cos(math.pi * verts[:, 1] / size)
    add_shape_key(obj, "Wave", wave)
    add_shape_key(obj, "Roll", bend(verts, math.pi, size))  # isometric: lengths of Basis are kept
    return obj


def build_demo_scene():
    """The demo scene: a cube, a bar and a grid side by side; returns the objects."""
    objs = [make_cube("Cube"), make_bar("Bar"), make_wave_grid("Grid")]
    for obj, x in zip(objs, (-5.0, 0.0, 6.0), strict=True):
        obj.location.x = x
    return objs
