"""Claim a private ROS domain ID on this host, so concurrent runs never share one.

A randomly drawn ``ROS_DOMAIN_ID`` keeps two concurrent runs apart only with probability
1 − 1/N: a test and a benchmark that both drew the same ID saw each other's commands and
samples (the plant took 3202 commands from an excitation that had sent 2448; docs/data_plane.md).
A claim is an exclusive ``flock`` on ``<tmp>/aeropend-ros-domain-<id>.lock``: every aeropend
process that claims through this module skips IDs that another live process holds, and the
kernel releases the lock when the holder exits (also on a crash), so no stale claim survives.

Processes that do not claim (a lab's own ``ros2 run``) are not seen; keep them on IDs outside
the claimed range.
"""

from __future__ import annotations

import fcntl
import os
import random
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

#: Highest domain ID whose Fast DDS / RTPS ports (7400 + 250·id + offsets) fit in 16 bits.
MAX_DOMAIN_ID = 232


class DomainError(RuntimeError):
    """No domain ID in the requested range is free, or the range is invalid."""


@dataclass
class DomainClaim:
    """An exclusive claim on a ROS domain ID, held until :meth:`release` or process exit.

    Attributes
    ----------
    domain_id : int
        The claimed ``ROS_DOMAIN_ID``.
    lock_path : Path
        The lock file that holds the claim.
    """

    domain_id: int
    lock_path: Path
    _handle: IO[bytes] | None = field(default=None, repr=False)

    def release(self) -> None:
        """Give the domain ID back (idempotent)."""
        if self._handle is not None:
            self._handle.close()  # closing the descriptor drops the flock
            self._handle = None

    def __enter__(self) -> DomainClaim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def lock_dir() -> Path:
    """Folder of the claim files: ``$AEROPEND_DOMAIN_LOCK_DIR`` or the system temp folder."""
    return Path(os.environ.get("AEROPEND_DOMAIN_LOCK_DIR") or tempfile.gettempdir())


def claim_domain(first: int = 1, last: int = 200, *, rng: random.Random | None = None) -> DomainClaim:
    """Claim a domain ID in ``first..last`` that no other aeropend process on this host holds.

    IDs are tried in random order (OS entropy unless ``rng`` is given), so concurrent claimers
    rarely contend for the same lock.

    Parameters
    ----------
    first, last : int
        Inclusive bounds, ``0 <= first <= last <= 232``.
    rng : random.Random, optional
        Order of the tries (tests).

    Returns
    -------
    DomainClaim
        Hold it for as long as the nodes on that domain run.

    Raises
    ------
    DomainError
        If the bounds are invalid or every ID in the range is claimed.
    """
    if not 0 <= first <= last <= MAX_DOMAIN_ID:
        raise DomainError(f"domain range {first}..{last}: expected 0 <= first <= last <= {MAX_DOMAIN_ID}")
    ids = list(range(first, last + 1))
    (rng or random.SystemRandom()).shuffle(ids)
    folder = lock_dir()
    for domain_id in ids:
        path = folder / f"aeropend-ros-domain-{domain_id}.lock"
        handle = open(path, "ab")  # held open: the open descriptor is the claim
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return DomainClaim(domain_id, path, handle)
    raise DomainError(f"every ROS domain ID in {first}..{last} is claimed by another aeropend process "
                      f"(lock files in {folder})")
