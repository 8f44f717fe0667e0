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
        self.where = str(where)
        self.expected = expected
        self.found = found
        super().__init__(f"{self.where}: expected {expected}; found {found}. See the {README_SECTION}.")
