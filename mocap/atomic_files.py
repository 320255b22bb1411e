"""Files written whole or not at all: every file the capture product and the bench write goes through here.

A file is written under a temporary name of its own beside the target (hidden, ``.NAME.XXXXXXXX.tmp``,
made with ``O_EXCL``, so no other process and no file of the user's has it) and renamed onto the
target only when the writing succeeded; on any error the temporary file is removed and the target is as it
was. Why one helper: the writers each had their own temporary name, and some shared a fixed one
(``NAME.tmp``), which two processes writing the same file at once interleaved (the colour shirt's cached pose
database came out corrupt that way, session 27) and which would overwrite a user's file of that name.
"""

from __future__ import annotations

import os
import secrets
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from mocap.errors import MocapInputError

__all__ = ["atomic_target", "atomic_write_text", "atomic_write_bytes", "check_output_file"]


@contextmanager
def atomic_target(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a new, empty temporary path beside ``path``; rename it onto ``path`` if the block succeeds.

    Parameters
    ----------
    path : path-like
        The file to write. Its folder must exist.
    suffix : str
        Ending of the temporary name, for writers that choose their format by it or append it
        (``".yml"`` for OpenCV's ``FileStorage``, ``".npz"`` for ``numpy.savez``, ``".c3d"`` for ezc3d).
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise MocapInputError(f"{path}: the folder {str(path.parent)!r} does not exist; create it or choose another output path")
    tmp = _new_temporary(path, suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _new_temporary(path: Path, suffix: str) -> Path:
    """Create an empty ``.NAME.XXXXXXXX.tmp<suffix>`` beside ``path`` that no other call has, with the mode a plain
    write gives (``0o666`` less the umask; ``tempfile.mkstemp``'s ``0o600`` would make every output private)."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp{suffix}")
        try:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(f"{path}: no free temporary name beside it")


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all."""
    with atomic_target(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, fsync: bool = False) -> None:
    """Write ``data`` to ``path`` whole or not at all; ``fsync``: flushed to the disk before the rename
    (a results store that must survive a power cut)."""
    with atomic_target(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())


def check_output_file(path: str | os.PathLike, ours: Callable[[Path], bool], what: str, *,
                      error: type[Exception] = MocapInputError,
                      how: str = "choose another path, or move or remove it yourself") -> None:
    """Before any work: a single-file output ``path`` may be written when it does not exist, or when ``ours(path)``
    says it is ``what`` (the kind of file this writer writes, which a rerun replaces). Otherwise raises ``error``
    with one line naming the path and ``how`` to go on: a file the writer did not write is never replaced."""
    path = Path(path)
    if path.is_symlink():
        raise error(f"{path}: is a symbolic link; it will not be replaced; {how}")
    if not path.exists():
        return
    if not path.is_file():
        raise error(f"{path}: exists and is not a file; it will not be replaced; {how}")
    try:
        mine = ours(path)
    except OSError:
        mine = False
    if not mine:
        raise error(f"{path}: exists and is not {what}; it will not be replaced; {how}")
