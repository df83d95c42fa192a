"""The one checked reader of the files dgtd reads: problems, checkpoints, results and sweep tables.

Every reader here turns what can be wrong with a file (missing, a directory, truncated, not of its kind, holding
Python objects, the wrong columns or fields) into a one-line `DgtdInputError` that names the file, says what is
wrong in the user's words and what to do, so that no command shows a traceback for a file that is not what it
claims to be.
"""

from __future__ import annotations

import csv
import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError


def text_of(path) -> str:
    """A text file's contents, UTF-8 with or without a byte-order mark (an editor's BOM is no part of the text)."""
    return Path(path).read_text(encoding="utf-8-sig")


def present(path: Path, what: str, fix: str) -> Path:
    """``path``, or a one-line refusal naming the file by its role (``what``) and saying what it is instead: a folder,
    a symbolic link to nothing (or a loop of them), missing, or not a regular file (a pipe, which reading would wait
    on for ever without a writer, a socket or a device)."""
    path = Path(path)
    if path.is_dir():
        raise DgtdInputError(f"{what} {path} is a directory, not a file; {fix}")
    if path.is_symlink() and not path.exists():
        raise DgtdInputError(f"{what} {path} is a symbolic link to nothing, or a loop of them; {fix}")
    if not path.exists():
        raise DgtdInputError(f"{what} {path} is missing; {fix}")
    if not path.is_file():
        raise DgtdInputError(
            f"{what} {path} is not a regular file (a pipe, a socket or a device): save what it gives to a file "
            f"first; {fix}"
        )
    return path


def open_npz(path):
    """np.load of an .npz without Python objects; an .npy array saved under an .npz name is refused (np.load would
    hand back the array, which has no named arrays to read)."""
    data = np.load(path, allow_pickle=False)
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise DgtdInputError(
            f"{path} holds one .npy array, not an .npz of named arrays: save the arrays with "
            "numpy.savez(file, NAME=array, ...)"
        )
    return data


def read_npz(path, what: str, fix: str, required=()) -> dict:
    """The arrays of an .npz file (read whole, without Python objects), with the arrays ``required`` present."""
    path = present(path, what, fix)
    try:
        with open_npz(path) as data:
            arrays = {k: data[k] for k in data.files}
    except DgtdInputError as e:
        raise DgtdInputError(f"{what} {e}; {fix}") from None
    except ValueError as e:
        # np.load takes any file that is neither .npy nor .npz for a pickle of Python objects
        reason = "it is not an .npz file of plain arrays" if "pickle" in str(e) else str(e)
        raise DgtdInputError(f"{what} {path} cannot be read: {reason}; {fix}") from None
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, KeyError) as e:
        raise DgtdInputError(f"{what} {path} is not a complete .npz file ({type(e).__name__}); {fix}") from None
    missing = [k for k in required if k not in arrays]
    if missing:
        raise DgtdInputError(f"{what} {path} lacks {', '.join(missing)}; {fix}")
    return arrays


def read_json(path, what: str, fix: str, required=()) -> dict:
    """A JSON object from a file, with the keys ``required`` present."""
    path = present(path, what, fix)
    try:
        data = json.loads(text_of(path))
    except (ValueError, UnicodeDecodeError) as e:
        raise DgtdInputError(f"{what} {path} is not valid JSON ({e}); {fix}") from None
    if not isinstance(data, dict):
        raise DgtdInputError(f"{what} {path} does not hold a JSON object; {fix}")
    missing = [k for k in required if k not in data]
    if missing:
        raise DgtdInputError(f"{what} {path} lacks {', '.join(missing)}; {fix}")
    return data


def read_csv(path, what: str, fix: str, required=()) -> list[dict]:
    """The rows of a CSV file with a header, as dicts, with the columns ``required`` present and filled."""
    path = present(path, what, fix)
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            rows = list(reader)
            header = reader.fieldnames or []
    except (UnicodeDecodeError, csv.Error) as e:
        raise DgtdInputError(f"{what} {path} is not a CSV table ({e}); {fix}") from None
    missing = [k for k in required if k not in header]
    if missing:
        raise DgtdInputError(f"{what} {path} lacks the column(s) {', '.join(missing)}; {fix}")
    if any(None in r.values() or None in r for r in rows):
        raise DgtdInputError(f"{what} {path} has rows shorter or longer than its header (cut off?); {fix}")
    return rows


def numbers(rows: list[dict], column: str, kind, path, what: str, fix: str) -> np.ndarray:
    """Column ``column`` of CSV rows as an array of ``kind`` (int or float)."""
    try:
        return np.asarray([kind(r[column]) for r in rows], dtype=np.float64 if kind is float else np.int64)
    except ValueError as e:
        raise DgtdInputError(
            f"{what} {path}: column {column} holds something that is not a number ({e}); {fix}"
        ) from None
