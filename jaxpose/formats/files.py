"""Checked readers for the file kinds of the real data sets: HDF5, npz, MATLAB .mat and JSON; and typed JSON,
what jaxpose keeps of its own dataclasses in a cache instead of a pickle (`typed_json`, `from_typed_json`).

Each reader turns a missing, empty, truncated or foreign file into a `DataFormatError` that names
the file and what was expected in it, instead of an h5py / zipfile / pickle traceback.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import pickle
import types
import typing
import zipfile
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import scipy.io

from jaxpose.formats.errors import DataFormatError

# What numpy, zipfile, zlib and pickle raise on an empty, truncated, garbled or foreign .npz file.
_NPZ_ERRORS = (
    OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, pickle.UnpicklingError, AttributeError, ImportError,
)  # fmt: skip
# What h5py raises on a damaged file: OSError mostly; garbled metadata also gives RuntimeError (link
# iteration), KeyError, ValueError, or names that are bytes (TypeError where they meet strings).
_H5_ERRORS = (OSError, RuntimeError, KeyError, ValueError, TypeError, UnicodeDecodeError)


def require_file(path: Path, what: str) -> Path:
    """`path` itself, or a `DataFormatError` saying that `what` was expected there."""
    if not path.is_file():
        raise DataFormatError(path, what, "no such file" if not path.exists() else "not a regular file")
    return path


@contextlib.contextmanager
def open_h5(path: Path, what: str) -> Iterator[h5py.File]:
    """Open an HDF5 file read-only; unreadable files and failed reads (also those of the caller's
    block) become `DataFormatError`."""
    require_file(path, what)
    try:
        with h5py.File(path, "r") as file:
            yield file
    except DataFormatError:  # a ValueError too, raised by the reader about the file's contents
        raise
    except _H5_ERRORS as error:
        raise DataFormatError(path, f"{what} (an HDF5 file)", f"a file h5py cannot read ({error!r})") from None


def h5_dataset(group: h5py.Group, name: str, path: Path, what: str) -> np.ndarray:
    """Read dataset `name` of `group` fully, or raise naming the datasets that are there."""
    node = group.get(name)
    if not isinstance(node, h5py.Dataset):
        found = sorted(group.keys())
        raise DataFormatError(
            f"{path}:{group.name}", f"{what}: a dataset {name!r}", f"only {found}" if found else "an empty group"
        )
    return node[()]


def real_array(value: Any, where: str, what: str) -> np.ndarray:
    """`value` as a numpy array of real numbers (bool, int or float), or a `DataFormatError` naming
    its dtype: strings, complex numbers and Python objects would fail later, far from the file."""
    array = np.asarray(value)
    if array.dtype.kind not in "biuf":
        raise DataFormatError(where, f"{what}: real numbers", f"an array of dtype {array.dtype}, shape {array.shape}")
    return array


def read_h5_dataset(path: Path, name: str, what: str) -> np.ndarray:
    """One whole dataset of one HDF5 file."""
    with open_h5(path, what) as file:
        return h5_dataset(file, name, path, what)


def load_npz_object(path: Path, key: str, what: str) -> Any:
    """The pickled object stored under `key` of an .npz file (the VideoPose3D files store dicts).

    Unpickling runs code from the file, so only load files from a source you trust.
    """
    require_file(path, what)
    try:
        with np.load(path, allow_pickle=True) as archive:
            keys = archive.files
            value = archive[key] if key in keys else None
    except _NPZ_ERRORS as error:
        raise DataFormatError(path, f"{what} (an .npz file)", f"a file numpy cannot read ({error!r})") from None
    if value is None:
        raise DataFormatError(path, f"{what}: an array {key!r}", f"only {sorted(keys)}")
    return value.item() if value.dtype == object and value.shape == () else value


def read_npz_arrays(path: Path, what: str) -> dict[str, np.ndarray]:
    """Every array of an .npz file (no pickled objects: they would run code from the file)."""
    require_file(path, what)
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {key: archive[key] for key in archive.files}
    except _NPZ_ERRORS as error:
        raise DataFormatError(path, f"{what} (an .npz file of plain arrays)", f"a file numpy cannot read ({error!r})") from None


def read_mat(path: Path, names: Sequence[str], what: str) -> dict[str, np.ndarray]:
    """Variables of a MATLAB .mat file, in MATLAB's axis order, whichever kind the file is.

    v7.3 files are HDF5; h5py lists a MATLAB array's axes in reverse (a MATLAB 3x17x1xN array
    reads as N x 1 x 17 x 3), so they are transposed back.  Older files go through
    `scipy.io.loadmat`, which already keeps MATLAB's order.
    """
    require_file(path, what)
    if h5py.is_hdf5(path):
        with open_h5(path, what) as file:
            return {name: np.transpose(h5_dataset(file, name, path, what)) for name in names}
    try:
        variables = scipy.io.loadmat(path, variable_names=list(names))
    except Exception as error:  # scipy raises several unrelated types (MatReadError, ValueError, ...)
        raise DataFormatError(path, f"{what} (a MATLAB .mat file)", f"a file scipy cannot read ({error!r})") from None
    missing = [name for name in names if name not in variables]
    if missing:
        present = sorted(key for key in variables if not key.startswith("__"))
        raise DataFormatError(path, f"{what}: variables {list(names)}", f"{missing} missing (has {present})")
    return {name: variables[name] for name in names}


def read_json(path: Path, what: str) -> Any:
    """A JSON document; invalid text becomes a `DataFormatError` with the parser's position."""
    require_file(path, what)
    try:
        return json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise DataFormatError(path, f"{what} (a JSON file)", f"invalid JSON ({error})") from None


