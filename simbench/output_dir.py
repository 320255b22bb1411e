"""Output folders the bench may replace, and only those.

Every folder the bench writes (``simbench render``, ``simbench run``, the run folders of
sweeps and checks) is built in a temporary sibling ``.NAME.partial-XXXXXXXX`` and moved
to its final path only when complete. Rules, so that no user data is ever deleted:

* every output folder carries a marker file, :data:`MARKER` (``.simbench-output.json``:
  tool, version, scenario name, kind, host and pid of the process that wrote it). It is
  written into the partial folder the moment that folder is made;
* an existing output path is replaced only if it is a folder holding that marker. An
  existing **empty** folder (e.g. one the user made for the output) is filled. Anything
  else (a file, a symbolic link, a folder without the marker, even one with a single
  file in it) is refused with :class:`OutputPathError` before anything is rendered;
* a folder name derived from a scenario's ``name`` (``out/<name>``) must be a plain
  name: not empty, no path separator, not ``.`` or ``..`` (:func:`check_plain_name`);
* partial folders left behind by a killed process (SIGKILL, power loss) are removed by
  the next output made in the same parent folder, but only those that carry the marker
  and whose writing process (same host, recorded pid) is gone
  (:func:`remove_stale_partials`).

The final move swaps the new folder with the old one atomically where the system can
(Linux ``renameat2(RENAME_EXCHANGE)``), so at every instant the output path holds either
the old result or the new one; the old one is then deleted.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import secrets
import shutil
import socket
import sys
import time
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Literal

from simbench import interrupts
from simbench.errors import SimbenchInputError

#: Name of the marker file in every folder the bench writes.
MARKER = ".simbench-output.json"
_TOOL = "simbench"
PARTIAL_INFIX = ".partial-"

OutputKind = Literal["run", "render", "report"]


class OutputPathError(SimbenchInputError):
    """An output path the bench must not replace, or a scenario name that is not a plain folder name."""


@dataclass(frozen=True)
class OutputMarker:
    """Contents of :data:`MARKER`."""

    tool: str
    version: str
    scenario: str
    kind: str
    host: str
    pid: int
    created_utc: str

    @classmethod
    def for_this_process(cls, scenario: str, kind: str) -> "OutputMarker":
        return cls(tool=_TOOL, version=_version(), scenario=scenario, kind=kind, host=socket.gethostname(),
                   pid=os.getpid(), created_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))

    def to_json(self) -> str:
        return json.dumps(self.__dict__, indent=1) + "\n"


def _version() -> str:
    try:
        return metadata.version("simbench")
    except metadata.PackageNotFoundError:
        return "unknown"


def read_marker(folder: Path) -> OutputMarker | None:
    """The marker of ``folder``, or None when it has none (or not one the bench wrote)."""
    try:
        data = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("tool") != _TOOL:
        return None
    try:
        return OutputMarker(tool=_TOOL, version=str(data.get("version", "")), scenario=str(data.get("scenario", "")),
                            kind=str(data.get("kind", "")), host=str(data.get("host", "")), pid=int(data.get("pid", 0)),
                            created_utc=str(data.get("created_utc", "")))
    except (TypeError, ValueError):
        return None


def check_plain_name(name: str, source: Path | str, field: str = "name") -> str:
    """``name`` if it can be used as one folder name under ``out/``; else :class:`OutputPathError`.

    ``source`` is the file the name came from (named in the message).
    """
    bad = ""
    if not name.strip():
        bad = "it is empty"
    elif name in (".", ".."):
        bad = f"'{name}' is not a folder name"
    elif "/" in name or "\\" in name or os.sep in name or (os.altsep and os.altsep in name):
        bad = "it contains a path separator"
    elif "\x00" in name:
        bad = "it contains a NUL character"
    if bad:
        raise OutputPathError(f"{source}: field '{field}': got {name!r}: {bad}; the default output folder is out/<{field}>, "
                              f"so use a plain name such as 'my_run' (letters, digits, '_', '-', '.'), or pass --out DIR")
    return name


def default_run_dir(name: str, source: Path | str, root: Path = Path("out")) -> Path:
    """``out/<name>`` after checking that ``name`` is a plain folder name."""
    return root / check_plain_name(name, source)


def replaceable_state(out: Path) -> Literal["absent", "empty", "ours"]:
    """How ``out`` may be written: it does not exist, is an empty folder, or is a bench output.

    Raises :class:`OutputPathError` (one line naming the path and what to do) otherwise.
    """
    how = "choose another --out, or move or remove it yourself"
    if out.is_symlink():
        raise OutputPathError(f"{out}: is a symbolic link; simbench does not replace it; {how}")
    if not out.exists():
        return "absent"
    if not out.is_dir():
        raise OutputPathError(f"{out}: exists and is not a folder; simbench will not replace it; {how}")
    if read_marker(out) is not None:
        return "ours"
    try:
        empty = not any(out.iterdir())
    except OSError as exc:
        raise OutputPathError(f"{out}: cannot be read ({exc.strerror}); {how}") from None
    if empty:
        return "empty"
    raise OutputPathError(f"{out}: exists and was not written by simbench (no {MARKER} in it); it will not be "
                          f"replaced or deleted; {how}")


def pid_alive(pid: int) -> bool:
    """Whether a process of this host with ``pid`` exists (True when unsure: keep its files)."""
    if pid <= 0:
        return True  # unknown: keep the folder
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_partials(parent: Path) -> list[Path]:
    """Remove ``.*.partial-*`` folders in ``parent`` left by a bench process that is gone.

    Only folders carrying the bench's marker, written on this host by a pid that no
    longer exists, are removed (a live run's partial folder, or one written by another
    host on a shared file system, is left alone). Returns the folders removed.
    """
    removed: list[Path] = []
    if not parent.is_dir():
        return removed
    host = socket.gethostname()
    for p in parent.glob(f".*{PARTIAL_INFIX}*"):
        if p.is_symlink() or not p.is_dir():
            continue
        m = read_marker(p)
        if m is None or m.host != host or m.pid == os.getpid() or pid_alive(m.pid):
            continue
        shutil.rmtree(p, ignore_errors=True)
        if not p.exists():
            removed.append(p)
    return removed


def _make_partial(parent: Path, name: str) -> Path:
    # Not tempfile.mkdtemp: it makes the folder 0700, and that mode would become the
    # output's. os.mkdir applies the user's umask like any folder they make.
    for _ in range(100):
        p = parent / f".{name}{PARTIAL_INFIX}{secrets.token_hex(4)}"
        try:
            os.mkdir(p)
            return p
        except FileExistsError:
            continue
    raise FileExistsError(f"{parent}: could not make a temporary output folder")


def _exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``).

    Returns False where the call does not exist or the file system does not support
    it (the caller then falls back to two renames). Hand-written with ctypes because
    the standard library has no binding for it.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def public_message(text: str, tmp: Path, out: Path) -> str:
    """``text`` with the temporary folder's path replaced by the final output path."""
    return text.replace(str(tmp), str(out))


