"""Render the marker-fitting comparison picture (docs/images/marker_fitting.png) with NumPy only.

Reads the ``.npz`` written by ``benchmarks/bench_marker_fitting.py --save FILE`` and draws, for a few frames
(columns), the true mesh with its markers and the three fits (lengths-and-angles model, vertex PCA, mean-only
prior) coloured by per-vertex error (white 0 -> red >= 50 mm), each row titled with its mean error, and a
legend: an orthographic triangle z-buffer rasterizer with Lambert shading, labels in the bitmap font of
``scripts/raster_text.py``, written to PNG by zlib.  ``make demo`` draws its ``human_fit.png`` with
:func:`figure` too.

Usage::

    python scripts/run_benchmarks.py --only bench_marker_fitting --extra=--save --extra=FIT.npz
    python scripts/render_marker_fit.py FIT.npz -o docs/images/marker_fitting.png [--frames 20 75 130]
"""

import argparse
import os
import struct
import zlib

import numpy as np
from raster_text import color_bar, draw_text, text_size

ERR_MAX_MM = 50.0
TRUE_COLOR = np.array([0.75, 0.8, 0.9])
MARKER_COLOR = np.array([0.1, 0.6, 0.1])
TEXT_SCALE = 2


def write_png(path, rgb):
    """Write an ``(H, W, 3)`` uint8 image as PNG."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[i].tobytes() for i in range(h))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    tmp = path + ".tmp"
    with open(tmp, "wb") as fh:
        fh.write(png)
    os.replace(tmp, path)


def rasterize(X, F, colors, view, size, image, depth, offset, scale, centre):
    """Draw triangles ``F`` of ``X`` (V,3) with per-vertex ``colors`` (V,3) into ``image`` at pixel ``offset``.

    ``view`` (3,3) rotates world to camera (x right, y up, z toward the viewer); orthographic projection with
    ``scale`` pixels per unit around ``centre``.
    """
    P = (X - centre) @ view.T
    px = P[:, 0] * scale + size[1] / 2 + offset[1]
    py = -P[:, 1] * scale + size[0] / 2 + offset[0]
    pz = P[:, 2]
    n = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-30
    light = np.array([0.3, 0.5, 0.8])
    light /= np.linalg.norm(light)
    shade = 0.25 + 0.75 * np.abs(n @ light)
    H, W = image.shape[:2]
    for f in range(len(F)):
        a, b, c = F[f]
        x0, x1 = int(max(np.floor(min(px[a], px[b], px[c])), 0)), int(min(np.ceil(max(px[a], px[b], px[c])), W - 1))
        y0, y1 = int(max(np.floor(min(py[a], py[b], py[c])), 0)), int(min(np.ceil(max(py[a], py[b], py[c])), H - 1))
        if x1 < x0 or y1 < y0:
            continue
        gx, gy = np.meshgrid(np.arange(x0, x1 + 1) + 0.5, np.arange(y0, y1 + 1) + 0.5)
        d = (py[b] - py[c]) * (px[a] - px[c]) + (px[c] - px[b]) * (py[a] - py[c])
        if abs(d) < 1e-12:
            continue
        l0 = ((py[b] - py[c]) * (gx - px[c]) + (px[c] - px[b]) * (gy - py[c])) / d
        l1 = ((py[c] - py[a]) * (gx - px[c]) + (px[a] - px[c]) * (gy - py[c])) / d
        l2 = 1 - l0 - l1
        inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        if not inside.any():
            continue
        z = l0 * pz[a] + l1 * pz[b] + l2 * pz[c]
        sub = depth[y0:y1 + 1, x0:x1 + 1]
        hit = inside & (z > sub)
        if not hit.any():
            continue
        sub[hit] = z[hit]
        col = (l0[..., None] * colors[a] + l1[..., None] * colors[b] + l2[..., None] * colors[c]) * shade[f]
        image[y0:y1 + 1, x0:x1 + 1][hit] = col[hit]


def draw_points(image, depth, points, view, size, offset, scale, centre, color, radius=3):
    P = (points - centre) @ view.T
    H, W = image.shape[:2]
    for p in P[np.isfinite(P).all(1)]:
        x = int(p[0] * scale + size[1] / 2 + offset[1])
        y = int(-p[1] * scale + size[0] / 2 + offset[0])
        image[max(y - radius, 0):min(y + radius + 1, H), max(x - radius, 0):min(x + radius + 1, W)] = color


def error_colors(err_mm):
    """Per-vertex colours: white at 0 mm to red at :data:`ERR_MAX_MM` and beyond."""
    t = np.clip(np.asarray(err_mm, float) / ERR_MAX_MM, 0, 1)[..., None]
    return (1 - t) * np.array([0.92, 0.92, 0.92]) + t * np.array([0.85, 0.1, 0.1])


def front_view(heading):
    """World -> camera rotation looking at a body from the front: ``heading`` (3,) is its forward direction
    (y is up; only the horizontal part counts)."""
    zc = np.array(heading, float)
    zc[1] = 0.0
    zc /= np.linalg.norm(zc)
    yc = np.array([0.0, 1.0, 0.0])
    return np.stack([np.cross(yc, zc), yc, zc])


def figure(panels, n_rows, n_cols, faces, cell=(300, 190), col_titles=None, row_titles=None, title=None,
           body_height=18.0):
    """A grid of rendered bodies with titles and a legend; returns the ``(H, W, 3)`` float image.

    ``panels``: ``[(row, col, vertices (V, 3), colors (V, 3), markers (M, 3) or None, view (3, 3),
    centre (3,))]``.  ``col_titles`` go above the columns, ``row_titles`` above each row, ``title`` on top;
    the legend (marker swatch, error colour bar) at the bottom.  ``body_height`` (scene units) fills 90 % of
    a cell's height.
    """
    s = TEXT_SCALE
    strip = 13 * s
    top = (strip if title else 0) + (strip if col_titles else 0)
    row_h = cell[0] + (strip if row_titles else 0)
    legend_h = 30 * s
    H, W = top + n_rows * row_h + legend_h, n_cols * cell[1]
    image = np.ones((H, W, 3))
    depth = np.full((H, W), -np.inf)
    scale = 0.9 * cell[0] / body_height
    y = 2 * s
    if title:
        draw_text(image, title, 4 * s, y, s)
        y += strip
    for j, text in enumerate(col_titles or []):
        tw, _ = text_size(text, s)
        draw_text(image, text, j * cell[1] + max((cell[1] - tw) // 2, 0), y, s)
    for i, text in enumerate(row_titles or []):
        draw_text(image, text, 4 * s, top + i * row_h + 2 * s, s)
    for i, j, X, colors, markers, view, centre in panels:
        off = (top + i * row_h + (strip if row_titles else 0), j * cell[1])
        rasterize(X, faces, colors, view, cell, image, depth, off, scale, centre)
        if markers is not None:
            draw_points(image, depth, markers, view, cell, off, scale, centre, MARKER_COLOR)
    # legend: marker swatch, then the error colour bar
    ly = top + n_rows * row_h + 6 * s
    x = 4 * s
    image[ly + s:ly + 7 * s, x:x + 6 * s] = MARKER_COLOR
    draw_text(image, "marker", x + 9 * s, ly, s)
    x += 9 * s + text_size("marker", s)[0] + 12 * s
    bar_w = min(75 * s, W - x - text_size("error vs true pose", s)[0] - 8 * s)
    color_bar(image, x, ly, bar_w, 8 * s, error_colors_unit, [(0.0, "0"), (0.5, "25"), (1.0, "50+ mm")],
              "error vs true pose", s)
    return image


def error_colors_unit(t):
    """:func:`error_colors` on ``t`` in [0, 1] (a fraction of :data:`ERR_MAX_MM`)."""
    return error_colors(np.asarray(t) * ERR_MAX_MM)


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("fit")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--frames", type=int, nargs="+", default=None)
    args = p.parse_args(argv)
    d = np.load(args.fit)
    true, faces, markers = d["true"], d["faces"], d["markers"]
    fits = [("lengths & angles fit", d["la"]), ("vertex PCA fit (baseline)", d["pca"]),
            ("mean-only prior", d["mean_only"])]
    T = len(true)
    frames = args.frames or [int(T * 0.15), int(T * 0.5), int(T * 0.85)]
    panels = []
    row_titles = ["true pose + markers"]
    for name, V in fits:
        err = np.linalg.norm(V - true, axis=2) * 100.0   # decimetres -> mm
        row_titles.append(f"{name}: mean error {err.mean():.1f} mm")
    for j, t in enumerate(frames):
        X = true[t]
        centre = 0.5 * (X.min(0) + X.max(0))
        # look at the body from its front: the root's forward direction, or front minus back waist markers
        if "root_rotation" in d.files:
            heading = d["root_rotation"][t] @ np.array([0.0, 0.0, 1.0])
        else:
            m = markers[max(t - 5, 0):t + 6]
            heading = np.nanmean(m[:, 9:11].reshape(-1, 3), 0) - np.nanmean(m[:, 11:13].reshape(-1, 3), 0)
        view = front_view(heading)
        panels.append((0, j, X, np.tile(TRUE_COLOR, (len(X), 1)), markers[t], view, centre))
        for i, (_, V) in enumerate(fits, start=1):
            err = np.linalg.norm(V[t] - X, axis=1) * 100.0
            panels.append((i, j, V[t], error_colors(err), None, view, centre))
    image = figure(panels, 1 + len(fits), len(frames), faces, col_titles=[f"frame {t}" for t in frames],
                   row_titles=row_titles, title=f"held-out take, errors: mean over its {T} frames")
    write_png(args.output, (np.clip(image, 0, 1) * 255).astype(np.uint8))


if __name__ == "__main__":
    main()
