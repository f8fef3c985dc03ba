# SPDX-License-Identifier: GPL-3.0-or-later
"""Picture of the add-on's panel (docs/images/panel.png), drawn from its own ``draw()`` calls in headless Blender.

Background Blender has no window to screenshot, so this script builds a small scene (a bar with three
shape keys, encoded, one in-between, a shape model, a four-marker take imported and bound), calls the
``draw()`` of the add-on's two panels and of the In-betweens dialog with a layout that records every call
(``row``, ``column``, ``split``, ``box``, ``operator``, ``label``, ``prop`` and their arguments), and paints what was
recorded the way Blender's default dark theme would: buttons, sliders, fields, labels.  Operator texts
come from the operators' registered labels, property values from the scene.  Blender's own Shape Keys
list above the add-on's panels is drawn from the mesh's keys.  Icons are approximated by font symbols.
Text is drawn with Blender's UI font (``blf`` into an image buffer), shapes with NumPy.

usage (bpy 5.2 with SciPy on its path, as ``make demo``)::

    python scripts/draw_panel.py [--output docs/images/panel.png] [--dialog docs/images/inbetweens_dialog.png]
"""

import argparse
import math
import os
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)

S = 1.4                        # UI scale
U = round(20 * S)              # widget height
GAP = round(2 * S)             # between the items of a column or row that is not aligned
PAD = round(10 * S)            # panel padding
RADIUS = round(4 * S)          # corner radius of buttons and fields
FONT = round(11 * S)           # UI text size (pixels)
WIDTH = round(380 * S)         # the Properties editor's width

THEME = {
    "back": (0.19, 0.19, 0.19), "panel": (0.24, 0.24, 0.24), "header": (0.27, 0.27, 0.27),
    "subpanel": (0.22, 0.22, 0.22), "button": (0.33, 0.33, 0.33), "field": (0.13, 0.13, 0.13),
    "slider_fill": (0.28, 0.45, 0.70), "box": (0.20, 0.20, 0.20), "list": (0.16, 0.16, 0.16),
    "active": (0.28, 0.45, 0.70), "text": (0.90, 0.90, 0.90), "dim": (0.63, 0.63, 0.63),
    "disabled": (0.45, 0.45, 0.45), "error": (0.95, 0.62, 0.25), "ok": (0.55, 0.80, 0.45),
}

#: Blender icon names -> a font symbol approximating them
ICONS = {
    "CHECKMARK": "\u2713", "X": "\u2715", "ERROR": "\u26a0", "INFO": "\u2139", "TRASH": "\U0001f5d1",
    "MOD_EDGESPLIT": "\u25c7", "IPO_EASE_IN_OUT": "\u223f", "KEYFRAME_HLT": "\u25c6",
    "MOD_DATA_TRANSFER": "\u21c4", "SHAPEKEY_DATA": "\u25b3", "EMPTY_DATA": "\u271b",
    "ARMATURE_DATA": "\u25b7", "NONE": "",
}
ICON_COLORS = {"ERROR": "error", "CHECKMARK": "ok"}


# ----------------------------------------------------------------------------- recording the draw calls
class Item:
    """One widget the panel asked for: ``kind`` (operator, label, prop, separator) and its arguments."""

    def __init__(self, kind, args, kwargs, layout):
        self.kind, self.args, self.kwargs = kind, args, kwargs
        self.enabled = layout.enabled
        self.split = layout.use_property_split


class _Props:
    """What ``layout.operator(...)`` returns: the operator's properties (accepted, not drawn)."""

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)