class AtomicOutputDir:
    """Write into a temporary sibling folder; move it into place on success only.

    Construction checks ``out`` (see the module docstring) and raises
    :class:`OutputPathError` before anything is created; it then removes stale partial
    folders in the parent and makes the partial folder with its marker. Leaving the
    ``with`` block by an exception (also KeyboardInterrupt or a signal turned into one)
    deletes the partial folder and leaves ``out`` as it was; messages of the exception
    that name the partial folder are made to name ``out`` instead.
    """

    def __init__(self, out: str | Path, scenario: str = "", kind: OutputKind = "run") -> None:
        self.out = Path(out)
        replaceable_state(self.out)
        self.out.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_partials(self.out.parent)
        self.tmp = _make_partial(self.out.parent, self.out.name)
        try:
            (self.tmp / MARKER).write_text(OutputMarker.for_this_process(scenario, kind).to_json())
        except BaseException:
            shutil.rmtree(self.tmp, ignore_errors=True)
            raise

    def __enter__(self) -> Path:
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.discard()
            if exc is not None:
                self._rename_in_message(exc)
            return
        self.commit()

    def discard(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)

    def public(self, text: str) -> str:
        """``text`` naming the final output path instead of the partial folder."""
        return public_message(text, self.tmp, self.out)

    def _rename_in_message(self, exc: BaseException) -> None:
        # Exceptions of this code base carry their message as args[0] (one line).
        if exc.args and isinstance(exc.args[0], str) and str(self.tmp) in exc.args[0]:
            exc.args = (self.public(exc.args[0]),) + tuple(exc.args[1:])

    def commit(self) -> None:
        """Move the finished folder to ``out`` (replacing a bench output or an empty folder);
        not after SIGINT/SIGTERM (:mod:`simbench.interrupts`): then discard it and raise."""
        try:
            interrupts.raise_if_pending()
        except interrupts.Interrupted:
            self.discard()
            raise
        try:
            state = replaceable_state(self.out)  # again: the path may have changed during the run
        except OutputPathError:
            self.discard()
            raise
        try:
            if state == "ours" and _exchange(self.tmp, self.out):
                shutil.rmtree(self.tmp, ignore_errors=True)  # now the old output
            elif state == "ours":
                old = self.out.with_name(f".{self.out.name}{PARTIAL_INFIX}old-{os.getpid()}")
                os.replace(self.out, old)
                os.replace(self.tmp, self.out)
                shutil.rmtree(old, ignore_errors=True)
            else:
                # "absent", or an empty folder: rename(2) replaces an empty folder and
                # fails (ENOTEMPTY) if something was put into it meanwhile.
                os.replace(self.tmp, self.out)
        except OSError as exc:
            self.discard()
            raise OutputPathError(f"{self.out}: could not move the finished output into place "
                                  f"({exc.strerror or exc}); choose another --out") from None
