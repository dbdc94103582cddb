"""Domain claims: concurrent aeropend processes never get the same ROS_DOMAIN_ID."""

from __future__ import annotations

import random
import subprocess
import sys

import pytest

from aeropend_sim.ros.domain import DomainError, claim_domain
from aeropend_sim.ros.harness import claimed_domains, random_domain, release_domains


@pytest.fixture(autouse=True)
def private_lock_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("AEROPEND_DOMAIN_LOCK_DIR", str(tmp_path))


def test_claims_in_one_range_are_distinct_until_released():
    claims = [claim_domain(10, 14, rng=random.Random(0)) for _ in range(5)]
    assert sorted(c.domain_id for c in claims) == [10, 11, 12, 13, 14]
    with pytest.raises(DomainError, match=r"every ROS domain ID in 10\.\.14 is claimed"):
        claim_domain(10, 14)
    freed = claims[2].domain_id
    claims[2].release()
    claims[2].release()  # idempotent
    with claim_domain(10, 14) as again:
        assert again.domain_id == freed
    assert claim_domain(10, 14).domain_id == freed  # the with-block gave it back


def test_a_claim_held_by_another_process_is_skipped_and_freed_when_it_exits():
    code = ("import sys; from aeropend_sim.ros.domain import claim_domain; c = claim_domain(20, 20); "
            "print(c.domain_id, flush=True); sys.stdin.read()")
    holder = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "20"
        with pytest.raises(DomainError):
            claim_domain(20, 20)
        assert claim_domain(20, 21).domain_id == 21
    finally:
        holder.communicate("", timeout=10)  # EOF: the holder exits, the kernel drops its lock
    assert claim_domain(20, 20).domain_id == 20


@pytest.mark.parametrize("first,last", [(-1, 5), (5, 4), (0, 233)])
def test_invalid_ranges_are_refused(first, last):
    with pytest.raises(DomainError, match="expected 0 <= first <= last <= 232"):
        claim_domain(first, last)


def test_released_harness_claims_are_free_again_and_older_ones_are_kept():
    """What test/conftest.py does after every test: the claims made since are given back."""
    before = claimed_domains()
    kept = random_domain(30, 30)
    held = claimed_domains()
    assert random_domain(31, 31) == 31
    with pytest.raises(ValueError, match=r"every ROS domain ID in 31\.\.31 is claimed"):
        random_domain(31, 31)
    release_domains(keep=held)
    assert claimed_domains() == held
    with claim_domain(31, 31) as again:  # free for anyone
        assert again.domain_id == 31
    with pytest.raises(DomainError):
        claim_domain(30, 30)  # the older claim is still held
    release_domains(keep=before)
    assert claim_domain(kept, kept).domain_id == 30
