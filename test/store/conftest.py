"""A real PostgreSQL for the database tests: one throwaway cluster per session (pg_cluster)."""
from __future__ import annotations

import pytest

from pg_cluster import throwaway_cluster


@pytest.fixture(scope='session')
def postgres_url():
    with throwaway_cluster() as url:
        yield url


@pytest.fixture(params=['sqlite', 'postgresql'])
def db_url(request, tmp_path):
    """Each database test runs on both: a SQLite file and the session's PostgreSQL (a fresh
    cell per test keeps them apart there)."""
    if request.param == 'sqlite':
        return f'sqlite:///{tmp_path / "results.sqlite"}'
    return request.getfixturevalue('postgres_url')
