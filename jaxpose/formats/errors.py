"""The one exception the real-data loaders raise for missing or malformed files."""

from __future__ import annotations

from os import PathLike

README_SECTION = 'manual: "Getting the data" (docs/data.md), or for your own rig "Train on your own rig" (docs/rig.md)'


class DataFormatError(ValueError):
    """A data file or folder is missing, unreadable, or not in the documented format.

    The message says where the loader looked, what it expected there and what it found, and points
    to the manual's pages that explain how to get and lay out the data.  Loaders raise it before
    returning anything, so a data set is never half-loaded.
    """

    def __init__(self, where: str | PathLike, expected: str, found: str):
        self.where = printable(str(where))
        self.expected = printable(expected)
        self.found = printable(found)
        super().__init__(f"{self.where}: expected {self.expected}; found {self.found}. See the {README_SECTION}.")


def printable(text: str) -> str:
    """`text` with the bytes of a file name that is not UTF-8 (Python's surrogate escapes) written as
    ``\\xNN``, so that a message naming the file prints on any terminal and into any log."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a lone surrogate that is no escaped byte (from JSON text, say)
        return text.encode("utf-8", "backslashreplace").decode("utf-8")
