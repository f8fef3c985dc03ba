"""Sample data generators (not shipped data).

:mod:`.bar` -- a closed box bar bent and twisted by known angles (a shape family of dimension 2);
:mod:`.human` -- the CC0 human body of ``shared/data/human`` posed by linear-blend skinning;
:mod:`.markers` -- a standard full-body marker set on it, observed with offset, noise and occlusion;
:mod:`.simple_deform` -- a box bar and Blender's Simple Deform 'BEND' applied analytically (an exact bend).
"""
