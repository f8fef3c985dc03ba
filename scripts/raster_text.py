# SPDX-License-Identifier: GPL-3.0-or-later
"""Labels for the NumPy-rendered pictures: a 5 x 7 bitmap font (descenders below), drawn into float images.

The pictures of ``scripts/render_marker_fit.py`` and ``make demo`` are drawn with NumPy alone; this module
writes their titles and legends with the same means.  Each glyph is 5 columns wide and 9 rows tall (7 above
the baseline, 2 for descenders); ``scale`` enlarges every pixel to a ``scale x scale`` block.

>>> import numpy as np
>>> image = np.ones((30, 80, 3))
>>> text_size("mm", scale=2)
(22, 18)
>>> draw_text(image, "0 mm", 2, 2, scale=2)
>>> bool((image < 0.5).any())
True
"""

import numpy as np

__all__ = ["GLYPHS", "color_bar", "draw_text", "text_size"]

_ROWS = {
    "A": ".###. #...# #...# ##### #...# #...# #...#",
    "B": "####. #...# #...# ####. #...# #...# ####.",
    "C": ".###. #...# #.... #.... #.... #...# .###.",
    "D": "####. #...# #...# #...# #...# #...# ####.",
    "E": "##### #.... #.... ####. #.... #.... #####",
    "F": "##### #.... #.... ####. #.... #.... #....",
    "G": ".###. #...# #.... #.### #...# #...# .####",
    "H": "#...# #...# #...# ##### #...# #...# #...#",
    "I": ".###. ..#.. ..#.. ..#.. ..#.. ..#.. .###.",
    "J": "..### ...#. ...#. ...#. ...#. #..#. .##..",
    "K": "#...# #..#. #.#.. ##... #.#.. #..#. #...#",
    "L": "#.... #.... #.... #.... #.... #.... #####",
    "M": "#...# ##.## #.#.# #.#.# #...# #...# #...#",
    "N": "#...# #...# ##..# #.#.# #..## #...# #...#",
    "O": ".###. #...# #...# #...# #...# #...# .###.",
    "P": "####. #...# #...# ####. #.... #.... #....",
    "Q": ".###. #...# #...# #...# #.#.# #..#. .##.#",
    "R": "####. #...# #...# ####. #.#.. #..#. #...#",
    "S": ".#### #.... #.... .###. ....# ....# ####.",
    "T": "##### ..#.. ..#.. ..#.. ..#.. ..#.. ..#..",
    "U": "#...# #...# #...# #...# #...# #...# .###.",
    "V": "#...# #...# #...# #...# #...# .#.#. ..#..",
    "W": "#...# #...# #...# #.#.# #.#.# #.#.# .#.#.",
    "X": "#...# #...# .#.#. ..#.. .#.#. #...# #...#",
    "Y": "#...# #...# .#.#. ..#.. ..#.. ..#.. ..#..",
    "Z": "##### ....# ...#. ..#.. .#... #.... #####",
    "a": "..... ..... .###. ....# .#### #...# .####",
    "b": "#.... #.... ####. #...# #...# #...# ####.",
    "c": "..... ..... .###. #.... #.... #...# .###.",
    "d": "....# ....# .#### #...# #...# #...# .####",
    "e": "..... ..... .###. #...# ##### #.... .###.",
    "f": "..##. .#..# .#... ###.. .#... .#... .#...",
    "g": "..... ..... .#### #...# #...# #...# .#### ....# .###.",
    "h": "#.... #.... #.##. ##..# #...# #...# #...#",
    "i": "..#.. ..... .##.. ..#.. ..#.. ..#.. .###.",
    "j": "...#. ..... ..##. ...#. ...#. ...#. ...#. #..#. .##..",
    "k": "#.... #.... #..#. #.#.. ##... #.#.. #..#.",
    "l": ".##.. ..#.. ..#.. ..#.. ..#.. ..#.. .###.",
    "m": "..... ..... ##.#. #.#.# #.#.# #.#.# #.#.#",
    "n": "..... ..... #.##. ##..# #...# #...# #...#",
    "o": "..... ..... .###. #...# #...# #...# .###.",
    "p": "..... ..... ####. #...# #...# #...# ####. #.... #....",
    "q": "..... ..... .#### #...# #...# #...# .#### ....# ....#",
    "r": "..... ..... #.##. ##..# #.... #.... #....",
    "s": "..... ..... .###. #.... .###. ....# ####.",
    "t": ".#... .#... ###.. .#... .#... .#..# ..##.",
    "u": "..... ..... #...# #...# #...# #..## .##.#",
    "v": "..... ..... #...# #...# #...# .#.#. ..#..",
    "w": "..... ..... #...# #...# #.#.# #.#.# .#.#.",
    "x": "..... ..... #...# .#.#. ..#.. .#.#. #...#",
    "y": "..... ..... #...# #...# #...# #...# .#### ....# .###.",
    "z": "..... ..... ##### ...#. ..#.. .#... #####",
    "0": ".###. #...# #..## #.#.# ##..# #...# .###.",
    "1": "..#.. .##.. ..#.. ..#.. ..#.. ..#.. .###.",
    "2": ".###. #...# ....# ...#. ..#.. .#... #####",
    "3": "##### ...#. ..#.. ...#. ....# #...# .###.",
    "4": "...#. ..##. .#.#. #..#. ##### ...#. ...#.",
    "5": "##### #.... ####. ....# ....# #...# .###.",
    "6": "..##. .#... #.... ####. #...# #...# .###.",
    "7": "##### ....# ...#. ..#.. .#... .#... .#...",
    "8": ".###. #...# #...# .###. #...# #...# .###.",
    "9": ".###. #...# #...# .#### ....# ...#. .##..",
    " ": "..... ..... ..... ..... ..... ..... .....",
    ".": "..... ..... ..... ..... ..... .##.. .##..",
    ",": "..... ..... ..... ..... ..... ..#.. ..#.. .#...",
    ":": "..... .##.. .##.. ..... .##.. .##.. .....",
    "-": "..... ..... ..... .###. ..... ..... .....",
    "+": "..... ..#.. ..#.. ##### ..#.. ..#.. .....",
    "=": "..... ..... ##### ..... ##### ..... .....",
    "&": ".##.. #..#. #.#.. .#... #.#.# #..#. .##.#",
    "(": "...#. ..#.. .#... .#... .#... ..#.. ...#.",
    ")": ".#... ..#.. ...#. ...#. ...#. ..#.. .#...",
    "/": "....# ....# ...#. ..#.. .#... #.... #....",
    "%": "##... ##..# ...#. ..#.. .#... #..## ...##",
    ">": ".#... ..#.. ...#. ....# ...#. ..#.. .#...",
    "<": "...#. ..#.. .#... #.... .#... ..#.. ...#.",
    "'": "..#.. ..#.. .#... ..... ..... ..... .....",
}

