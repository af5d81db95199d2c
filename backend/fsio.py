"""Atomic file output: write to a temporary sibling, fsync, rename.

A reader (or a crash) never sees a half-written file, and a folder of outputs appears
all at once or not at all."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from pathlib import Path

from .errors import InputError

_UMASK = os.umask(0)
os.umask(_UMASK)


def space_error(path, err: OSError) -> Exception:
    """The InputError for a write that failed on a full disk or quota; other errors unchanged."""
    if err.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return InputError(path, f"cannot write: {os.strerror(err.errno).lower()}",
                          "free disk space, raise the quota or choose another output folder")
    return err


def _check_space(path: Path, err: OSError):
    failure = space_error(path, err)
    if failure is err:
        raise err
    raise failure from err


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path next to ``path``; rename it over ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.fchmod(fd, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the usual permissions
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        _check_space(path, err)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes(path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path, text: str) -> None:
    write_bytes(path, text.encode())


def _plain(value):
    """A NumPy scalar as the Python number or bool it holds (``json`` knows only those)."""
    item = getattr(value, "item", None)
    if item is not None and getattr(value, "shape", None) == ():
        return item()
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


def write_json(path, obj, indent: int | None = 2) -> None:
    write_text(path, json.dumps(obj, indent=indent, allow_nan=False, default=_plain) + "\n")


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, replace: bool = False):
    """Yield a temporary folder that becomes ``path`` on success, or vanishes on failure."""
    path = Path(path)
    if path.exists() and any(path.iterdir()) and not replace:
        raise InputError(path, "output folder exists and is not empty",
                         "choose a new folder or pass --overwrite")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    tmp.chmod(0o777 & ~_UMASK)
    try:
        yield tmp
        if path.exists():
            old = path.with_name(f".{path.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except OSError as err:
        shutil.rmtree(tmp, ignore_errors=True)
        _check_space(path, err)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
