"""A small content-addressed cache on disk, for what is slow to derive and cheap to keep.

Entries are named by a hash of everything they were derived from (the caller's key), so a
changed input is a different entry and nothing is ever invalidated by hand. Each entry is
written to a temporary file and renamed into place (readers see a whole entry or none, and
two processes writing the same entry both succeed); each kind keeps a bounded number of
entries and bytes, the least recently used removed first. Any failure to read or write only
costs the time the cache would have saved.

The cache lives in ``$KINESPHERE_CACHE`` if set, else ``$XDG_CACHE_HOME/kinesphere``, else
``~/.cache/kinesphere``; ``KINESPHERE_CACHE=off`` turns it off. A folder another user owns or
may write to is not used (its entries could be anyone's): the cache is then off.
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
import tempfile
import time
from pathlib import Path
from typing import Final

CACHE_ENV: Final = "KINESPHERE_CACHE"
OFF: Final = "off"
STALE_S: Final = 3600.0
"""A temporary file older than this was left by a writer that died."""
_KEY = re.compile(r"[0-9a-f]{16,128}")


def cache_root() -> Path | None:
    """The cache folder, or None when the cache is off."""
    chosen = os.environ.get(CACHE_ENV, "")
    if chosen == OFF:
        return None
    if chosen:
        return Path(chosen).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "kinesphere"


class FileCache:
    """One kind of entry (a subfolder of the cache): at most ``max_entries`` of at most
    ``max_bytes`` each, ``max_total`` bytes in all."""

    def __init__(self, kind: str, max_entries: int, max_bytes: int, max_total: int) -> None:
        self.kind = kind
        self.max_entries = max_entries
        self.max_bytes = max_bytes
        self.max_total = max_total

    def folder(self) -> Path | None:
        """This kind's folder, or None when the cache is off or its folders are not ours
        alone."""
        root = cache_root()
        if root is None or not (_ours(root) and _ours(root / self.kind)):
            return None
        return root / self.kind

    def get(self, key: str) -> bytes | None:
        """The entry of ``key`` (a hex digest), or None when absent, too large or unreadable."""
        folder = self.folder()
        if folder is None or not _KEY.fullmatch(key):
            return None
        try:
            with open(folder / key, "rb") as f:
                data = f.read(self.max_bytes + 1)
        except OSError:
            return None
        if len(data) > self.max_bytes:
            return None
        with contextlib.suppress(OSError):
            os.utime(folder / key)  # recently used: trimmed last
        return data

    def put(self, key: str, data: bytes) -> None:
        """Keep ``data`` as the entry of ``key``; then drop the oldest past ``max_entries``."""
        folder = self.folder()
        if folder is None or not _KEY.fullmatch(key) or len(data) > self.max_bytes:
            return
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-")
            try:
                with os.fdopen(fd, "wb") as f:
                    f.write(data)
                os.replace(tmp, folder / key)
            except BaseException:
                os.unlink(tmp)
                raise
            self._trim(folder)
        except OSError:
            return

    def _trim(self, folder: Path) -> None:
        entries = []
        now = time.time()
        for p in folder.iterdir():
            if p.name.startswith(".tmp-"):  # left by a process killed while writing
                with contextlib.suppress(OSError):
                    if now - p.stat().st_mtime > STALE_S:
                        p.unlink()
            elif _KEY.fullmatch(p.name):
                try:
                    st = p.stat()
                except OSError:
                    continue  # removed by another process meanwhile
                entries.append((st.st_mtime, st.st_size, p))
        count, total = len(entries), sum(size for _, size, _ in entries)
        for _, size, p in sorted(entries):  # the least recently used first
            if count <= self.max_entries and total <= self.max_total:
                break
            p.unlink(missing_ok=True)
            count, total = count - 1, total - size


def _ours(folder: Path) -> bool:
    """Whether only this user can have written in ``folder`` (or it does not exist yet, and
    will be made by this user)."""
    try:
        st = folder.stat()
    except FileNotFoundError:
        return True
    except OSError:
        return False
    return st.st_uid == os.getuid() and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
