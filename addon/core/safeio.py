"""Safe writers shared by the core: unique temporary files, fsync, rename; an exclusive lock.

No writer here follows a symlink planted at the destination or at a temporary name, and none
leaves a half-written file under the destination's name. Every failure is one ClothFitError line.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from typing import Any

from .errors import ClothFitError


def atomic_write(path: str | os.PathLike, data: bytes) -> None:
    """Write a file safely: a new unique temporary file next to ``path`` (created exclusively by
    ``mkstemp``, so a planted file or symlink is never followed), flushed and fsynced, then renamed
    over ``path`` (a rename replaces a symlink at ``path`` itself, never its target). Two writers
    never share a temporary file; a reader sees the old or the new file, whole. One-line errors."""
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    base = os.path.basename(path)
    if not base:
        raise ClothFitError(f"cannot write {path!r}: not a file name")
    if os.path.isdir(path) and not os.path.islink(path):
        raise ClothFitError(f"cannot write {path}: it is a directory")
    tmp = None
    try:
        os.makedirs(d, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{base}.", suffix=".tmp", dir=d)
        try:
            mode = os.lstat(path).st_mode & 0o777 if os.path.isfile(path) and not os.path.islink(path) else 0o644
            os.fchmod(fd, mode)
        except (OSError, AttributeError):
            pass
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        tmp = None
    except OSError as e:
        raise ClothFitError(f"cannot write {path}: {e.strerror or e}") from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


@contextlib.contextmanager
def exclusive_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold an exclusive advisory lock on ``path + '.lock'`` (POSIX ``flock``; released when the
    process ends, even by kill -9). Another holder -> ClothFitError at once. The lock file is removed
    when the block ends (normally, by an error or by Ctrl-C): unlinked while the lock is still held,
    and a locker that finds the file it locked no longer on disk (removed by the holder it waited
    behind) locks the new one instead, so two holders never hold two different files."""
    lock_path = os.fspath(path) + ".lock"
    try:
        import fcntl
    except ImportError:  # Windows: no advisory lock; the unique temp files still keep files whole
        yield
        return
    fd = _locked_fd(lock_path, path, fcntl)
    try:
        yield
    finally:
        try:
            if _same_file(fd, lock_path):
                os.unlink(lock_path)
        except OSError:
            pass
        os.close(fd)


def _same_file(fd: int, path: str) -> bool:
    """Whether ``path`` still names the file open as ``fd`` (not removed, not replaced)."""
    try:
        st = os.lstat(path)
    except OSError:
        return False
    mine = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (mine.st_dev, mine.st_ino)


def _locked_fd(lock_path: str, path: str | os.PathLike, fcntl: Any) -> int:
    """Open and flock ``lock_path``; again if the file locked was removed meanwhile by its holder."""
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        try:
            os.makedirs(os.path.dirname(os.path.abspath(lock_path)), exist_ok=True)
            fd = os.open(lock_path, flags, 0o644)
        except OSError as e:
            raise ClothFitError(f"cannot create the lock file {lock_path}: {e.strerror or e}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise ClothFitError(
                f"another fit is writing {path} (it holds {lock_path}): wait for it, or choose another --out"
            ) from None
        if _same_file(fd, lock_path):
            return fd
        os.close(fd)  # its holder removed it between our open and our flock: lock the file on disk now
    raise ClothFitError(f"cannot lock {lock_path}: it keeps being removed and created again")