#: glyph bitmaps, ``(9, 5)`` bool arrays (rows 0-6 above the baseline, 7-8 descenders)
GLYPHS = {}
for _char, _text in _ROWS.items():
    _rows = [[c == "#" for c in row] for row in _text.split()]
    GLYPHS[_char] = np.array(_rows + [[False] * 5] * (9 - len(_rows)), bool)

_ADVANCE = 6  # glyph width + one column of space


def text_size(text, scale=2):
    """``(width, height)`` in pixels of ``text`` drawn at ``scale`` (height includes descenders)."""
    return (max(len(text) * _ADVANCE - 1, 0) * scale, 9 * scale)


def draw_text(image, text, x, y, scale=2, color=(0.1, 0.1, 0.1)):
    """Draw ``text`` into ``image`` ``(H, W, 3)`` float with its top-left corner at pixel column ``x``, row ``y``.

    Characters without a glyph are drawn as blanks; parts outside the image are clipped.
    """
    H, W = image.shape[:2]
    color = np.asarray(color, float)
    for i, char in enumerate(text):
        glyph = GLYPHS.get(char, GLYPHS[" "])
        block = np.kron(glyph, np.ones((scale, scale), bool))
        x0, y0 = x + i * _ADVANCE * scale, y
        ys, xs = np.nonzero(block)
        ys, xs = ys + y0, xs + x0
        keep = (ys >= 0) & (ys < H) & (xs >= 0) & (xs < W)
        image[ys[keep], xs[keep]] = color


def color_bar(image, x, y, width, height, colormap, ticks, label="", scale=2, color=(0.1, 0.1, 0.1)):
    """A horizontal colour bar at ``(x, y)``: ``colormap(t)`` for ``t`` in [0, 1] left to right, a thin frame,
    ``ticks`` (``[(t, text), ...]``) written below it and ``label`` to its right."""
    t = np.linspace(0.0, 1.0, width)
    image[y:y + height, x:x + width] = colormap(t)[None, :, :]
    frame = np.asarray(color, float)
    image[y, x:x + width] = image[y + height - 1, x:x + width] = frame
    image[y:y + height, x] = image[y:y + height, x + width - 1] = frame
    for pos, text in ticks:
        px = x + int(round(pos * (width - 1)))
        image[y + height:y + height + 3 * scale, px] = frame
        tw, _ = text_size(text, scale)
        draw_text(image, text, min(max(px - tw // 2, 0), image.shape[1] - tw), y + height + 4 * scale, scale, color)
    if label:
        draw_text(image, label, x + width + 6 * scale, y + (height - 7 * scale) // 2, scale, color)
