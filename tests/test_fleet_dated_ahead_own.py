"""The push's "dated ahead" line counts exactly the signatures the export kept back as dated after tomorrow, and only
the site's own. The export refused another site's signature only among those it would send: dated ahead (or past
the retention), one was kept back quietly and named as this site's in the "kept at the site" line and count, and
under ``aggregates_only`` another site's signatures were counted into this site's aggregates."""

from __future__ import annotations

import datetime as dt
import itertools

import pytest

from cellguard.fleet.export import export_batch, newest_kept
from cellguard.fleet.policy import DataPolicy, PolicyError
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature

TODAY = dt.date(2026, 3, 1)
KEY = b"site-secret-of-the-tests"
POLICIES = (DataPolicy("ta", "s1", retention_days=30),
            DataPolicy("ta", "s1", export="aggregates_only", min_group_size=2, retention_days=30))


def sig(days: int, n: int = 0, site: str = "s1") -> Signature:
    return Signature("ta", site, (TODAY + dt.timedelta(days=days)).isoformat(), "friction", 0.8, "arm5", "arm-cell",
                     {"current_rms.elbow": 6.0 + n}, 7, 1)


@pytest.mark.parametrize("policy", POLICIES, ids=lambda p: p.export)
@pytest.mark.parametrize("days", [-40, 2, 30])  # past the retention, a day after tomorrow, a month ahead
def test_another_sites_signature_is_refused_whatever_its_date(tmp_path, policy, days):
    signatures = [sig(0, 1), sig(0, 2), sig(days, 3, site="s2")]
    with pytest.raises(PolicyError, match="ta/s2 is not the policy's ta/s1"):
        export_batch(signatures, policy, TODAY, key=KEY)
    with pytest.raises(PolicyError, match="ta/s2 is not the policy's ta/s1"):
        push(signatures, policy, tmp_path, None, today=TODAY)  # no line names it as kept at this site


def test_aggregates_count_no_other_sites_signatures():
    policy = POLICIES[1]
    with pytest.raises(PolicyError, match="ta/s2 is not the policy's ta/s1"):
        export_batch([sig(0, 1), sig(0, 2, site="s2")], policy, TODAY, key=KEY)
    (row,) = export_batch([sig(0, 1), sig(0, 2)], policy, TODAY, key=KEY).aggregates
    assert row["signatures"] == 2


@pytest.mark.parametrize("policy", POLICIES, ids=lambda p: p.export)
def test_the_dated_ahead_count_is_the_signatures_kept_back_for_it(tmp_path, policy):
    """Every mix of dates past the retention, kept, tomorrow, and after tomorrow: the line's count and span are
    the signatures not exported that are dated after tomorrow, no more, no fewer."""
    newest = newest_kept(TODAY)
    for n, days in enumerate(itertools.product((-40, 0, 1, 2, 9), repeat=3)):
        signatures = [sig(d, i) for i, d in enumerate(days)]
        site = tmp_path / str(n)
        result = push(signatures, policy, site, None, today=TODAY)
        ahead = sorted(s.created_date for s in signatures if dt.date.fromisoformat(s.created_date) > newest)
        assert all(r["created_date"] <= newest.isoformat() for r in result.batch.signatures)
        if not ahead:
            assert result.dated_ahead is None
            continue
        span = ahead[0] if ahead[0] == ahead[-1] else f"{ahead[0]} to {ahead[-1]}"
        assert result.dated_ahead.startswith(f"{len(ahead)} signature(s) dated {span} kept at the site: after "
                                             f"tomorrow ({newest}) by this host's UTC date"), result.dated_ahead