class Layout:
    """A ``UILayout`` stand-in recording its children (sub-layouts and items) in order."""

    def __init__(self, kind="column", align=False, parent=None):
        self.kind, self.align, self.children = kind, align, []
        self.enabled = True if parent is None else parent.enabled
        self.use_property_split = False if parent is None else parent.use_property_split
        self.operator_context = 'EXEC_DEFAULT'
        self.alert = False

    def _sub(self, kind, align=False, **_):
        child = Layout(kind, align, self)
        self.children.append(child)
        return child

    def row(self, align=False, **kw):
        return self._sub("row", align)

    def split(self, factor=0.0, align=False, **kw):
        child = self._sub("split", align)
        child.factor = factor
        return child

    def column(self, align=False, **kw):
        return self._sub("column", align)

    def box(self):
        return self._sub("box")

    def operator(self, *args, **kwargs):
        self.children.append(Item("operator", args, kwargs, self))
        return _Props()

    def label(self, *args, **kwargs):
        self.children.append(Item("label", args, kwargs, self))

    def prop(self, *args, **kwargs):
        self.children.append(Item("prop", args, kwargs, self))

    def separator(self, *args, **kwargs):
        self.children.append(Item("separator", args, kwargs, self))


def record(draw, context, owner=None):
    """The layout tree of ``draw(self, context)`` (``self.layout`` recorded; ``owner``'s attributes kept)."""
    from types import SimpleNamespace

    layout = Layout()
    draw(SimpleNamespace(layout=layout, **(owner or {})), context)
    return layout


# ----------------------------------------------------------------------------- what an item shows
def operator_label(idname):
    import bpy

    module, name = idname.split(".")
    return getattr(getattr(bpy.ops, module), name).get_rna_type().name


def prop_widget(item):
    """``(kind, label, value text, fraction)`` of a ``prop`` item from the property's RNA and value."""
    data, name = item.args[0], item.args[1]
    rna = data.bl_rna.properties[name]
    index = item.kwargs.get("index", -1)
    value = getattr(data, name)
    if index >= 0:
        value = value[index]
    label = item.kwargs.get("text", rna.name)
    if rna.type == 'ENUM':
        if rna.is_enum_flag:
            return "flags", label, [(i.name, i.identifier in value) for i in _enum_items(data, name)], None
        items = {i.identifier: i.name for i in _enum_items(data, name)}
        return "enum", label, items.get(value, str(value)), None
    if rna.type == 'BOOLEAN':
        return "bool", label, bool(value), None
    if rna.type == 'STRING':
        return "text", label, value, None
    if rna.type in ('INT', 'FLOAT'):
        text = f"{value:.3f}" if rna.type == 'FLOAT' else str(value)
        fraction = None
        if item.kwargs.get("slider"):
            lo, hi = rna.soft_min, rna.soft_max
            fraction = (value - lo) / (hi - lo) if hi > lo else 0.0
        return "number", label, text, fraction
    return "text", label, str(value), None


def _enum_items(data, name):
    """The enum's static items (dynamic ones, such as the mesh's keys, have none: their value is shown)."""
    return list(data.bl_rna.properties[name].enum_items)


# ----------------------------------------------------------------------------- layout: boxes and texts
class Canvas:
    """Shapes (painted with NumPy) and texts (drawn by blf afterwards), in pixels from the top left."""

    def __init__(self):
        self.shapes, self.texts = [], []

    def rect(self, x, y, w, h, color, radius=RADIUS):
        self.shapes.append((x, y, w, h, THEME[color] if isinstance(color, str) else color, radius))

    def text(self, x, y, h, text, color="text", align="left", w=0, size=FONT, icon=None):
        """``text`` vertically centred in the band ``[y, y + h)``; ``align`` left (at x), center or right of w;
        ``icon`` (a Blender icon name) drawn just before the text."""
        self.texts.append((x, y, h, text, THEME[color], align, w, size, icon))


