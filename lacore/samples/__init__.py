"""Sample data generators (not shipped data).

:mod:`.bar` -- a closed box bar bent and twisted by known angles (a shape family of dimension 2);
:mod:`.human` -- the CC0 human body of ``shared/data/human`` posed by linear-blend skinning.
"""