def typed_json(value: Any) -> Any:
    """A frozen dataclass of numpy arrays, numbers, strings, tuples and dicts (a recovered calibration) as JSON,
    each array with its dtype (`from_typed_json` reads it back; nothing in the file names code to run, unlike a pickle)."""
    if dataclasses.is_dataclass(value):
        return {field.name: typed_json(getattr(value, field.name)) for field in dataclasses.fields(value)}
    if isinstance(value, np.ndarray) or hasattr(value, "__array__") and not isinstance(value, (int, float, bool)):
        array = np.asarray(value)
        return {"ndarray": array.tolist(), "dtype": array.dtype.str}
    if isinstance(value, (tuple, list)):
        return [typed_json(item) for item in value]
    if isinstance(value, dict):
        return {key: typed_json(item) for key, item in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def from_typed_json(kind: Any, value: Any) -> Any:
    """The inverse of `typed_json`, guided by the dataclass's type hints (no code named by the file runs)."""
    if isinstance(value, dict) and set(value) == {"ndarray", "dtype"}:
        dtype = np.dtype(value["dtype"])
        if dtype.hasobject:
            raise ValueError(f"an array of {dtype}")
        return np.asarray(value["ndarray"], dtype)
    if isinstance(kind, type) and dataclasses.is_dataclass(kind):
        if not isinstance(value, dict):
            raise ValueError(f"{kind.__name__}: expected an object")
        hints = typing.get_type_hints(kind)
        return kind(**{field.name: from_typed_json(hints[field.name], value[field.name]) for field in dataclasses.fields(kind) if field.name in value})
    if kind is Path and isinstance(value, str):
        return Path(value)
    if typing.get_origin(kind) in (typing.Union, types.UnionType):  # X | None: None, or the one other type
        options = [option for option in typing.get_args(kind) if option is not type(None)]
        return None if value is None else from_typed_json(options[0], value) if len(options) == 1 else value
    if typing.get_origin(kind) is tuple and isinstance(value, list):
        items = typing.get_args(kind)
        items = items[:1] * len(value) if len(items) == 2 and items[1] is Ellipsis else items or (Any,) * len(value)
        if len(items) != len(value):
            raise ValueError(f"{kind}: expected {len(items)} items, found {len(value)}")
        return tuple(from_typed_json(item, entry) for item, entry in zip(items, value))
    if typing.get_origin(kind) is dict:
        if not isinstance(value, dict):
            raise ValueError(f"{kind}: expected an object")
        item = typing.get_args(kind)[1]
        return {name: from_typed_json(item, entry) for name, entry in value.items()}
    return value
