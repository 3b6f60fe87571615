"""One writer per campaign directory: an OS lock, and a record of who holds it.

Every command that writes a campaign (`campaign run`, `propose`, `ingest`, a comparison's workers) holds
the directory's lock while it works. The lock is an exclusive `flock` on DIR/.lock: the kernel (or the
NFS server) drops it when its process dies, so a lock left by a dead process is taken over at once. Beside
it, DIR/lock.json records the holder (host, pid, command, since when, a random token) for the message a
second writer gets, and the holder renews a lease every LEASE_SECONDS / 3 in a file of its own token,
DIR/lock.<token>.lease: a record from another host whose lease was not renewed for LEASE_SECONDS is stale
(its holder is gone, or its file system's locks did not reach this host), one from this host is stale
once its pid is gone. A holder stalled past its lease and taken over finds out from the record at its
next commit (`check`) and stops without writing. The record is written once, when the lock is taken, and
a renewal writes only the holder's own lease file: a renewer stopped between its check and its write
(a stall can fall anywhere) cannot write its record back over a taker's. A second writer waits up to
`wait` seconds, then raises CampaignLocked naming the holder. Re-entering the lock in the same thread
(`tell` proposes, `ingest` tells) only counts.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import json
import os
import secrets
import shlex
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar

from activelearn.data import atomic_write_bytes
from activelearn.errors import ActiveLearnError, CampaignStopped, InputError

LOCK_FILE = ".lock"
HOLDER_FILE = "lock.json"
LEASE_SUFFIX = ".lease"  # DIR/lock.<token>.lease: one holder's renewals
COMMIT_FILE = "state.json"  # a campaign's commit point (activelearn.loop.state.STATE_FILE is this name)
LEASE_SECONDS = 60.0
DEFAULT_WAIT = 120.0  # s a second writer waits before it gives up
_POLL = 0.2

F = TypeVar("F", bound=Callable[..., Any])


class CampaignLocked(ActiveLearnError):
    """Another process writes this campaign directory; nothing was written."""


@dataclass(frozen=True)
class Holder:
    """Who holds a campaign directory's lock."""

    host: str
    pid: int
    command: str
    since: float  # Unix time the lock was taken
    renewed: float  # Unix time the holder last renewed its lease
    lease: float
    token: str

    def describe(self) -> str:
        """host, pid, command and since when, in one line."""
        since = datetime.fromtimestamp(self.since, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
        return f"host {self.host}, pid {self.pid} (`{self.command}`), since {since}"

    def stale(self, now: float) -> bool:
        """Its holder is gone: a dead pid on this host, or a lease not renewed in time."""
        if now - self.renewed > self.lease:
            return True
        return self.host == socket.gethostname() and not _alive(self.pid)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def lease_file(directory: str | Path, token: str) -> Path:
    """The file in which the holder with `token` renews its lease."""
    return Path(directory) / f"lock.{token}{LEASE_SUFFIX}"


def read_holder(directory: str | Path) -> Holder | None:
    """The record of a directory's lock holder with its latest renewal, or None (no record, or one being
    written)."""
    try:
        holder = Holder(**json.loads((Path(directory) / HOLDER_FILE).read_text()))
    except (OSError, ValueError, TypeError):
        return None
    try:
        renewed = float(json.loads(lease_file(directory, holder.token).read_text())["renewed"])
    except (OSError, ValueError, TypeError, KeyError):
        return holder  # not renewed yet (or a renewal being written): the record's own time
    return Holder(**{**asdict(holder), "renewed": max(holder.renewed, renewed)})


class DirectoryLock:
    """The exclusive lock of one campaign directory, held by this process (see the module's docstring)."""

    def __init__(self, directory: str | Path, *, lease: float = LEASE_SECONDS) -> None:
        self.directory = Path(directory)
        self.lease = lease
        self.lost = False  # another process took the lock over (a lease this one did not renew in time)
        self._fd: int | None = None
        self._created: list[Path] = []
        self._holder: Holder | None = None
        self._written = 0.0  # Unix time of the record's taking or of the last renewal written
        self._stop = threading.Event()
        self._renewer: threading.Thread | None = None

    def acquire(self, wait: float = DEFAULT_WAIT, on_wait: Callable[[Holder], None] | None = None) -> None:
        """Take the lock, waiting up to `wait` s (`on_wait` is told the holder once); else CampaignLocked."""
        deadline = time.monotonic() + wait
        told = False
        while True:
            holder = self._try()
            if holder is None:
                return
            if time.monotonic() >= deadline:
                what = holder.describe() if holder is not _UNKNOWN else "another process"
                raise CampaignLocked(
                    f"{self.directory}: another command writes this campaign ({what}); nothing was "
                    f"written: retry when it has finished (or wait longer with --wait)"
                )
            if not told and on_wait is not None:
                on_wait(holder)
                told = True
            time.sleep(min(_POLL, max(0.0, deadline - time.monotonic())))

    def _try(self) -> Holder | None:
        """Take the lock now and return None, or return the holder (_UNKNOWN before it wrote its record)."""
        fd = self._flock()
        holder = read_holder(self.directory)
        if fd is None:
            return holder or _UNKNOWN
        if holder is not None and not holder.stale(time.time()):
            # A live holder the OS lock did not see: another host on a file system whose locks stay local.
            os.close(fd)
            return holder
        self._fd = fd
        now = time.time()
        command = shlex.join(getattr(sys, "orig_argv", sys.argv))[:300]
        self._holder = Holder(socket.gethostname(), os.getpid(), command, now, now, self.lease,
                              secrets.token_hex(8))  # fmt: skip
        try:
            atomic_write_bytes(self.directory / HOLDER_FILE, json.dumps(asdict(self._holder)).encode())
        except OSError:
            self.release()
            raise
        self._written = now
        for stale in self.directory.glob(f"lock.*{LEASE_SUFFIX}"):  # left by holders gone or taken over
            if stale != lease_file(self.directory, self._holder.token):
                stale.unlink(missing_ok=True)
        self._stop.clear()
        self._renewer = threading.Thread(target=self._renew, name="campaign-lock", daemon=True)
        self._renewer.start()
        return None

    def _flock(self) -> int | None:
        """An fd holding the OS lock on DIR/.lock, or None if another process holds it."""
        missing = []
        for parent in (self.directory, *self.directory.parents):
            if parent.exists():
                break
            missing.append(parent)
        self.directory.mkdir(parents=True, exist_ok=True)
        self._created = self._created or missing
        path = self.directory / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except FileNotFoundError:  # the last holder removed the directory it had made: try again
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        try:  # the last holder may have removed the file (an empty directory it had made)
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if not same:
            os.close(fd)
            return None
        return fd

    def _renew_lease(self) -> None:
        """Write the renewal into this holder's own lease file (never the record: see the module)."""
        assert self._holder is not None
        now = time.time()
        renewal = json.dumps({"renewed": now}).encode()
        atomic_write_bytes(lease_file(self.directory, self._holder.token), renewal)
        self._written = now

    def held(self) -> bool:
        """Whether this process still holds the lock, by its record: no other holder's token in it.

        A record gone while this holder's lease ran out (it was stalled past it) counts as lost too:
        another process may have taken the directory over, done its work and released it meanwhile.
        A record gone within the lease is a read that failed for a moment.
        """
        if self.lost or self._holder is None:
            return False
        current = read_holder(self.directory)
        if current is None:
            return time.time() - self._written <= self.lease
        return current.token == self._holder.token

    def _renew(self) -> None:
        while not self._stop.wait(self.lease / 3):
            if not self.held():  # taken over: renewing would only leave a file behind
                self.lost = True
                return
            with contextlib.suppress(OSError):  # a full disk: the next renewal tries again
                self._renew_lease()

    def release(self) -> None:
        """Drop the record and the lock; remove the directory again if the lock made it and it is empty."""
        self._stop.set()
        if self._renewer is not None:
            self._renewer.join()
        if self._fd is None:
            return
        if self._holder is not None:
            holder = read_holder(self.directory)
            if not self.lost and holder is not None and holder.token == self._holder.token:
                (self.directory / HOLDER_FILE).unlink(missing_ok=True)
            lease_file(self.directory, self._holder.token).unlink(missing_ok=True)
        if self._created and [p.name for p in self.directory.iterdir()] == [LOCK_FILE]:
            (self.directory / LOCK_FILE).unlink()  # waiters see the inode change and try again
            os.close(self._fd)
            for path in self._created:
                with contextlib.suppress(OSError):
                    path.rmdir()
        else:
            os.close(self._fd)
        self._fd = None


_UNKNOWN = Holder("?", 0, "?", 0.0, 0.0, 0.0, "")  # the lock is taken and its record not written yet
_held: dict[tuple[Path, int], tuple[DirectoryLock, int]] = {}


@contextlib.contextmanager
def hold(
    directory: str | Path,
    wait: float = DEFAULT_WAIT,
    on_wait: Callable[[Holder], None] | None = None,
    *,
    lease: float = LEASE_SECONDS,
) -> Iterator[DirectoryLock]:
    """Hold a campaign directory's lock for the block (re-entrant within a thread).

    `lease`: seconds the lock's record stays valid without a renewal (renewed every lease / 3); a holder
    stalled for longer may be taken over, and then stops at its next checkpoint (`check`). Re-entering
    keeps the lease of the outer block.
    """
    if not wait >= 0:
        raise InputError("--wait", wait, "must be a number of seconds >= 0")
    key = (Path(directory).absolute(), threading.get_ident())
    if key in _held:
        lock, depth = _held[key]
        _held[key] = (lock, depth + 1)
    else:
        lock = DirectoryLock(directory, lease=lease)
        lock.acquire(wait, on_wait)
        _held[key] = (lock, 1)
    try:
        yield lock
    finally:
        lock, depth = _held[key]
        if depth > 1:
            _held[key] = (lock, depth - 1)
        else:
            del _held[key]
            lock.release()


def _within(filename: Any, directory: Path) -> bool:
    """Whether an OSError's file lies in `directory`."""
    return isinstance(filename, str | Path) and Path(filename).absolute().is_relative_to(directory.absolute())


def check(directory: str | Path) -> None:
    """Raise CampaignLocked if this thread held the directory's lock and another process took it over.

    It asks the record itself rather than waiting for the renewer to notice: a holder resumed after a
    stall may reach its next write before its renewer thread runs again.
    """
    entry = _held.get((Path(directory).absolute(), threading.get_ident()))
    if entry is not None and not entry[0].held():
        entry[0].lost = True
        raise CampaignLocked(
            f"{directory}: another command took this campaign over while this one was stalled for more "
            f"than {entry[0].lease:g} s; this one stops without writing"
        )


def writer(method: F) -> F:
    """Run `method(campaign, ...)` holding the lock of `campaign.directory` (wait: `campaign.lock_wait`).

    A write into the directory that fails (disk full, read-only) stops it with CampaignStopped: every
    write is atomic and the state is written last, so the directory holds its last finished step.
    """

    @functools.wraps(method)
    def locked(campaign: Any, *args: Any, **kwargs: Any) -> Any:
        def tell(holder: Holder) -> None:
            who = holder.describe() if holder is not _UNKNOWN else "another process"
            campaign.progress({"event": "lock_wait", "holder": who, "wait": campaign.lock_wait,
                               "directory": str(campaign.directory)})  # fmt: skip

        try:
            with hold(campaign.directory, campaign.lock_wait, tell):
                return method(campaign, *args, **kwargs)
        except OSError as exc:
            if not _within(exc.filename, campaign.directory):
                raise
            # state.json is the commit point: without one there is nothing to resume, only to redo
            committed = (Path(campaign.directory) / COMMIT_FILE).is_file()
            advice = (
                "holds its last finished step: rerun with --resume once it can be written"
                if committed
                else "holds no finished step yet: rerun the same command (no --resume) once it can be written"
            )
            raise CampaignStopped(
                f"cannot write {exc.filename} ({exc.strerror}); {campaign.directory} {advice}"
            ) from None

    return locked  # type: ignore[return-value]