def place(node, canvas, x, y, w):
    """Lay ``node`` (a Layout or an Item) out at ``(x, y)`` with width ``w``; returns its height."""
    if isinstance(node, Item):
        return place_item(node, canvas, x, y, w)
    if node.kind == "box":
        inner = Canvas()
        h = place_children(node, inner, x + PAD // 2, y + PAD // 2, w - PAD, vertical=True) + PAD
        canvas.rect(x, y, w, h, "box")
        canvas.shapes += inner.shapes
        canvas.texts += inner.texts
        return h
    return place_children(node, canvas, x, y, w, vertical=node.kind == "column")


def _fixed_width(node):
    """Icon-only buttons are square; everything else shares a row's width."""
    if isinstance(node, Item) and node.kind == "operator" and node.kwargs.get("text") == "" and node.kwargs.get("icon"):
        return U
    return None


def place_children(node, canvas, x, y, w, vertical):
    gap = 0 if node.align else GAP
    if not node.children:
        return 0
    if vertical:
        top = y
        for child in node.children:
            y += place(child, canvas, x, y, w) + gap
        return y - top - gap
    fixed = [_fixed_width(c) for c in node.children]
    if node.kind == "split" and node.factor > 0 and len(fixed) > 1:
        fixed[0] = node.factor * (w - gap * (len(fixed) - 1))   # Blender's split: the first column's share
    free = w - sum(f for f in fixed if f) - gap * (len(fixed) - 1)
    n_free = sum(1 for f in fixed if not f) or 1
    height = 0
    for child, f in zip(node.children, fixed, strict=True):
        cw = f or free / n_free
        height = max(height, place(child, canvas, round(x), y, round(cw)))
        x += cw + gap
    return height


def _icon(canvas, name, x, y, color="text"):
    symbol = ICONS.get(name, "\u25cf")
    if symbol:
        canvas.text(x, y, U, symbol, ICON_COLORS.get(name, color), align="center", w=U)
    return U if symbol else 0


def place_item(item, canvas, x, y, w):
    color = "text" if item.enabled else "disabled"
    if item.kind == "separator":
        return U // 2
    if item.kind == "label":
        text = item.kwargs.get("text", item.args[0] if item.args else "")
        dx = _icon(canvas, item.kwargs["icon"], x, y, color) if item.kwargs.get("icon") else round(4 * S)
        canvas.text(x + dx, y, U, text, color)
        return U
    if item.kind == "operator":
        text = item.kwargs.get("text", operator_label(item.args[0]))
        icon = item.kwargs.get("icon")
        if item.kwargs.get("emboss", True):
            canvas.rect(x, y, w, U, "button")
        if text:
            if item.kwargs.get("emboss", True):
                canvas.text(x, y, U, text, color, align="center", w=w, icon=icon)
            else:
                dx = _icon(canvas, icon, x, y, color) if icon and icon != 'NONE' else round(4 * S)
                canvas.text(x + dx, y, U, text, color)
        elif icon:
            _icon(canvas, icon, x + (w - U) / 2, y, color)
        return U
    kind, label, value, fraction = prop_widget(item)
    if item.split and kind not in ("bool", "flags"):   # label right-aligned in the left 40 %, widget right
        lw = round(0.4 * w)
        canvas.text(x, y, U, label, "dim" if item.enabled else "disabled", align="right", w=lw - round(8 * S))
        x, w, label = x + lw, w - lw, ""
    if kind == "flags":
        for i, (name, on) in enumerate(value):
            yy = y + i * U
            canvas.rect(x + round(4 * S), yy + round(4 * S), U - round(8 * S), U - round(8 * S),
                        "active" if on else "field", radius=round(3 * S))
            if on:
                canvas.text(x + round(4 * S), yy, U, "\u2713", "text", align="center", w=U - round(8 * S))
            canvas.text(x + U + round(2 * S), yy, U, name, color)
        return U * len(value)
    if kind == "bool":
        canvas.rect(x + round(4 * S), y + round(4 * S), U - round(8 * S), U - round(8 * S),
                    "active" if value else "field", radius=round(3 * S))
        if value:
            canvas.text(x + round(4 * S), y, U, "\u2713", "text", align="center", w=U - round(8 * S))
        canvas.text(x + U + round(2 * S), y, U, label, color)
        return U
    field = "button" if kind in ("enum",) else "field"
    canvas.rect(x, y, w, U, field if kind != "number" else "button")
    if kind == "number" and fraction is not None:
        fill = max(0.0, min(1.0, fraction))
        if fill > 0:
            canvas.rect(x, y, max(round(w * fill), round(8 * S)), U, "slider_fill")
    inset = round(8 * S)
    if kind == "enum":
        canvas.text(x + inset, y, U, str(value), color)
        canvas.text(x, y, U, "\u2304", "dim", align="right", w=w - inset)
    elif kind == "number":
        if label:
            canvas.text(x + inset, y, U, label, color)
        canvas.text(x, y, U, str(value), color, align="right" if label else "center",
                    w=w - inset if label else w)
    else:
        canvas.text(x + inset, y, U, str(value) if value else label, color if value else "disabled")
    return U


def panel(canvas, title, layout, x, y, w, sub=True):
    """A (sub-)panel: header strip with its disclosure triangle and title, then its layout."""
    canvas.rect(x, y, w, U + round(4 * S), "header" if not sub else "panel", radius=round(4 * S))
    canvas.text(x + round(6 * S), y, U + round(4 * S), "\u25be", "dim")
    canvas.text(x + round(22 * S), y, U + round(4 * S), title, "text")
    y += U + round(4 * S)
    inner = Canvas()
    h = place(layout, inner, x + PAD, y + PAD // 2, w - 2 * PAD) + PAD
    canvas.rect(x, y, w, h, "subpanel" if sub else "panel", radius=0)
    canvas.shapes += inner.shapes
    canvas.texts += inner.texts
    return U + round(4 * S) + h


def shape_key_list(canvas, obj, x, y, w):
    """Blender's own Shape Keys list (above the add-on's panels): one row per key, its value at the right."""
    blocks = list(obj.data.shape_keys.key_blocks)
    h = U * len(blocks) + round(8 * S)
    canvas.rect(x, y, w, h, "list")
    for i, kb in enumerate(blocks):
        yy = y + round(4 * S) + i * U
        if i == obj.active_shape_key_index:
            canvas.rect(x + round(2 * S), yy, w - round(4 * S), U, "active", radius=round(3 * S))
        canvas.text(x + round(4 * S), yy, U, ICONS["SHAPEKEY_DATA"], "dim", align="center", w=U)
        canvas.text(x + U + round(4 * S), yy, U, kb.name, "text")
        if i > 0:
            canvas.text(x, yy, U, f"{kb.value:.3f}", "text", align="right", w=w - round(34 * S))
            canvas.rect(x + w - round(26 * S), yy + round(5 * S), U - round(10 * S), U - round(10 * S),
                        "active" if not kb.mute else "field", radius=round(3 * S))
    return h


# ----------------------------------------------------------------------------- painting
def paint(canvas, width, height, path):
    """Shapes by NumPy (anti-aliased rounded rectangles), then the texts by blf; PNG at ``path``."""
    import blf
    import imbuf
    import numpy as np

    from render_marker_fit import write_png

    image = np.empty((height, width, 3))
    image[:] = THEME["back"]
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    for x, y, w, h, color, r in canvas.shapes:
        x0, y0, x1, y1 = x, y, x + w, y + h
        sub = (slice(max(int(y0), 0), min(int(math.ceil(y1)), height)), slice(max(int(x0), 0), min(int(math.ceil(x1)),
                                                                                                   width)))
        px, py = xx[sub], yy[sub]
        # signed distance to the rounded rectangle, then a one-pixel coverage ramp
        cx, cy = np.clip(px, x0 + r, x1 - r), np.clip(py, y0 + r, y1 - r)
        d = np.hypot(px - cx, py - cy) - r
        cover = np.clip(0.5 - d, 0.0, 1.0)[..., None]
        image[sub] = image[sub] * (1 - cover) + np.asarray(color) * cover
    with tempfile.TemporaryDirectory() as tmp:
        base = os.path.join(tmp, "base.png")
        write_png(base, (np.clip(image, 0, 1) * 255).round().astype(np.uint8))
        buf = imbuf.load(base)
        font = 0
        with blf.bind_imbuf(font, buf):
            for x, y, h, text, color, align, w, size, icon in canvas.texts:
                blf.size(font, size)
                symbol = ICONS.get(icon, "") if icon else ""
                lead = blf.dimensions(font, symbol)[0] + round(6 * S) if symbol else 0
                tw = blf.dimensions(font, text)[0] + lead
                if align == "center":
                    x = x + (w - tw) / 2
                elif align == "right":
                    x = x + w - tw
                baseline = round(height - (y + h / 2 + size * 0.36))
                if symbol:
                    blf.color(font, *THEME[ICON_COLORS.get(icon, "text")], 1.0)
                    blf.position(font, round(x), baseline, 0)
                    blf.draw_buffer(font, symbol)
                blf.color(font, *color, 1.0)
                blf.position(font, round(x + lead), baseline, 0)
                blf.draw_buffer(font, text)
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        imbuf.write(buf, filepath=os.path.abspath(path))


# ----------------------------------------------------------------------------- the scene
def build_scene(tmp):
    """A bar with Basis, Bend180, Bend90 and Twist90; encoded, one in-between, a shape model, two vertex groups, a
    bound take."""
    import bpy
    import numpy as np

    import blend_sample_cases as cases
    from lacore.markers.io import MarkerTake, write_c3d

    bpy.ops.wm.read_homefile(use_empty=True)
    obj = cases.bent_bar("Arm", 180.0, segments=(32, 3, 3))
    cases.add_simple_deform_key(obj, "Bend90", method="BEND", angle=math.pi / 2, axis="Z")
    cases.add_simple_deform_key(obj, "Twist90", method="TWIST", angle=math.pi / 2, axis="X")
    for kb in obj.data.shape_keys.key_blocks[1:]:
        kb.value = 0.0
    context = {"active_object": obj, "object": obj, "selected_objects": [obj]}
    with bpy.context.temp_override(**context):
        assert bpy.ops.lengths_angles.encode() == {'FINISHED'}
        assert bpy.ops.lengths_angles.interpolate(key_from="Basis", key_to="Bend180", count=1) == {'FINISHED'}
        assert bpy.ops.lengths_angles.encode() == {'FINISHED'}   # the in-between too
        assert bpy.ops.lengths_angles.build_model() == {'FINISHED'}
    obj.lengths_angles_mode_weights[0] = 0.8
    obj.lengths_angles_mode_weights[1] = -0.3
    # a four-marker take on the bar's surface (metres), bound at frame 1
    X = cases.key_coords(obj, "Basis")
    # vertex groups, as a rigged arm has them: the panel names each marker's group
    obj.vertex_groups.new(name="Forearm").add(np.flatnonzero(X[:, 0] < 0).tolist(), 1.0, 'REPLACE')
    obj.vertex_groups.new(name="UpperArm").add(np.flatnonzero(X[:, 0] >= 0).tolist(), 1.0, 'REPLACE')
    picks = [int(np.argmin(np.linalg.norm(X - p, axis=1)))
             for p in ((-4, 0, 0.5), (-1.3, 0, 0.5), (1.3, 0, 0.5), (4, 0, 0.5))]
    frames = np.repeat(X[picks][None], 5, axis=0) + [0.0, 0.0, 0.01]
    path = os.path.join(tmp, "arm_take.c3d")
    write_c3d(path, MarkerTake(labels=("WRIST", "FOREARM", "UPPERARM", "SHOULDER"), positions=frames, rate=60.0,
                               units="m"))
    assert bpy.ops.lengths_angles.import_markers(filepath=path) == {'FINISHED'}
    take = bpy.data.objects["arm_take"]
    for o in bpy.context.view_layer.objects:
        o.select_set(o in (obj, take))
    bpy.context.view_layer.objects.active = obj
    bpy.context.scene.frame_set(1)
    assert bpy.ops.lengths_angles.bind_markers() == {'FINISHED'}
    obj.active_shape_key_index = 1
    return obj


def draw_panels(obj, path):
    """The Shape Keys panel with the key list and the add-on's two sub-panels, as ``path``."""
    import bpy

    from types import SimpleNamespace

    context = SimpleNamespace(object=obj, active_object=obj, scene=bpy.context.scene)
    canvas = Canvas()
    x, y, w = round(8 * S), round(8 * S), WIDTH - round(16 * S)
    top = y
    canvas.rect(x, y, w, U + round(4 * S), "header")
    canvas.text(x + round(6 * S), y, U + round(4 * S), "\u25be", "dim")
    canvas.text(x + round(22 * S), y, U + round(4 * S), "Shape Keys", "text")
    y += U + round(4 * S)
    body = Canvas()
    yy = y + PAD // 2
    yy += shape_key_list(body, obj, x + PAD, yy, w - 2 * PAD) + PAD
    for cls in (bpy.types.LENGTHS_ANGLES_PT_shape_keys, bpy.types.LENGTHS_ANGLES_PT_mocap):
        layout = record(cls.draw, context)
        yy += panel(body, cls.bl_label, layout, x + round(4 * S), yy, w - round(8 * S)) + round(4 * S)
    canvas.rect(x, y, w, yy - y + round(4 * S), "panel", radius=0)
    canvas.shapes += body.shapes
    canvas.texts += body.texts
    height = yy + round(4 * S) + round(8 * S)
    paint(canvas, WIDTH, height - top + round(8 * S), path)
    return height


def draw_dialog(obj, path):
    """The In-betweens dialog (operator ``lengths_angles.interpolate`` invoked from the panel), as ``path``."""
    import bpy

    from types import SimpleNamespace

    cls = bpy.types.LENGTHS_ANGLES_OT_interpolate
    rna = bpy.ops.lengths_angles.interpolate.get_rna_type()
    values = {p.identifier: p.default for p in rna.properties
              if p.identifier != "rna_type" and not (p.type == 'ENUM' and not p.enum_items)}  # (dynamic: below)
    # what the dialog proposes: the reference key -> the active key
    values.update(key_from="Basis", key_to=obj.data.shape_keys.key_blocks[obj.active_shape_key_index].name)
    layout = record(cls.draw, SimpleNamespace(object=obj), owner=values)
    holder = SimpleNamespace(bl_rna=rna, **values)
    for item in _items(layout):
        if item.kind == "prop":
            item.args = (holder, *item.args[1:])
    canvas = Canvas()
    w = round(420 * S)
    x, y = round(8 * S), round(8 * S)
    head = U + round(4 * S)
    canvas.rect(x, y, w, head, "header")
    canvas.text(x, y, head, operator_label("lengths_angles.interpolate"), "text", align="center", w=w)
    inner = Canvas()
    h = place(layout, inner, x + PAD, y + head + PAD // 2, w - 2 * PAD) + PAD
    yb = y + head + h
    bw = round(96 * S)
    inner.rect(x + w - PAD - 2 * bw - GAP * 2, yb, bw, U, "button")
    inner.text(x + w - PAD - 2 * bw - GAP * 2, yb, U, "Cancel", "text", align="center", w=bw)
    inner.rect(x + w - PAD - bw, yb, bw, U, "active")
    inner.text(x + w - PAD - bw, yb, U, "OK", "text", align="center", w=bw)
    canvas.rect(x, y + head, w, h + U + PAD, "panel", radius=0)
    canvas.shapes += inner.shapes
    canvas.texts += inner.texts
    paint(canvas, w + 2 * x, y + head + h + U + PAD + y, path)


def _items(layout):
    for child in layout.children:
        if isinstance(child, Item):
            yield child
        else:
            yield from _items(child)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output", default=os.path.join(REPO, "docs", "images", "panel.png"))
    parser.add_argument("--dialog", default=None, help="also draw the In-betweens dialog to this PNG")
    args = parser.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_panel_"))
    import bpy

    sys.path.insert(0, HERE)
    sys.path.insert(1, REPO)
    from addon_dev import load_addon

    load_addon()
    bpy.context.preferences.filepaths.save_version = 0
    with tempfile.TemporaryDirectory(prefix="lengths_angles_panel_") as tmp:
        obj = build_scene(tmp)
        draw_panels(obj, args.output)
        print(f"wrote {args.output}")
        if args.dialog:
            draw_dialog(obj, args.dialog)
            print(f"wrote {args.dialog}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
