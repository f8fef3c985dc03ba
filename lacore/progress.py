"""Progress reporting and cancellation: the one mechanism of every long-running lacore entry point.

A *progress callback* is any callable ``progress(done, total, message)``:

``done``, ``total`` : int
    Units of work finished so far and in all (frames, samples, iterations...);
    ``done`` goes from 0 to ``total``.
``message`` : str
    What is being done, e.g. ``"frame 3 of 10"``.

If the callback returns ``True`` the computation stops at the next safe point
and raises :class:`Cancelled`; any other return value (``None``, ``False``)
lets it go on.  Entry points take it as ``progress=None`` and call
:func:`report` between units of work; the Blender add-on passes a callback
that updates the progress bar and returns ``True`` after Esc.
"""

__all__ = ["Cancelled", "report", "ProgressCallback"]

from collections.abc import Callable

#: Signature of a progress callback (see the module docstring).
ProgressCallback = Callable[[int, int, str], "bool | None"]


class Cancelled(Exception):
    """The progress callback asked the computation to stop.

    ``partial`` holds whatever the entry point documents as its partial
    result (``None`` if it keeps nothing).

    Examples
    --------
    A progress callback that returns True stops the computation:

    >>> from lacore import Cancelled
    >>> from lacore.progress import report
    >>> try:
    ...     report(lambda done, total, message: True, 1, 4, "frame 2")
    ... except Cancelled as exc:
    ...     print(exc)
    cancelled after 1 of 4 (frame 2)
    """

    def __init__(self, message="cancelled", partial=None):
        super().__init__(message)
        self.partial = partial


def report(progress, done, total, message="", partial=None):
    """Call ``progress(done, total, message)`` if given; raise :class:`Cancelled` if it returns True.

    ``partial`` (optional) is attached to the :class:`Cancelled` exception.
    """
    if progress is not None and progress(int(done), int(total), str(message)) is True:
        raise Cancelled(f"cancelled after {done} of {total}" + (f" ({message})" if message else ""), partial)
