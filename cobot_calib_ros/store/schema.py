"""The results database's tables (SQLAlchemy Core), as the newest migration leaves them
(store/migrations; test_database checks that the two agree). See store.database."""
from __future__ import annotations

import sqlalchemy as sa

NAME = sa.String(128)
metadata = sa.MetaData()

results = sa.Table(
    'results', metadata,
    sa.Column('cell', NAME, primary_key=True),
    sa.Column('kind', sa.String(32), primary_key=True),
    sa.Column('id', NAME, primary_key=True),
    sa.Column('scope', NAME, nullable=False),
    sa.Column('stamp_ns', sa.BigInteger, nullable=False),
    sa.Column('method', NAME, nullable=False),
    sa.Column('gate_problem', sa.Text, nullable=False),
    sa.Column('robot_model', NAME, nullable=False),
    sa.Column('robot_serial', NAME, nullable=False),
    sa.Column('model_hash', sa.String(64), nullable=False),
    sa.Column('software_version', sa.String(64), nullable=False),
    sa.Column('bag_sha256', sa.String(64), nullable=False),
    sa.Column('temperature_c', sa.Float, nullable=True),
    sa.Column('body', sa.Text, nullable=False),
    sa.Column('written_ns', sa.BigInteger, nullable=False),
    sa.Index('results_by_time', 'cell', 'kind', 'stamp_ns'),
)

selections = sa.Table(
    'selections', metadata,
    sa.Column('cell', NAME, primary_key=True),
    sa.Column('kind', sa.String(32), primary_key=True),
    sa.Column('scope', NAME, primary_key=True),
    sa.Column('active_id', NAME, nullable=False),
)

retired = sa.Table(
    'retired', metadata,
    sa.Column('cell', NAME, primary_key=True),
    sa.Column('kind', sa.String(32), primary_key=True),
    sa.Column('id', NAME, primary_key=True),
)
