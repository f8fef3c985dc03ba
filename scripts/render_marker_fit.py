"""Render the marker-fitting comparison picture (docs/images/marker_fitting.png) with NumPy only.

Reads the ``.npz`` written by ``benchmarks/bench_marker_fitting.py --save FILE`` and draws, for a few frames
(columns), the true mesh with its markers and the three fits (lengths-and-angles model, vertex PCA, mean-only
prior) coloured by per-vertex error (white 0 -> red >= 50 mm): an orthographic triangle z-buffer rasterizer with
Lambert shading, written to PNG by zlib.

Usage::

    python scripts/render_marker_fit.py FIT.npz -o docs/images/marker_fitting.png [--frames 20 75 130]
"""

import argparse
import os
import struct
import zlib

import numpy as np

ERR_MAX_MM = 50.0


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
    t = np.clip(err_mm / ERR_MAX_MM, 0, 1)[:, None]
    return (1 - t) * np.array([0.92, 0.92, 0.92]) + t * np.array([0.85, 0.1, 0.1])


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("fit")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--frames", type=int, nargs="+", default=None)
    args = p.parse_args(argv)
    d = np.load(args.fit)
    true, faces, markers = d["true"], d["faces"], d["markers"]
    fits = [("la", d["la"]), ("pca", d["pca"]), ("mean", d["mean_only"])]
    T = len(true)
    frames = args.frames or [int(T * 0.15), int(T * 0.5), int(T * 0.85)]
    cell = (300, 190)  # (height, width) per panel
    rows = 1 + len(fits)
    image = np.ones((rows * cell[0], len(frames) * cell[1], 3))
    depth = np.full(image.shape[:2], -np.inf)
    for j, t in enumerate(frames):
        X = true[t]
        centre = 0.5 * (X.min(0) + X.max(0))
        # look at the body from its front: the root's forward direction, or front minus back waist markers
        if "root_rotation" in d.files:
            heading = d["root_rotation"][t] @ np.array([0.0, 0.0, 1.0])
        else:
            m = markers[max(t - 5, 0):t + 6]
            heading = np.nanmean(m[:, 9:11].reshape(-1, 3), 0) - np.nanmean(m[:, 11:13].reshape(-1, 3), 0)
        heading = heading.copy()
        heading[1] = 0.0
        heading /= np.linalg.norm(heading)
        zc = heading
        yc = np.array([0.0, 1.0, 0.0])
        xc = np.cross(yc, zc)
        view = np.stack([xc, yc, zc])
        scale = 0.9 * cell[0] / 18.0
        for i in range(rows):
            off = (i * cell[0], j * cell[1])
            if i == 0:
                rasterize(X, faces, np.tile([0.75, 0.8, 0.9], (len(X), 1)), view, cell, image, depth, off, scale,
                          centre)
                draw_points(image, depth, markers[t], view, cell, off, scale, centre, np.array([0.1, 0.6, 0.1]))
            else:
                V = fits[i - 1][1][t]
                err = np.linalg.norm(V - X, axis=1) * 100.0
                rasterize(V, faces, error_colors(err), view, cell, image, depth, off, scale, centre)
    write_png(args.output, (np.clip(image, 0, 1) * 255).astype(np.uint8))


if __name__ == "__main__":
    main()
